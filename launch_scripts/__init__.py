"""Entry points that start the toolkit's processes (``python -m launch_scripts.<name>``), and
the orchestration of the trials: command lines and processes only, the logic they run lives
in the packages below (docs/architecture.md)."""

import sys

if sys.argv and sys.argv[0] == "-m":  # a command starting: Python names no module yet while it looks for one
    # Ctrl-C while the command's modules load, before its main catches it
    # (``cli.exit_130_on_ctrl_c``), ends it the same way: one line, not an import's traceback;
    # the interpreter still exits as interrupted (status 130).
    def _interrupted(kind, value, tb, _default=sys.excepthook):
        if issubclass(kind, KeyboardInterrupt):
            print("interrupted", file=sys.stderr, flush=True)
        else:
            _default(kind, value, tb)

    sys.excepthook = _interrupted
