"""Judging trials by ground truth, Wilson intervals, the empty-table mask, reports, the runner's arguments."""

import json
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest

from ipc.messages import CameraInfo, RGBDFrame
from launch_scripts.trial_runner.report import failure_kind, markdown, report, summarise, wilson_interval
from sim.laundry import TOLERANCE_M, judge, mask_from_reference, rectangle_corners_uv

# A 0.5 x 0.4 m towel: corners at (0, 0), (0.5, 0), (0.5, 0.4), (0, 0.4); outline = its sides.
CORNERS, _ = rectangle_corners_uv(0.5, 0.4)
OUTLINE = np.stack([CORNERS, np.roll(CORNERS, -1, axis=0)], axis=1)


# ----------------------------------------------------------------------------- judge


@pytest.mark.parametrize("uv, corner_error", [
    ((0.0, 0.0), 0.0),
    ((0.02, 0.02), np.hypot(0.02, 0.02)),
    ((0.5, 0.371), 0.029),
    ((0.48, 0.38), np.hypot(0.02, 0.02)),
])
def test_corner_grasp_within_tolerance_and_lifted_succeeds(uv, corner_error):
    verdict = judge("corner", uv, True, CORNERS, OUTLINE)
    assert verdict.success and verdict.corner_success and verdict.reason == ""
    assert verdict.corner_error_m == pytest.approx(corner_error)


@pytest.mark.parametrize("uv", [(0.25, 0.2), (0.0, 0.2), (0.04, 0.0), (0.5 - 0.025, 0.4 - 0.025)])
def test_corner_grasp_beyond_tolerance_fails_and_says_how_far(uv):
    verdict = judge("corner", uv, True, CORNERS, OUTLINE)
    assert not verdict.success and not verdict.corner_success
    assert verdict.corner_error_m > TOLERANCE_M
    assert verdict.reason == f"grasped {100 * verdict.corner_error_m:.1f} cm from the nearest corner"


def test_a_corner_grasp_that_does_not_lift_clear_fails():
    verdict = judge("corner", (0.0, 0.0), False, CORNERS, OUTLINE)
    assert not verdict.success and not verdict.corner_success
    assert verdict.reason == "not lifted clear"
    both = judge("corner", (0.25, 0.2), False, CORNERS, OUTLINE)
    assert both.reason == "grasped 32.0 cm from the nearest corner; not lifted clear"


def test_boundary_kind_measures_the_distance_to_the_outline():
    on_edge = judge("boundary", (0.25, 0.01), True, CORNERS, OUTLINE)
    assert on_edge.success and on_edge.boundary_error_m == pytest.approx(0.01)
    assert not on_edge.corner_success  # 25 cm from a corner
    inside = judge("boundary", (0.25, 0.2), True, CORNERS, OUTLINE)
    assert not inside.success and inside.boundary_error_m == pytest.approx(0.2)
    assert inside.reason == "grasped 20.0 cm from the outline"


def test_highest_kind_succeeds_when_lifted_and_reports_the_corner_distance():
    verdict = judge("highest", (0.25, 0.2), True, CORNERS, OUTLINE)
    assert verdict.success and not verdict.corner_success
    assert verdict.corner_error_m == pytest.approx(np.hypot(0.25, 0.2))
    assert not judge("highest", (0.25, 0.2), False, CORNERS, OUTLINE).success


def test_nothing_held_is_a_miss_for_every_kind():
    for kind in ("corner", "boundary", "highest"):
        verdict = judge(kind, None, False, CORNERS, OUTLINE)
        assert not verdict.success and verdict.nearest_corner == -1 and np.isinf(verdict.corner_error_m)
        assert verdict.reason == "missed: no cloth between the fingers"


def test_judge_rejects_an_unknown_kind():
    with pytest.raises(ValueError, match="Expected kind in .*, got 'middle'"):
        judge("middle", (0.0, 0.0), True, CORNERS, OUTLINE)


# ----------------------------------------------------------------------------- Wilson


