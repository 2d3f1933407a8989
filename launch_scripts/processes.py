"""The child processes an entry point starts (a trial's services, the pipeline's publisher
and service): started with a bounded wait for readiness, always stopped.

Each child is ``python -m MODULE ARGS`` that prints the endpoints it bound as one JSON
line on stdout once ready (``--print-endpoints``). Its stderr goes to a log file, or to
this process's stderr. On Linux the kernel sends a child SIGTERM when the process that
started it dies (``launch_scripts._child`` asks for it after exec, not in a
``preexec_fn``, which may deadlock once this process has threads), so no child outlives
a killed parent; ``Children.stop_all`` stops them on every normal exit path.
"""

from __future__ import annotations

import json
import logging
import os
import select
import subprocess
import sys
import time
from pathlib import Path
from typing import Self

log = logging.getLogger(__name__)

#: Seconds a child may take to bind its sockets (imports of NumPy, OpenCV, SciPy on a
#: loaded machine included).
STARTUP_TIMEOUT_S = 90.0
#: Seconds a child gets to stop after SIGTERM before it is killed.
STOP_TIMEOUT_S = 5.0


class ChildError(RuntimeError):
    """A child did not start, or ended early; the message is one line with its last log line."""


def _last_line(path: Path) -> str:
    try:
        lines = [line.strip() for line in path.read_text(errors="replace").splitlines() if line.strip()]
    except OSError:
        return ""
    return lines[-1][:300] if lines else ""


class Children:
    """A group of child processes.

    log_dir : folder for each child's stderr (``NAME.log``), or None for this process's stderr
    startup_timeout_s : default of ``start``'s ``timeout_s``
    Use as a context manager: every child still running is stopped on exit.
    """

    def __init__(self, log_dir: Path | None, startup_timeout_s: float = STARTUP_TIMEOUT_S):
        self.log_dir = None if log_dir is None else Path(log_dir)
        self.startup_timeout_s = startup_timeout_s
        self.procs: dict[str, subprocess.Popen] = {}
        self._logs: dict[str, Path] = {}

    def start(self, name: str, module: str, args: list[str], timeout_s: float | None = None) -> dict:
        """Start ``python -m module args`` and return the endpoints it prints once ready.

        raises ChildError when it exits or prints nothing within ``timeout_s`` (default
        ``startup_timeout_s``)
        """
        timeout_s = self.startup_timeout_s if timeout_s is None else timeout_s
        command = [sys.executable, "-m", "launch_scripts._child", str(os.getpid()), module, *args]
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        if self.log_dir is None:
            proc = subprocess.Popen(command, stdout=subprocess.PIPE, stdin=subprocess.DEVNULL, text=True, env=env)
        else:
            self.log_dir.mkdir(parents=True, exist_ok=True)
            self._logs[name] = self.log_dir / f"{name}.log"
            with open(self._logs[name], "w") as err:
                proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=err, stdin=subprocess.DEVNULL,
                                        text=True, env=env)
        self.procs[name] = proc
        log.debug("started %s (pid %d): %s", name, proc.pid, " ".join(command))
        ready, _, _ = select.select([proc.stdout], [], [], timeout_s)
        line = proc.stdout.readline() if ready else ""
        if not line:
            # End of stdout means the child is exiting; give it a moment to be reaped so its
            # status, not a time-out, is reported.
            try:
                status = proc.wait(timeout=5.0) if ready else proc.poll()
            except subprocess.TimeoutExpired:
                status = None
            why = f"exited with status {status}" if status is not None else f"printed no endpoint within {timeout_s:.0f} s"
            raise ChildError(f"{name} {why}: {self._last_words(name)}")
        try:
            return json.loads(line)
        except json.JSONDecodeError:
            raise ChildError(f"{name} printed {line.strip()[:100]!r}, not its endpoints as JSON") from None

    def check(self) -> None:
        """Raise ChildError if a child has ended."""
        for name, proc in self.procs.items():
            if proc.poll() is not None:
                raise ChildError(f"{name} exited with status {proc.returncode}: {self._last_words(name)}")

    def _last_words(self, name: str) -> str:
        """The last line a child wrote to its log, for an error message."""
        if name not in self._logs:
            return "see its messages above"
        return _last_line(self._logs[name]) or "no message"

    def stop_all(self) -> None:
        """SIGTERM every child still running, then SIGKILL those that do not stop in time."""
        for proc in self.procs.values():
            if proc.poll() is None:
                proc.terminate()
        deadline = time.monotonic() + STOP_TIMEOUT_S
        for name, proc in self.procs.items():
            try:
                proc.wait(timeout=max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                log.warning("%s (pid %d) did not stop within %.0f s; killed", name, proc.pid, STOP_TIMEOUT_S)
                proc.kill()
                proc.wait()
            if proc.stdout is not None:
                proc.stdout.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc) -> None:
        self.stop_all()
