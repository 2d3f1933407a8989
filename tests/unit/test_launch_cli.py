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


def test_tracker_options_come_from_the_config_fields():
    import dataclasses

    from launch_scripts import perception_service, track
    from launch_scripts.cli import field_docs
    from perception.tracker import TrackerConfig

    docs = field_docs(TrackerConfig)
    scalar = [f.name for f in dataclasses.fields(TrackerConfig)
              if isinstance(getattr(TrackerConfig(), f.name), (bool, int, float, str, tuple))]
    assert set(scalar) <= set(docs), "every field the command line offers is described in the docstring"
    for parser in (track.build_parser(), perception_service.build_parser()):
        dests = {a.dest: a for a in parser._actions}
        assert set(scalar) <= set(dests)
        assert docs["lambda_d"] in dests["lambda_d"].help and "(default 0.6)" in dests["lambda_d"].help
        assert "realtime 6" in dests["max_iterations"].help
    parse = track.build_parser().parse_args
    from launch_scripts.cli import tracker_config_from_args

    # the options the command lines have always had keep their names and meaning
    config = tracker_config_from_args(parse(["SEQ", "-o", "x.npz", "--spacing-m", "0.015", "--no-boundary",
                                             "--features", "klt", "--lambda-c", "2", "--max-iterations", "3"]))
    assert config == TrackerConfig(spacing_m=0.015, use_boundary=False, features="klt", lambda_c=2.0, max_iterations=3)
    config = tracker_config_from_args(parse(["SEQ", "-o", "x.npz", "--preset", "realtime", "--no-depth",
                                             "--outlier-radii-m", "0.1", "0.03"]))
    assert config == TrackerConfig.realtime(use_depth=False, outlier_radii_m=(0.1, 0.03))
    assert tracker_config_from_args(parse(["SEQ", "-o", "x.npz"])) == TrackerConfig()
    with pytest.raises(ValueError, match="lambda_d: expected a non-negative number"):
        tracker_config_from_args(parse(["SEQ", "-o", "x.npz", "--lambda-d", "-1"]))
    # an offline run may spend more on a frame than the service takes over the wire...
    assert tracker_config_from_args(parse(["SEQ", "-o", "x.npz", "--max-iterations", "150"])).max_iterations == 150
    # ...but not a mesh spacing that would take hours (0.1 mm) or give a handful of vertices (5 m)
    for spacing in ("0.0001", "5"):
        with pytest.raises(ValueError, match=f"--spacing-m: expected a value in 0 or \\[0.005, 1\\], got {spacing}"):
            tracker_config_from_args(parse(["SEQ", "-o", "x.npz", "--spacing-m", spacing]))


def test_field_docs_read_grouped_and_continued_entries():
    from launch_scripts.cli import field_docs

    class Example:
        """Summary.

        a, b : weights
            of two things
        c : one thing
        """

    assert field_docs(Example) == {"a": "weights of two things", "b": "weights of two things", "c": "one thing"}


def test_entry_points_share_their_flag_names():
    from launch_scripts import (
        convert_recording,
        perception_service,
        planner_service,
        publish_frames,
        record_scene,
        track,
        trials,
    )

    def options(parser):
        found = {o for a in parser._actions for o in a.option_strings}
        for sub in (a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction"):
            for p in sub.choices.values():
                found |= {o for a in p._actions for o in a.option_strings}
        return found

    for module in (convert_recording, perception_service, planner_service, publish_frames, record_scene, track, trials):
        assert "--log-level" in options(module.build_parser()), module.__name__
    for module in (perception_service, planner_service, publish_frames):
        found = options(module.build_parser())
        assert {"--print-endpoints", "--print-endpoint"} <= found and "-v" not in found, module.__name__
    args = planner_service.build_parser().parse_args(["--print-endpoint", "--log-level", "WARNING"])
    assert args.print_endpoints and args.log_level == "WARNING"


@pytest.mark.parametrize("text, ok", [
    ("tcp://127.0.0.1:5562", True), ("tcp://127.0.0.1:*", True), ("tcp://[::1]:5562", True), ("ipc:///tmp/x", True),
    ("inproc://frames", True), ("tcp://127.0.0.1:0", True), ("tcp://*:5560", True), ("tcp://eth0:5560", True),
    ("tcp://127.0.0.1:99999", False), ("tcp://127.0.0.1", False), ("tcp://[::1]", False), ("tcp://:5562", False),
    ("127.0.0.1:5562", False), ("tcp://host:http", False), ("tcp://127.0.0.1:-1", False),
])
def test_an_endpoint_zeromq_would_take_for_another_is_refused(text, ok):
    from ipc.endpoints import check_endpoint

    if ok:
        assert check_endpoint(text) == text
    else:
        with pytest.raises(ValueError, match="expected"):
            check_endpoint(text)


@pytest.mark.parametrize("module, option", [("perception_service", "--control"), ("perception_service", "--frames"),
                                            ("perception_service", "--estimates"), ("planner_service", "--bind"),
                                            ("planner_service", "--estimates")])
def test_the_services_refuse_a_port_out_of_range_in_one_line(module, option, capsys):
    import importlib

    parser = importlib.import_module(f"launch_scripts.{module}").build_parser()
    with pytest.raises(SystemExit) as e:
        parser.parse_args([option, "tcp://127.0.0.1:99999"])
    assert e.value.code == 2
    assert capsys.readouterr().err.strip().endswith(
        f"error: argument {option}: expected a port in 0-65535 or *, got '99999' in 'tcp://127.0.0.1:99999'")


def test_the_perception_service_refuses_to_reinitialise_after_lost_frames_without_automatic_initialisation(capsys):
    from launch_scripts import perception_service

    with pytest.raises(SystemExit) as stop:
        perception_service.main(["--no-auto-init", "--reinit-after-lost", "3"])
    assert stop.value.code == 2
    assert "--reinit-after-lost re-initialises by itself, which --no-auto-init rules out" in capsys.readouterr().err


def test_an_endpoint_no_other_process_can_reach_is_refused_on_the_command_line(capsys):
    from launch_scripts import perception_service, publish_frames

    for parser, argv in ((publish_frames.build_parser(), ["sequence", "seq", "--endpoint", "inproc://frames"]),
                         (perception_service.build_parser(), ["--frames", "inproc://frames"])):
        with pytest.raises(SystemExit) as e:
            parser.parse_args(argv)
        assert e.value.code == 2
        err = capsys.readouterr().err.strip()
        assert "inproc://frames: an inproc:// endpoint is reached only from inside this process; use tcp:// or ipc://" \
            in err and len(err.splitlines()) == 1


def test_a_simulated_camera_too_large_to_render_is_refused_in_one_line(capsys):
    from launch_scripts import publish_frames

    assert publish_frames.main(["sim", "--width", "100000", "--height", "100000", "--max-frames", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == "error: camera size: expected at most 4096x4096 pixels, got 100000x100000"