def test_wilson_interval_known_values():
    # Reference values from the closed form (Wilson 1927), z = 1.96.
    assert wilson_interval(0, 10) == pytest.approx((0.0, 0.27753), abs=1e-5)
    assert wilson_interval(10, 10) == pytest.approx((0.72247, 1.0), abs=1e-5)
    assert wilson_interval(45, 50) == pytest.approx((0.78640, 0.95653), abs=1e-5)
    assert wilson_interval(0, 0) == (0.0, 1.0)
    low, high = wilson_interval(7, 20)
    assert low < 7 / 20 < high


def test_wilson_interval_rejects_impossible_counts():
    with pytest.raises(ValueError, match="Expected 0 <= successes <= n, got successes=5, n=3"):
        wilson_interval(5, 3)


# ----------------------------------------------------------------------------- empty-table mask


def _frames(cloth: bool, rng):
    camera = CameraInfo.from_fov(80, 60, np.deg2rad(60))
    rgb = np.full((60, 80, 3), 150, np.uint8)
    depth = np.full((60, 80), 1.2, np.float32)
    if cloth:
        rgb[20:40, 30:60] = (175, 160, 140)  # a pale cloth on a grey table: 25 levels of contrast
        rgb[25:28, 35:50] = 150  # a printed stripe in the table's colour, inside the cloth
        depth[20:40, 30:60] -= 0.004  # a few millimetres thick: depth cannot tell
    rgb = np.clip(rgb + rng.normal(0, 2, rgb.shape), 0, 255).astype(np.uint8)
    return RGBDFrame(rgb=rgb, depth_m=depth, camera=camera)


def test_mask_from_reference_finds_a_thin_pale_cloth_and_fills_its_print():
    rng = np.random.default_rng(0)
    mask = mask_from_reference(_frames(True, rng), _frames(False, rng))
    truth = np.zeros((60, 80), bool)
    truth[20:40, 30:60] = True
    assert (mask & ~truth).sum() <= 60 and (truth & ~mask).sum() <= 10  # at most a one-pixel rim more


def test_the_cloth_seen_is_the_cloth_not_the_robots_larger_arm_beside_it():
    import dataclasses

    from sim.laundry.segment import cloth_seen

    rng = np.random.default_rng(2)
    frame, reference = _frames(True, rng), _frames(False, rng)
    arm = np.zeros((60, 80), bool)
    arm[2:14, 5:75] = True  # larger than the cloth, apart from it, and in the robot's known occluder mask
    frame.rgb[arm] = (90, 90, 95)
    frame = dataclasses.replace(frame, occluder_mask=arm)
    truth = np.zeros((60, 80), bool)
    truth[20:40, 30:60] = True
    seen = cloth_seen(frame, reference)
    assert not (seen & arm).any() and (truth & ~seen).sum() <= 10 and (seen & ~truth).sum() <= 60


def test_mask_from_reference_is_empty_without_a_cloth():
    rng = np.random.default_rng(1)
    assert not mask_from_reference(_frames(False, rng), _frames(False, rng)).any()


# ----------------------------------------------------------------------------- report


RECORDS = [
    {"seed": 2, "success": True, "corner_success": True, "failure": "", "corner_error_m": 0.01,
     "scene": {"state": "flat", "cloth": "towel", "printed": True},
     "timing": {"tracking_ms": 100.0, "planning_ms": 20.0, "total_s": 10.0}},
    {"seed": 0, "success": False, "corner_success": False, "failure": "grasped 4.2 cm from the nearest corner",
     "corner_error_m": 0.042, "scene": {"state": "held", "cloth": "tshirt", "printed": False}, "timing": {"total_s": 12.0}},
    {"seed": 4, "success": False, "corner_success": False, "failure": "error: TimeoutError: no estimate of frame 3",
     "scene": {"state": "flat", "cloth": "towel", "printed": False}, "timing": {"total_s": 60.0}},
]


