"""Entry points that start the toolkit's processes (``python -m launch_scripts.<name>``), and
the orchestration of the trials: command lines and processes only, the logic they run lives
in the packages below (docs/architecture.md)."""

import signal
import sys
import threading

#: Ctrl-C presses that came while the command's modules loaded. A library can swallow the
#: KeyboardInterrupt as it loads (numpy.random's compiled module did, in CI), and the command
#: would then run on as if never interrupted: ``loaded`` raises it again.
interrupts_while_loading: list[int] = []


def _remember_ctrl_c(signum, frame):
    interrupts_while_loading.append(signum)
    raise KeyboardInterrupt


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
    if signal.getsignal(signal.SIGINT) is signal.default_int_handler:  # not where Ctrl-C is ignored
        signal.signal(signal.SIGINT, _remember_ctrl_c)


def loaded() -> None:
    """The command's modules have loaded (``cli.OneLineParser`` calls this as it parses the
    arguments): Ctrl-C is Python's own again, and one that came while loading is raised now."""
    if signal.getsignal(signal.SIGINT) is _remember_ctrl_c and threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.default_int_handler)
    if interrupts_while_loading:
        interrupts_while_loading.clear()
        raise KeyboardInterrupt
