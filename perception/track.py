"""``python -m perception.track``: the offline tracking command, under the name the toolkit documents.

The command itself is ``launch_scripts.track`` (an entry point, like the others); this
module only runs it, so ``import perception.track`` loads nothing else.
"""

if __name__ == "__main__":
    import runpy

    runpy.run_module("launch_scripts.track", run_name="__main__", alter_sys=True)
