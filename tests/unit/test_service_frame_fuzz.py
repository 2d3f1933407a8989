"""The perception service's core under hostile frames: every frame is tracked or rejected
with a named kind, never as ``internal`` (a bug), and a second run of the same fuzz in the
same process allocates nothing that stays.

Frames that do not decode (NaN or infinite intrinsics, infinite or negative depth) never
reach the core: the codec refuses them, which the first test checks on the wire format.
"""

import gc
import math
import re
import tracemalloc
from pathlib import Path

import msgpack
import numpy as np
import pytest

from ipc import codec
from ipc.messages import RGBDFrame
from perception import TrackerConfig
from perception.frame_checks import check_camera, check_frame
from perception.service_core import PerceptionCore
from tests.fuzz_frames import CAMERA, FrameFuzzer, sheet_frames

pytestmark = pytest.mark.timeout(300)

SEED = 20261130
DOC = (Path(__file__).resolve().parents[2] / "docs" / "protocol.md").read_text()
#: The kinds of rejected frames docs/protocol.md lists for the perception service, but "internal" (a bug).
NAMED_KINDS = set(re.findall(r"^\| `(\w+)` \|", DOC[DOC.index("| kind | cause |"):DOC.index("`messages_malformed`, each")],
                             flags=re.M)) - {"internal"}
#: What an estimate's energies may hold (docs/protocol.md, MeshEstimate.energies).
ENERGY_NAMES = {"smoothness", "correspondence", "depth", "boundary", "motion_prior", "stretch", "hold", "outside",
                "free_space", "total", "inliers"}


def frame_bytes(depth: np.ndarray) -> list[bytes]:
    """A wire RGBDFrame of CAMERA's size with ``depth`` (float32) written as sent, unchecked."""
    good = codec.encode(RGBDFrame(np.zeros((CAMERA.height, CAMERA.width, 3), np.uint8),
                                  np.ones((CAMERA.height, CAMERA.width), np.float32), CAMERA), inline_max_bytes=0)
    header = msgpack.unpackb(good[0])
    frames = [None, *good[1:]]
    index = header["fields"]["depth_m"]["frame"]
    frames[index] = depth.astype("<f4").tobytes()
    frames[0] = msgpack.packb(header)
    return frames


@pytest.mark.parametrize("value", [np.inf, -np.inf, -1.0, -1e-30])
def test_infinite_and_negative_depth_never_decode(value):
    depth = np.ones((CAMERA.height, CAMERA.width), np.float32)
    depth[5, 7] = value
    with pytest.raises(codec.ProtocolError, match="RGBDFrame.depth_m"):
        codec.decode(frame_bytes(depth))


def test_nan_depth_decodes_as_missing_and_is_rejected_as_no_depth():
    frame = codec.decode(frame_bytes(np.full((CAMERA.height, CAMERA.width), np.nan, np.float32)))
    assert not frame.depth_m.any()
    assert check_frame(frame)[0] == "no_depth"


def test_the_checks_name_what_is_wrong():
    good = sheet_frames(1)[0]
    assert check_frame(good) is None and check_camera(good.camera) is None
    wide = RGBDFrame(good.rgb, good.depth_m, type(CAMERA)(160, 120, np.array([[1e-9, 0, 80], [0, 1e-9, 60], [0, 0, 1.0]])))
    assert check_frame(wide) == ("bad_camera", pytest.approx(check_frame(wide)[1]))
    assert "horizontal field of view 180 deg" in check_frame(wide)[1]
    far = RGBDFrame(good.rgb, good.depth_m * np.float32(1000), good.camera, seq=3)  # millimetres sent as metres
    kind, message = check_frame(far)
    assert kind == "bad_depth" and message.startswith("frame 3: depth from") and "wrong depth_scale" in message
    off = type(CAMERA)(160, 120, np.array([[100.0, 0, 1e6], [0, 100.0, 60], [0, 0, 1.0]]))
    assert "principal point" in check_camera(off)
    flung = RGBDFrame(good.rgb, good.depth_m, good.camera, seq=4, held_vertices=np.array([0, 1]),
                      held_points_m=np.array([[0.0, 0.0, 1.0], [0.0, 5e3, 1.0]]))
    assert check_frame(flung) == ("bad_hold", "frame 4: held point 1 is 5000 m from the camera, beyond the 100 m of "
                                              "any RGB-D sensor")


def fuzz(core: PerceptionCore, n: int) -> dict:
    """Feed ``n`` events of the fuzzer to ``core``, as the service would; returns what happened."""
    outcome = {"tracked": 0, "refused": 0, "idle": 0, "energies": set(), "held": []}
    for kind, value in FrameFuzzer(SEED, core.parameters()).events(n):
        if kind == "frame":
            outcome["idle"] += core.state == "idle"
            estimate = core.handle_frame(value)
            if estimate is not None:
                outcome["tracked"] += 1
                outcome["energies"].update(estimate.energies)
                if value.held_vertices is not None:
                    outcome["held"].append(estimate)
        else:
            try:
                if kind == "initialise":
                    core.request_initialise(value)
                else:
                    core.set_parameters(value)
            except ValueError:  # answered ErrorReply "invalid" by the service
                outcome["refused"] += 1
    return outcome


def test_every_frame_is_tracked_or_rejected_with_a_named_kind():
    core = PerceptionCore(TrackerConfig.realtime(), reinit_after_lost=3)
    outcome = fuzz(core, 400)
    rejected = core.counters.rejected
    assert "internal" not in rejected, core.last_error
    assert NAMED_KINDS >= {"no_depth", "bad_depth", "bad_camera", "camera_changed", "init_failed", "tracker"}
    assert set(rejected) <= NAMED_KINDS
    assert outcome["energies"] <= ENERGY_NAMES and {"smoothness", "total", "inliers"} <= outcome["energies"]
    energies_row = next(line for line in DOC.splitlines() if line.startswith("| `energies` |"))
    assert all(f"`{name}`" in energies_row for name in ENERGY_NAMES)
    # The fuzz reaches every check and still tracks good frames between the bad ones.
    assert {"no_depth", "bad_depth", "bad_camera", "bad_hold", "camera_changed", "init_failed", "tracker"} \
        <= set(rejected), rejected
    # Frames that held a vertex the mesh has were tracked, not rejected (what the hold term and
    # the tethers do with them: tests/unit/test_tracker_held_cloth.py).
    assert len(outcome["held"]) >= 5, len(outcome["held"])
    assert outcome["tracked"] > 20 and outcome["refused"] > 0, outcome
    assert core.counters.frames_taken == core.counters.processed + sum(rejected.values()) + outcome["idle"]
    assert core.counters.processed == outcome["tracked"]


def test_a_second_fuzz_run_keeps_no_memory():
    """The same fuzz twice in one process: whatever the second run allocates (NumPy arrays and
    Python objects, traced by tracemalloc) is freed, give or take the state the core keeps (one
    frame, one mesh). A leak of one small frame per event would add about 20 MB."""
    n = 200
    core = PerceptionCore(TrackerConfig.realtime(), reinit_after_lost=3)
    tracemalloc.start()
    try:
        fuzz(core, n)
        gc.collect()
        after_first, _ = tracemalloc.get_traced_memory()
        fuzz(core, n)
        gc.collect()
        after_second, _ = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert "internal" not in core.counters.rejected
    growth_mb = (after_second - after_first) / 2**20
    assert growth_mb < 2.0, f"the second run kept {growth_mb:.1f} MB"
    assert math.isfinite(growth_mb)