def test_summary_counts_rates_breakdowns_and_failures():
    s = summarise(RECORDS)
    assert s["success"]["n"] == 3 and s["success"]["successes"] == 1
    assert s["success"]["wilson_95"] == list(wilson_interval(1, 3))
    assert s["trials_that_could_not_run"] == 1
    assert s["by_state"]["flat"]["successes"] == 1 and s["by_state"]["flat"]["n"] == 2
    assert {name: (rate["successes"], rate["n"]) for name, rate in s["by_print"].items()} == \
        {"printed": (1, 1), "plain": (0, 2)}
    assert s["failures"] == {"grasped # cm from the nearest corner": 1, "error: TimeoutError": 1}
    assert s["median_corner_error_m"] == pytest.approx(0.026)


def test_report_is_sorted_json_with_the_contract_fields_and_a_markdown_summary():
    rep = report(RECORDS, "python -m launch_scripts.trials --seeds 0 2 4 --json r.json", {"kind": "corner"})
    assert [t["seed"] for t in rep["trials"]] == [0, 2, 4]
    assert rep["success_rate"] == pytest.approx(1 / 3)
    assert all("seed" in t and "success" in t for t in rep["trials"])
    json.dumps(rep)
    text = markdown(rep)
    assert "**success: 1/3 = 33.3 % (95 % Wilson interval 6.1-79.2 %)**" in text
    assert "seeds even (development)" in text and text.startswith("# Laundry-grasping trials: corner grasps")
    assert "| print | success |" in text and "| plain | 0/2 = 0.0 % " in text


def test_failure_kind_drops_numbers_and_keeps_error_types():
    assert failure_kind("grasped 12.5 cm from the nearest corner") == "grasped # cm from the nearest corner"
    assert failure_kind("error: ChildError: planner exited with status 2: boom") == "error: ChildError"
    assert failure_kind("") == ""


# ----------------------------------------------------------------------------- command line


@pytest.mark.parametrize("args, message", [
    (["--seeds", "x", "--json", "r.json"], "argument --seeds: expected a seed (integer >= 0) or START:STOP[:STEP], got 'x'"),
    (["--seeds", "-2", "--json", "r.json"], "argument --seeds: expected seeds >= 0, got '-2'"),
    (["--seeds", "0:10:0", "--json", "r.json"], "argument --seeds: expected START:STOP[:STEP] with a non-zero step"),
    (["--seeds", "5:1", "--json", "r.json"], "argument --seeds: '5:1' is an empty range"),
    (["--seeds", "0", "--json", "r.json", "--regrasp", "lowest"], "--regrasp: only the unfold task takes a second corner"),
    (["--seeds", "0", "--json", "r.json", "--workers", "0"], "argument --workers: expected a positive integer, got 0"),
    (["--seeds", "0", "--json", "r.json", "--mode", "middle"], "argument --kind/--mode: invalid choice: 'middle'"),
    (["--json", "r.json"], "the following arguments are required: --seeds"),
    (["--seeds", "0", "--json", "r.json", "--engine", "local", "--ray-address", "head:6379"],
     "error: --ray-address needs --engine ray (the local engine runs on this machine only)"),
    (["--seeds", "0", "--json", "r.json", "--ray-address", "head"],
     "argument --ray-address: expected HOST:PORT, ray://HOST:PORT or auto, got 'head'"),
    (["--seeds", "0", "--json", "r.json", "--ray-address", "head:70000"],
     "argument --ray-address: expected HOST:PORT, ray://HOST:PORT or auto, got 'head:70000'"),
])
def test_trials_bad_arguments_exit_2_with_one_line(args, message, capsys):
    from launch_scripts.trials import main

    with pytest.raises(SystemExit) as e:
        main(args)
    assert e.value.code == 2
    out, err = capsys.readouterr()
    assert out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and message in lines[0]


def test_a_bad_ray_address_in_the_environment_is_one_line_naming_it(monkeypatch, capsys):
    from launch_scripts.trials import main

    monkeypatch.setenv("RAY_ADDRESS", "head:port")
    with pytest.raises(SystemExit) as e:
        main(["--seeds", "0", "--json", "r.json", "--engine", "ray"])
    assert e.value.code == 2
    assert capsys.readouterr().err == ("python -m launch_scripts.trials: error: RAY_ADDRESS: expected HOST:PORT, "
                                       "ray://HOST:PORT or auto, got 'head:port'\n")


