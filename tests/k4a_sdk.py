"""The Azure Kinect SDK beside the test suite: a virtual environment and an X display.

The one package on PyPI that ships the SDK's native libraries, pyk4a-bundle 1.5.0 (pyk4a with
libk4a and libk4arecord 1.4.2 and the depth engine), was built against NumPy 1 and does not
import beside the NumPy 2 the suite runs on. ``sdk_python()`` builds, once, a virtual
environment with it, NumPy 1 and what ``perception.sources`` imports (OpenCV, msgpack, pyzmq),
in the user's cache folder, and returns its interpreter; code that needs the SDK runs there in
a subprocess with the repository on its path.

SDK 1.4 transforms depth into the colour camera with OpenGL through an X display:
``x_display()`` starts a private Xvfb server (Mesa's software OpenGL serves).
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import select
import shutil
import subprocess
import sys
from pathlib import Path

#: What the environment holds. OpenCV wheels from 4.12 on need NumPy 2; 4.8 to 4.11 take NumPy 1.
REQUIREMENTS = ("pyk4a-bundle==1.5.0", "numpy>=1.24,<2", "opencv-python-headless>=4.8,<4.12", "msgpack>=1.0",
                "pyzmq>=25")
#: The environment can run our sources with the SDK when this runs in it.
PROBE = "import cv2, msgpack, numpy, zmq; from pyk4a import PyK4APlayback"


class Unavailable(RuntimeError):
    """The SDK cannot run here; the message says why, in one line."""


def cache_root() -> Path:
    """``$XDG_CACHE_HOME/clothkit``, by default ``~/.cache/clothkit``."""
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "clothkit"


def sdk_python(root: Path | None = None, timeout_s: float = 900.0) -> Path:
    """The interpreter of the SDK's environment, built with pip on first use and reused.

    root : folder for environments (default ``cache_root()``); each is named by a hash of this
        interpreter's version and REQUIREMENTS, and marked complete only once it works
    raises Unavailable when the environment cannot be built or does not import the SDK
    """
    key = hashlib.sha256(repr((sys.version, sys.platform, REQUIREMENTS)).encode()).hexdigest()[:12]
    venv = (root or cache_root()) / f"k4a-venv-{key}"
    python, complete = venv / "bin" / "python", venv / "complete"
    if complete.exists() and _works(python):
        return python
    shutil.rmtree(venv, ignore_errors=True)
    venv.parent.mkdir(parents=True, exist_ok=True)
    _run([sys.executable, "-m", "venv", str(venv)], "python -m venv", timeout_s)
    _run([str(python), "-m", "pip", "install", "--quiet", "--disable-pip-version-check", *REQUIREMENTS],
         f"pip install {' '.join(REQUIREMENTS)}", timeout_s)
    if not _works(python):
        raise Unavailable(f"the SDK's environment {venv} does not import pyk4a with its libraries")
    complete.write_text("\n".join(REQUIREMENTS) + "\n")
    return python


def _works(python: Path) -> bool:
    try:
        return subprocess.run([str(python), "-c", PROBE], capture_output=True, timeout=120).returncode == 0
    except (OSError, subprocess.TimeoutExpired):
        return False


def _run(cmd: list[str], what: str, timeout_s: float) -> None:
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s)
    except (OSError, subprocess.TimeoutExpired) as e:
        raise Unavailable(f"cannot build the SDK's environment: {what}: {e}") from None
    if proc.returncode != 0:
        lines = (proc.stderr or proc.stdout).strip().splitlines()
        raise Unavailable(f"cannot build the SDK's environment: {what} failed: {lines[-1] if lines else proc.returncode}")


@contextlib.contextmanager
def x_display(timeout_s: float = 30.0):
    """A private X display (``":N"``) from Xvfb, for as long as the context lasts.

    raises Unavailable when Xvfb is not installed or does not start
    """
    if shutil.which("Xvfb") is None:
        raise Unavailable("Xvfb is not installed (Debian: apt-get install xvfb), and the SDK's depth "
                          "transformation needs an X display")
    read_fd, write_fd = os.pipe()
    with os.fdopen(read_fd) as numbers:
        try:  # -displayfd: Xvfb takes the first free display number and writes it to that descriptor
            server = subprocess.Popen(["Xvfb", "-displayfd", str(write_fd), "-screen", "0", "64x64x24",
                                       "-nolisten", "tcp"], pass_fds=(write_fd,), stdout=subprocess.DEVNULL,
                                      stderr=subprocess.DEVNULL)
        except OSError as e:
            raise Unavailable(f"Xvfb does not start: {e}") from None
        finally:
            os.close(write_fd)
        ready, _, _ = select.select([numbers], [], [], timeout_s)
        number = numbers.readline().strip() if ready else ""
    try:
        if not number.isdigit():
            raise Unavailable(f"Xvfb did not start within {timeout_s:g} s")
        yield f":{number}"
    finally:
        server.terminate()
        try:
            server.wait(timeout=10)
        except subprocess.TimeoutExpired:
            server.kill()
            server.wait()
