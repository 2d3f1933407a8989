"""Child processes of a trial: started with a bounded wait for readiness, always stopped.

Each child is ``python -m MODULE ARGS`` that prints the endpoints it bound as one JSON
line on stdout once ready (``perception_service --print-endpoints``,
``planner_service --print-endpoint``). Its stderr goes to a log file. On Linux the
kernel sends a child SIGTERM when the process that started it dies (``_child``), so no
child outlives a killed trial; ``Children.stop_all`` stops them on every normal exit path.
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
    """The child processes of one trial.

    log_dir : folder for each child's stderr (``NAME.log``)
    Use as a context manager: every child still running is stopped on exit.
    """

    def __init__(self, log_dir: Path):
        self.log_dir = Path(log_dir)
        self.procs: dict[str, subprocess.Popen] = {}
        self._logs: dict[str, Path] = {}

    def start(self, name: str, module: str, args: list[str], timeout_s: float = STARTUP_TIMEOUT_S) -> dict:
        """Start ``python -m module args`` and return the endpoints it prints once ready.

        raises ChildError when it exits or prints nothing within ``timeout_s``
        """
        self.log_dir.mkdir(parents=True, exist_ok=True)
        log_path = self.log_dir / f"{name}.log"
        self._logs[name] = log_path
        command = [sys.executable, "-m", "launch_scripts.trial_runner._child", str(os.getpid()), module, *args]
        with open(log_path, "w") as err:
            proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=err, stdin=subprocess.DEVNULL, text=True,
                                    env={**os.environ, "PYTHONUNBUFFERED": "1"})
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
            raise ChildError(f"{name} {why}: {_last_line(log_path) or 'no message'}")
        try:
            return json.loads(line)
        except json.JSONDecodeError:
            raise ChildError(f"{name} printed {line.strip()[:100]!r}, not its endpoints as JSON") from None

    def check(self) -> None:
        """Raise ChildError if a child has ended."""
        for name, proc in self.procs.items():
            if proc.poll() is not None:
                raise ChildError(f"{name} exited with status {proc.returncode}: {_last_line(self._logs[name]) or 'no message'}")

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
