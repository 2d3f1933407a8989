"""What every launch script shares: one-line usage errors, checked numbers, CURVE options, and stopping on a signal."""

from __future__ import annotations

import argparse
import math
import os
import signal
import threading

from ipc.endpoints import is_loopback


class OneLineParser(argparse.ArgumentParser):
    """argparse, but a usage error is one line on stderr (no usage block) and exit status 2,
    so a supervisor's log shows what was wrong without scrolling."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message}\n")


def positive_int(text: str) -> int:
    """argparse type: an integer >= 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {value}")
    return value


def finite_float(text: str) -> float:
    """argparse type: a finite number."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return value


def non_negative_float(text: str) -> float:
    """argparse type: a finite number >= 0."""
    value = finite_float(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {text}")
    return value


def add_security_arguments(parser: argparse.ArgumentParser) -> None:
    """``--curve-keys DIR`` and ``--insecure``, read back by ``curve_keys_from_args``."""
    g = parser.add_argument_group("security")
    g.add_argument("--curve-keys", metavar="DIR",
                   help="encrypt every socket with CURVE and accept only authorised clients: a key directory made by "
                        "python -m launch_scripts.curve_keys (server.key_secret, authorized_clients/)")
    g.add_argument("--insecure", action="store_true",
                   help="allow binding an address other than loopback without --curve-keys (unencrypted, anyone may connect)")


def curve_keys_from_args(args, bind_endpoints):
    """The ``ipc.transport.CurveKeys`` of ``--curve-keys``, or None without it.

    bind_endpoints : the endpoints the process binds; one reachable from another machine
        (``ipc.endpoints.is_loopback`` false) needs ``--curve-keys`` or ``--insecure``
    raises ValueError (one line) for a bad key directory or an exposed endpoint
    """
    from ipc.transport import CurveKeys  # zmq only for the commands that open sockets

    if args.curve_keys:
        return CurveKeys.from_directory(args.curve_keys)
    exposed = [ep for ep in bind_endpoints if not is_loopback(ep)]
    if exposed and not args.insecure:
        raise ValueError(f"{exposed[0]} can be reached from other machines: give --curve-keys DIR to encrypt and "
                         "authenticate, or --insecure to serve it unencrypted to anyone")
    return None


def stop_on_signals(stop: threading.Event, signals=(signal.SIGINT, signal.SIGTERM)) -> None:
    """Set ``stop`` when one of ``signals`` arrives. Call from the main thread.

    A Python signal handler runs in the main thread between two bytecodes, possibly while
    that thread holds ``stop``'s lock inside ``Event.wait``, or inside an earlier handler's
    ``stop.set()`` (a child whose parent dies can get its parent-death SIGTERM more than
    once). A handler calling ``stop.set()`` then deadlocks. So the handlers do nothing, and
    Python's C-level handler writes each signal's number to a wakeup pipe
    (``signal.set_wakeup_fd``); a daemon thread reads it and sets ``stop``.
    """
    wanted = {int(sig) for sig in signals}
    read_fd, write_fd = os.pipe()
    os.set_blocking(write_fd, False)
    for sig in signals:
        signal.signal(sig, lambda *_: None)  # a Python handler, so the signal no longer kills the process
    signal.set_wakeup_fd(write_fd, warn_on_full_buffer=False)

    def watch() -> None:
        while True:
            received = os.read(read_fd, 64)
            if not received or wanted.intersection(received):
                stop.set()
                return

    threading.Thread(target=watch, name="stop on signal", daemon=True).start()