@pytest.mark.parametrize("engine, option, environ, expected", [
    (None, None, {}, ("local", None)),
    (None, None, {"RAY_ADDRESS": "head:6379"}, ("local", None)),  # the local engine ignores RAY_ADDRESS
    ("ray", None, {}, ("ray", None)),  # a local Ray instance
    ("ray", None, {"RAY_ADDRESS": " head:6379 "}, ("ray", "head:6379")),
    ("ray", None, {"RAY_ADDRESS": ""}, ("ray", None)),
    (None, "head:6379", {}, ("ray", "head:6379")),  # the option implies the Ray engine...
    ("ray", "ray://10.0.0.2:10001", {"RAY_ADDRESS": "other:1"}, ("ray", "ray://10.0.0.2:10001")),  # ...and wins
    ("ray", "auto", {}, ("ray", "auto")),
])
def test_engine_and_ray_address_from_options_and_environment(engine, option, environ, expected):
    from launch_scripts.trials import engine_and_address

    assert engine_and_address(engine, option, environ) == expected


@pytest.mark.parametrize("address, expected", [
    ("head:6379", ("head", 6379)), ("ray://10.0.0.2:10001", ("10.0.0.2", 10001)), ("[::1]:6379", ("::1", 6379)),
    ("head", None), ("head:0", None), (":6379", None), ("head:x", None), ("auto", None),
])
def test_host_and_port_of_a_ray_address(address, expected):
    from launch_scripts.trials import _host_port

    assert _host_port(address) == expected


def test_trials_seed_ranges():
    from launch_scripts.trials import build_parser

    args = build_parser().parse_args(["--seeds", "0:10:2", "7", "--json", "r.json"])
    assert sorted({s for group in args.seeds for s in group}) == [0, 2, 4, 6, 7, 8]


def test_trials_state_and_cloth_options_force_the_scene():
    from launch_scripts.trials import build_parser

    args = build_parser().parse_args(["--seeds", "0", "--json", "r.json", "--state", "held", "--cloth", "towel"])
    assert (args.state, args.cloth) == ("held", "towel")
    assert build_parser().parse_args(["--seeds", "0", "--json", "r.json"]).state is None


# ----------------------------------------------------------------------------- local runner


def fake_trial(seed, config):
    """A stand-in for run_trial in the runner's processes: seed 1 dies without reporting,
    seed 2 reports a record larger than a pipe's buffer."""
    import os
    import signal

    if seed == 1:
        os.kill(os.getpid(), signal.SIGKILL)
    return {"seed": seed, "kind": config.kind, "success": True, "failure": "", "payload": "x" * (200_000 if seed == 2 else 1)}


def test_a_trial_process_that_dies_is_a_failed_record_and_the_others_run(tmp_path):
    from launch_scripts.trial_runner import TrialConfig
    from launch_scripts.trials import _run_local

    seen = []
    config = TrialConfig(log_dir=str(tmp_path), scene_options={"state": "flat"})
    records = _run_local([0, 1, 2, 3], config, workers=2, progress=seen.append, trial=fake_trial)
    by_seed = {r["seed"]: r for r in records}
    assert sorted(by_seed) == [0, 1, 2, 3] and len(seen) == 4
    assert by_seed[1]["success"] is False
    assert by_seed[1]["failure"] == "error: WorkerDied: the trial's process ended with signal SIGKILL"
    assert by_seed[1]["scene"]["state"] == "flat"
    assert failure_kind(by_seed[1]["failure"]) == "error: WorkerDied"
    assert all(by_seed[s]["success"] for s in (0, 2, 3))
    assert len(by_seed[2]["payload"]) == 200_000


def sleeping_trial(seed, config):
    """A stand-in for run_trial that writes its pid where the test reads it, then sleeps."""
    import os
    import time

    Path(config.log_dir, f"pid{seed}").write_text(str(os.getpid()))
    time.sleep(60)
    return {"seed": seed}


