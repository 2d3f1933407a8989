"""What every launch script shares: one-line usage errors, checked numbers, the tracker's
options, CURVE options, and stopping on a signal."""

from __future__ import annotations

import argparse
import dataclasses
import functools
import inspect
import json
import logging
import math
import os
import re
import signal
import sys
import threading
from pathlib import Path

import launch_scripts
from ipc.endpoints import check_endpoint, is_loopback


class OneLineParser(argparse.ArgumentParser):
    """argparse, but a usage error is one line on stderr (no usage block) and exit status 2,
    so a supervisor's log shows what was wrong without scrolling."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message}\n")

    def parse_known_args(self, args=None, namespace=None):
        launch_scripts.loaded()  # a command parses its arguments once its modules have loaded
        return super().parse_known_args(args, namespace)


#: The levels of ``--log-level``.
LOG_LEVELS = ("DEBUG", "INFO", "WARNING", "ERROR")
LOG_FORMAT = "%(asctime)s %(levelname)s %(name)s: %(message)s"


def add_log_level_argument(parser, default: str = "WARNING") -> None:
    """``--log-level LEVEL``, the same in every entry point (``configure_logging`` applies it)."""
    parser.add_argument("--log-level", choices=LOG_LEVELS, default=default,
                        help=f"log messages from this level up, on stderr (default {default})")


def configure_logging(level: str, fmt: str = LOG_FORMAT) -> None:
    """Send the log to stderr from ``level`` up; only entry points configure logging."""
    logging.basicConfig(level=level, format=fmt)


def endpoint_printer(args, name: str):
    """The ``on_bound`` callback of a service or publisher: with ``--print-endpoints`` it prints
    ``{name: endpoint}`` as one JSON line on stdout, else nothing."""

    def print_endpoint(endpoint: str) -> None:
        if args.print_endpoints:
            print(json.dumps({name: endpoint}), flush=True)

    return print_endpoint


def add_print_endpoints_argument(parser, printed: str) -> None:
    """``--print-endpoints``: print the endpoints bound (``printed``, a JSON object's keys) as one
    JSON line on stdout once ready. ``--print-endpoint`` is the same option's earlier name
    in docs/protocol.md, kept so that existing controllers' command lines still work."""
    parser.add_argument("--print-endpoints", "--print-endpoint", dest="print_endpoints", action="store_true",
                        help=f"print {printed} as one JSON line on stdout once ready")


def _integer_from(lo: int, what: str):
    """An argparse type: an integer >= ``lo``, ``what`` naming it in the error."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
        if value < lo:
            raise argparse.ArgumentTypeError(f"expected {what}, got {value}")
        return value

    return parse


#: argparse types: an integer >= 1, and an integer >= 0.
positive_int = _integer_from(1, "a positive integer")
non_negative_int = _integer_from(0, "a non-negative integer")


def finite_float(text: str) -> float:
    """argparse type: a finite number."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return value


def endpoint(text: str) -> str:
    """argparse type: a ZeroMQ endpoint to bind or connect (``ipc.endpoints.check_endpoint``)
    that another process can reach: not ``inproc://``, which only sockets of the same process
    (one ZeroMQ context) reach, so that a command bound there would serve nobody."""
    if text.startswith("inproc://"):
        raise argparse.ArgumentTypeError(f"{text}: an inproc:// endpoint is reached only from inside this process; "
                                         "use tcp:// or ipc://")
    try:
        return check_endpoint(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def non_negative_float(text: str) -> float:
    """argparse type: a finite number >= 0."""
    value = finite_float(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {text}")
    return value


def positive_float(text: str) -> float:
    """argparse type: a finite number > 0."""
    value = finite_float(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"expected a number > 0, got {text}")
    return value


def output_problem(path, is_file: bool) -> str | None:
    """Why a command could not write its output ``path`` (a file when ``is_file``, else a folder
    to write files in), or None when it can: checked, and the folder made, before the work
    that produces the output, so that a long run does not fail at its end."""
    path = Path(path)
    folder = path.parent if is_file else path
    if is_file and path.is_dir():
        return "is a folder, expected a file"
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        return f"{folder} is a file, expected a folder" if is_file else "is a file, expected a folder"
    except OSError as e:
        return f"cannot make the folder {folder} ({e.strerror or e})" if is_file else \
            f"cannot make this folder ({e.strerror or e})"
    if not os.access(folder, os.W_OK | os.X_OK) or (is_file and path.exists() and not os.access(path, os.W_OK)):
        return "cannot write there"
    return None


def field_docs(cls) -> dict[str, str]:
    """Field name -> description, from a dataclass's docstring, which lists its fields as
    ``name : text`` or ``name_a, name_b : text`` lines, a description going on over the
    more indented lines below it. Fields the docstring does not describe are left out."""
    docs, names = {}, []
    for line in inspect.cleandoc(cls.__doc__ or "").splitlines():
        entry = re.match(r"^(\w+(?:, \w+)*) : (.*)$", line)
        if entry:
            names = entry.group(1).split(", ")
            for name in names:
                docs[name] = entry.group(2).strip()
        elif names and line.startswith(" ") and line.strip():
            for name in names:
                docs[name] += " " + line.strip()
        else:
            names = []
    return docs


#: The tracker's presets: the paper's settings (``TrackerConfig()``) and ``TrackerConfig.realtime()``.
TRACKER_PRESETS = ("paper", "realtime")


def add_tracker_arguments(parser: argparse.ArgumentParser, default_preset: str = "paper") -> None:
    """One option per field of ``perception.tracker.TrackerConfig`` (help from its docstring),
    and ``--preset``; ``tracker_config_from_args`` reads them back.

    A number or string field ``name_x`` is ``--name-x VALUE`` (a field with choices offers
    them), a tuple of numbers ``--name-x V [V ...]``, a bool ``use_x`` is ``--x`` /
    ``--no-x`` and any other bool ``name_x`` is ``--name-x`` / ``--no-name-x``. An option
    not given keeps the preset's value; nested settings (``segmentation``) keep theirs.
    """
    from perception.tracker import TrackerConfig

    g = parser.add_argument_group("tracker", "TrackerConfig's fields; an option not given keeps the preset's value")
    g.add_argument("--preset", choices=TRACKER_PRESETS, default=default_preset,
                   help=f"paper: SIFT/SURF features, the paper's iterations; realtime: KLT, fewer iterations "
                        f"(default {default_preset})")
    docs = field_docs(TrackerConfig)
    paper, realtime = TrackerConfig(), TrackerConfig.realtime()

    def shown(value) -> str:
        if isinstance(value, bool):
            return "on" if value else "off"
        if isinstance(value, tuple):
            return " ".join(shown(v) for v in value)
        return f"{value:g}" if isinstance(value, float) else str(value)

    for f in dataclasses.fields(TrackerConfig):
        default, fast = getattr(paper, f.name), getattr(realtime, f.name)
        values = shown(default) if default == fast else f"{shown(default)}; realtime {shown(fast)}"
        text = f"{docs.get(f.name, '')} (default {values})".replace("%", "%%")  # argparse formats help with %
        option = f"--{f.name.replace('_', '-')}"
        if isinstance(default, bool):
            flag = f.name.removeprefix("use_").replace("_", "-")
            g.add_argument(f"--{flag}", dest=f.name, action=argparse.BooleanOptionalAction, default=None, help=text)
        elif isinstance(default, (int, float, str)):
            kind = {int: int, float: finite_float, str: str}[type(default)]
            choices = f.metadata.get("choices")
            g.add_argument(option, dest=f.name, type=kind, default=None, choices=choices,
                           metavar=None if choices else "X", help=text)
        elif isinstance(default, tuple) and all(isinstance(v, float) for v in default):
            g.add_argument(option, dest=f.name, type=finite_float, nargs="+", default=None, metavar="X", help=text)


def tracker_config_from_args(args):
    """The ``perception.tracker.TrackerConfig`` of the options of ``add_tracker_arguments``: the
    preset with the options given. raises ValueError (one line) for a value the tracker refuses."""
    from perception.parameters import PARAMETER_RANGES
    from perception.tracker import TrackerConfig

    overrides = {}
    for f in dataclasses.fields(TrackerConfig):
        value = getattr(args, f.name, None)
        if value is not None:
            # the service's range for the mesh spacing: 5 m or 0.1 mm would not be refused by
            # the tracker, only make it work for hours (the other options may go beyond what the
            # service takes over the wire: an offline run may spend more time on each frame)
            if f.name == "spacing_m" and value not in PARAMETER_RANGES["spacing_m"]:
                raise ValueError(f"--spacing-m: expected a value in {PARAMETER_RANGES['spacing_m']}, got {value:g}")
            overrides[f.name] = tuple(value) if isinstance(value, list) else value
    return TrackerConfig.realtime(**overrides) if args.preset == "realtime" else TrackerConfig(**overrides)


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


def exit_130_on_ctrl_c(main):
    """Wrap a script's ``main(argv) -> int``: Ctrl-C (KeyboardInterrupt) anywhere in it ends it with
    the one line ``interrupted`` on stderr and exit status 130 (128 + SIGINT), not a traceback.
    ``main``'s own ``except``/``finally`` clauses (its clean-up) run first."""

    @functools.wraps(main)
    def run(*args, **kwargs):
        try:
            return main(*args, **kwargs)
        except KeyboardInterrupt:
            print("interrupted", file=sys.stderr, flush=True)
            return 130

    return run
