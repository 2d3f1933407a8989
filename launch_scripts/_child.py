"""Run a module as a child that dies with its parent: ``python -m launch_scripts._child PARENT_PID MODULE ARGS...``.

On Linux it asks the kernel to send it SIGTERM when its parent dies (prctl
PR_SET_PDEATHSIG), then checks that the parent is still the one that started it (it may
have died before the request), and runs ``python -m MODULE ARGS...`` in this process.
Done here after exec rather than in a ``preexec_fn``, which may deadlock when the parent
has threads (the trial's publisher and subscribers do).
"""

from __future__ import annotations

import ctypes
import os
import runpy
import signal
import sys

_PR_SET_PDEATHSIG = 1  # linux/prctl.h


def die_with_parent(parent: int) -> bool:
    """Have this process sent SIGTERM when its parent dies (Linux; elsewhere nothing), and
    return whether its parent is still ``parent`` (pid), the process that started it."""
    if sys.platform.startswith("linux"):
        ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)
    return os.getppid() == parent


def main() -> None:
    parent, module, args = int(sys.argv[1]), sys.argv[2], sys.argv[3:]
    if not die_with_parent(parent):
        sys.exit(f"{module}: the process that started it has ended")
    sys.argv = [module, *args]
    runpy.run_module(module, run_name="__main__", alter_sys=True)


if __name__ == "__main__":
    main()
