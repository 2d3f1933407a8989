"""What the launch scripts say to a user who interrupts them or asks for help: one line, no traceback."""

import argparse

import numpy as np
import pytest

from ipc.messages import CameraInfo
from launch_scripts.cli import exit_130_on_ctrl_c


def test_ctrl_c_ends_a_wrapped_main_with_one_line_and_status_130(capsys):
    cleaned = []

    @exit_130_on_ctrl_c
    def main(argv=None) -> int:
        """The script's main."""
        try:
            raise KeyboardInterrupt
        finally:
            cleaned.append(argv)

    assert main(["x"]) == 130 and cleaned == [["x"]]
    assert capsys.readouterr() == ("", "interrupted\n")
    assert main.__doc__ == "The script's main."
    assert exit_130_on_ctrl_c(lambda argv: 7)([]) == 7
    with pytest.raises(SystemExit):  # usage errors and --help still end as argparse ends them
        exit_130_on_ctrl_c(lambda argv: argparse.ArgumentParser().parse_args(argv))(["--nope"])


def test_ctrl_c_while_a_command_loads_is_one_line_too(tmp_path):
    import signal
    import subprocess
    import sys
    import time

    # The trial command takes most of a second to load its modules (PyBullet, OpenCV, SciPy):
    # interrupted a fifth of a second in, it is still loading them. Ctrl-C reaches it as from a
    # terminal even where the tests run in the background (whose children inherit SIGINT ignored).
    child = subprocess.Popen([sys.executable, "-m", "launch_scripts.trials", "--seeds", "0", "--json", "report.json"],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path,
                             preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    time.sleep(0.2)
    child.send_signal(signal.SIGINT)
    out, err = child.communicate(timeout=60)
    assert "Traceback" not in err and err.strip() in ("interrupted", ""), err
    assert child.returncode in (130, -signal.SIGINT), child.returncode  # the shell's 130 either way


def test_ctrl_c_a_library_swallows_while_loading_still_interrupts_the_command():
    import signal
    import subprocess
    import sys

    # A library that catches everything while it loads (numpy.random's compiled module does, for a
    # moment) must not make the command run on as if Ctrl-C had not been pressed.
    script = """
import os, signal, sys, time
sys.argv = ["-m"]
import launch_scripts
try:  # a library loading, which swallows the KeyboardInterrupt
    os.kill(os.getpid(), signal.SIGINT)
    time.sleep(1)
except BaseException:
    pass
from launch_scripts.cli import OneLineParser
OneLineParser().parse_args([])
print("ran on")
"""
    child = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60,
                           preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    assert "ran on" not in child.stdout
    assert child.stderr.strip() == "interrupted", child.stderr
    assert child.returncode == -signal.SIGINT


def test_track_demo_describes_every_option(capsys):
    from launch_scripts.track_demo import build_parser

    parser = build_parser()
    undescribed = [a.option_strings for a in parser._actions if not a.help]
    assert undescribed == []
    help_text = " ".join(parser.format_help().split())
    assert "(default towel_sway)" in help_text and "(default 60)" in help_text and "(default out/track_demo)" in help_text


def test_track_demo_ctrl_c_is_one_line_and_status_130(tmp_path, capsys, monkeypatch):
    from launch_scripts import track_demo

    def interrupted(argv):
        raise KeyboardInterrupt

    monkeypatch.setattr(track_demo.record_scene, "main", interrupted)
    assert track_demo.main(["--out", str(tmp_path / "demo")]) == 130
    assert capsys.readouterr().err == "interrupted\n"


def test_publish_frames_rate_pacing_needs_a_rate(capsys):
    from launch_scripts.publish_frames import main

    with pytest.raises(SystemExit) as stop:
        main(["sim", "--pacing", "rate"])
    assert stop.value.code == 2
    assert capsys.readouterr().err == ("python -m launch_scripts.publish_frames: error: --pacing rate needs --rate-hz HZ "
                                       "(frames per second)\n")


@pytest.mark.parametrize("args, message", [
    (["--pacing", "rate", "--rate-hz", "0"], "argument --rate-hz: expected a number > 0, got 0"),
    (["--rate-hz", "5"], "--rate-hz goes with --pacing rate"),  # silently ignored before
])
def test_publish_frames_takes_a_positive_rate_and_only_to_pace_by_it(args, message, capsys):
    from launch_scripts.publish_frames import main

    with pytest.raises(SystemExit) as stop:
        main(["sim", *args])
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("python -m launch_scripts.publish_frames") and err.endswith(f"error: {message}\n")
    assert err.count("\n") == 1


def test_reference_masks_names_the_seed_mask_option(tmp_path, capsys):
    from launch_scripts.reference_masks import main
    from tests.render import write_sheet_recording

    write_sheet_recording(tmp_path / "seq", CameraInfo.from_fov(160, 120, np.deg2rad(45)), 2, 0.01)
    (tmp_path / "text.png").write_text("not an image")
    for seed, problem in ((tmp_path / "nope.png", "no such file"), (tmp_path / "text.png", "not a readable image")):
        assert main([str(tmp_path / "seq"), "--seed-mask", str(seed), "--replace", "-q"]) == 2
        assert capsys.readouterr().err == f"error: --seed-mask {seed}: {problem}\n"


def test_track_demo_scores_the_frames_of_the_first_mesh_when_a_new_one_is_laid(tmp_path, monkeypatch, capsys):
    import json

    import launch_scripts.track as track
    from launch_scripts import track_demo
    from perception.tracker import MeshTracker

    class LaysANewMesh(MeshTracker):
        """Lays a new mesh on the third frame, as a tracker that found a plain cloth again does."""

        def track(self, frame):
            return self.initialise(frame) if frame.seq == 2 else super().track(frame)

    monkeypatch.setattr(track, "MeshTracker", LaysANewMesh)
    assert track_demo.main(["--frames", "4", "--out", str(tmp_path)]) == 0  # a NaN traceback before
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["frames"] == 4 and summary["frames_scored"] == 2 and summary["mean_mm"] < 5
    assert "laid a new mesh at frame 2: frames 0-1 are scored" in capsys.readouterr().out