def _runner(log_dir):
    """The body of a runner process that the test kills."""
    from launch_scripts.trial_runner import TrialConfig
    from launch_scripts.trials import _run_local

    _run_local([0, 1], TrialConfig(log_dir=log_dir), workers=2, progress=lambda record: None, trial=sleeping_trial)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="dying with the parent is Linux's prctl")
def test_trial_processes_die_with_a_runner_that_is_killed(tmp_path):
    import multiprocessing
    import os
    import time

    runner = multiprocessing.get_context("spawn").Process(target=_runner, args=(str(tmp_path),))
    runner.start()
    pids = []
    deadline = time.monotonic() + 60
    while len(pids) < 2 and time.monotonic() < deadline:
        pids = [int(f.read_text()) for f in tmp_path.glob("pid*") if f.read_text()]
        time.sleep(0.1)
    assert len(pids) == 2, "the trial processes did not start"
    runner.terminate()  # SIGTERM: no finally block runs in the runner
    runner.join(10)

    def alive(pid):
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return False
        # a zombie (dead, not yet reaped by init) is not running
        return Path(f"/proc/{pid}/stat").read_text().split(") ")[1][0] != "Z"

    deadline = time.monotonic() + 10
    while any(alive(pid) for pid in pids) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not any(alive(pid) for pid in pids), "trial processes outlived their runner"


# ----------------------------------------------------------------------------- Ray engine, without Ray


def test_the_shipped_packages_are_the_distributions_packages_without_bytecode():
    import tomllib

    from launch_scripts.trials import SHIPPED_PACKAGES, _shipped_packages

    pyproject = tomllib.loads((Path(__file__).resolve().parents[2] / "pyproject.toml").read_text())
    include = pyproject["tool"]["setuptools"]["packages"]["find"]["include"]
    assert sorted(SHIPPED_PACKAGES) == sorted(name.rstrip("*") for name in include)
    with _shipped_packages() as runtime_env:
        shipped = Path(runtime_env["working_dir"])
        assert sorted(p.name for p in shipped.iterdir()) == sorted(SHIPPED_PACKAGES)
        assert (shipped / "launch_scripts" / "trial_runner" / "trial.py").is_file()
        assert not list(shipped.rglob("__pycache__")) and not list(shipped.rglob("*.pyc"))
    assert not shipped.exists()


def test_a_ray_failure_is_one_line_with_the_exception_the_task_raised():
    from launch_scripts.trials import _ray_failure

    class TaskError(Exception):
        """Like Ray's RayTaskError: the task's own exception in ``cause``."""

        def __init__(self, cause):
            super().__init__("ray::_trial_on_ray() (pid=1, ip=10.0.0.2)\n  File ...")
            self.cause = cause

    assert _ray_failure(TaskError(ModuleNotFoundError("No module named 'pybullet'\ntraceback: ..."))) == (
        "error: ModuleNotFoundError: No module named 'pybullet'")
    assert _ray_failure(OSError("\nThe worker died unexpectedly.\nCheck the logs.")) == (
        "error: OSError: The worker died unexpectedly.")


def test_a_folder_a_node_cannot_make_falls_back_to_its_temporary_folder(tmp_path):
    from launch_scripts.trials import _writable_here

    (tmp_path / "a_file").write_text("")
    assert _writable_here(str(tmp_path / "logs")) == str(tmp_path / "logs") and (tmp_path / "logs").is_dir()
    assert _writable_here(str(tmp_path / "a_file" / "logs")) == str(Path(tempfile.gettempdir()) / "clothkit_trials" / "logs")
    assert _writable_here(None) is None


