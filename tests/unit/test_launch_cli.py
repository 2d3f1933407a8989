"""launch_scripts.cli: shared pieces of the launch scripts' command lines."""

import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from launch_scripts.cli import OneLineParser, positive_int

REPO = Path(__file__).resolve().parents[2]

# Waits on the event in a tight loop, so a signal often lands while the main thread holds
# the event's lock: where a handler calling stop.set() deadlocks.
WAITER = textwrap.dedent("""
    import sys
    import threading
    from launch_scripts.cli import stop_on_signals
    stop = threading.Event()
    stop_on_signals(stop)
    print("ready", flush=True)
    while not stop.wait(0.0005):
        pass
    print("stopped", flush=True)
    sys.stdin.read()  # exit only after the whole burst: at shutdown Python restores the default handlers
""")


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_a_burst_of_signals_stops_a_process_waiting_on_the_event(sig):
    for _ in range(5):
        proc = subprocess.Popen([sys.executable, "-c", WAITER], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                                cwd=REPO, env={**os.environ, "PYTHONPATH": str(REPO)})
        try:
            assert proc.stdout.readline().strip() == "ready"
            for _ in range(50):  # a parent-death signal can come more than once
                proc.send_signal(sig)
            out, _ = proc.communicate(timeout=20)  # closes stdin: the waiter may exit now
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
        assert proc.returncode == 0 and out.strip() == "stopped"


def test_usage_errors_are_one_line(capsys):
    parser = OneLineParser(prog="tool")
    parser.add_argument("--n", type=positive_int)
    with pytest.raises(SystemExit) as stop:
        parser.parse_args(["--n", "0"])
    assert stop.value.code == 2
    assert capsys.readouterr().err == "tool: error: argument --n: expected a positive integer, got 0\n"