def test_the_report_lists_the_ray_nodes_that_ran_the_trials():
    nodes = [{"id": "a" * 56, "ip": "10.0.0.1", "host": "head", "log_dir": "/x"},
             {"id": "b" * 56, "ip": "10.0.0.2", "host": "worker", "log_dir": "/y"}]
    records = [dict(RECORDS[0], node=nodes[0]), dict(RECORDS[1], node=nodes[1]), dict(RECORDS[2], node=nodes[0])]
    rep = report(records, "python -m launch_scripts.trials --seeds 0 2 4 --json r.json", {"kind": "corner"})
    assert rep["summary"]["nodes"] == [{"id": "b" * 56, "ip": "10.0.0.2", "host": "worker", "trials": 1},
                                       {"id": "a" * 56, "ip": "10.0.0.1", "host": "head", "trials": 2}]
    assert ("- ran on 2 Ray nodes: worker (10.0.0.2, node bbbbbbbbbbbb): 1 trial; "
            "head (10.0.0.1, node aaaaaaaaaaaa): 2 trials") in markdown(rep)
    without = report(RECORDS, "python -m launch_scripts.trials --seeds 0 2 4 --json r.json", {"kind": "corner"})
    assert without["summary"]["nodes"] == [] and "Ray node" not in markdown(without)


# ----------------------------------------------------------------------------- pictures


def test_a_caption_is_one_label_its_outline_does_not_drift_from_its_text():
    from sim.laundry.pictures import caption

    img = caption(np.full((60, 700, 3), 128, np.uint8), "corner plan (red), other candidates (orange), true corners (green)")
    grey = img[..., 0].astype(int)
    white_cols = np.flatnonzero((grey > 230).any(axis=0))
    dark_cols = np.flatnonzero((grey < 30).any(axis=0))
    assert white_cols.size and dark_cols.size
    assert dark_cols.min() >= white_cols.min() - 2 and dark_cols.max() <= white_cols.max() + 2


def test_a_caption_wider_than_its_picture_is_wrapped_onto_the_rows_above():
    from sim.laundry.pictures import caption

    verdict = ("FAILURE: first grasp 3.7 cm from the nearest corner; the held corners do not share an edge; "
               "edge held at 86 % of its length")
    img = caption(np.full((200, 640, 3), 128, np.uint8), verdict, row=1)
    white = (img[..., 0] > 230)
    rows, cols = np.flatnonzero(white.any(axis=1)), np.flatnonzero(white.any(axis=0))
    assert cols.max() < 640 - 8  # nothing runs off the right edge
    # two or more lines, the last one in row 1 (above row 0's caption), the others above it
    assert rows.max() <= 200 - 10 - 22 + 4 and rows.min() <= 200 - 10 - 22 * 2 - 8  # baselines and letters' height
    short = caption(np.full((200, 640, 3), 128, np.uint8), "SUCCESS", row=1)
    assert (short[..., 0] > 230).any(axis=1).nonzero()[0].min() > 200 - 10 - 22 * 2


def test_the_baseline_executes_the_planners_highest_point_even_for_a_held_cloth():
    from sim.laundry import best_candidate, default_controller, lowest_point_when_held

    assert default_controller("highest") is best_candidate
    assert default_controller("corner") is lowest_point_when_held
    assert default_controller("boundary") is lowest_point_when_held


@pytest.mark.parametrize("option, path, message", [
    ("--json", "file/r.json", "--json {tmp}/file/r.json: {tmp}/file is a file, expected a folder"),
    ("--markdown", "file/s.md", "--markdown {tmp}/file/s.md: {tmp}/file is a file, expected a folder"),
    ("--markdown", "folder", "--markdown {tmp}/folder: is a folder, expected a file"),  # failed after the trials
    ("--json", "folder", "--json {tmp}/folder: is a folder, expected a file"),
    ("--pictures", "file", "--pictures {tmp}/file: is a file, expected a folder"),
    ("--log-dir", "file/logs", "--log-dir {tmp}/file/logs: cannot make this folder (Not a directory)"),
])
def test_trials_refuse_an_output_they_cannot_write_before_running_any(tmp_path, capsys, option, path, message):
    from launch_scripts.trials import main

    (tmp_path / "file").write_text("a file, not a folder")
    (tmp_path / "folder").mkdir()
    paths = {"--json": tmp_path / "r.json", "--markdown": tmp_path / "s.md", option: tmp_path / path}
    args = ["--seeds", "0", "--quiet"] + [a for k, v in paths.items() for a in (k, str(v))]
    with pytest.raises(SystemExit) as e:
        main(args)
    assert e.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err == f"python -m launch_scripts.trials: error: {message.format(tmp=tmp_path)}"
