"""launch_scripts.evaluate --handled: its options, its pooled table and its own section of results.md."""

import pytest

from launch_scripts.evaluate import BEGIN, END, main, write_section
from launch_scripts.handled_table import BEGIN as HANDLED_BEGIN
from launch_scripts.handled_table import END as HANDLED_END
from launch_scripts.handled_table import PRESETS, VARIANTS, markdown, pooled_rows, variant_key


@pytest.mark.parametrize("args, message", [
    (["--handled", "--scenes", "poster_bend"], "unknown scene(s) poster_bend; expected among occluder_sweep"),
    (["--scenes", "table_lift"], "(the handled scenes need --handled)"),
    (["--handled", "--seeds", "-1"], "--seeds must be non-negative"),
])
def test_bad_options_stop_with_one_line(tmp_path, capsys, args, message):
    assert main([*args, "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0]
    assert not (tmp_path / "out").exists()


def _summary(mean, frames=10, lost=0, confident_wrong=0, area=None, late=0):
    return {"frames": frames, "mean_mm": mean, "p95_mm": 2 * mean, "occluded_area_ratio": area,
            "occluded_area_ratio_worst": None if area is None else area - 0.1, "lost_frames": lost, "wrong_frames": lost,
            "wrong_confident_frames": confident_wrong, "wrong_unflagged_late_frames": late, "new_meshes": 0,
            "median_ms": 20.0, "failure": ""}


def _seed(scale):
    runs = {}
    for preset in PRESETS:
        runs[preset] = {
            "clear": _summary(2.0 * scale),
            "occluder/unknown": {**_summary(6.0 * scale, area=0.5), "even_frames_mean_mm": 5.0 * scale},
            "occluder/known": {**_summary(3.0 * scale, area=0.9), "even_frames_mean_mm": 3.0 * scale},
            "dropped/unknown": _summary(10.0 * scale, frames=5, lost=2, area=0.4),
            "dropped/known": _summary(3.0 * scale, frames=5, confident_wrong=1, area=0.9, late=1),
            "occluder/robot": {**_summary(2.5 * scale, area=1.0), "even_frames_mean_mm": 2.0 * scale},
            "dropped/robot": _summary(3.0 * scale, frames=5, area=0.95),
        }
    return {"runs": runs}


def test_rows_pool_seeds_and_take_each_ratio_against_its_reference():
    rows = pooled_rows({"occluder_sweep": {"0": _seed(1.0), "2": _seed(2.0)}})
    assert len(rows) == len(VARIANTS) * len(PRESETS)
    by_key = {(r["variant"], r["masks"], r["preset"]): r for r in rows}
    clear = by_key["clear", None, "default"]
    assert clear["mean_mm"] == pytest.approx(3.0) and "to_twin" not in clear
    occluded = by_key["occluder", "unknown", "default"]
    assert occluded["to_twin"] == pytest.approx([3.0, 3.0]) and occluded["area_ratio"] == pytest.approx(0.5)
    dropped = by_key["dropped", "unknown", "realtime"]
    assert dropped["to_full_rate"] == pytest.approx([2.0, 2.0]) and dropped["to_twin"] == pytest.approx([5.0, 5.0])
    assert dropped["lost_frames"] == 4 and dropped["frames"] == 10
    assert by_key["dropped", "known", "default"]["wrong_confident_frames"] == 2
    assert by_key["dropped", "known", "default"]["wrong_unflagged_late_frames"] == 2
    robot = by_key["dropped", "robot", "default"]
    assert robot["to_full_rate"] == pytest.approx([1.5, 1.5]) and robot["area_ratio"] == pytest.approx(0.95)


def test_the_handled_section_leaves_the_paper_table_alone(tmp_path):
    results = {"table_lift": {"0": _seed(1.0)}}
    text = markdown(results, [0], (True,))
    assert text.startswith(HANDLED_BEGIN) and text.endswith(HANDLED_END)
    assert "| table_lift | dropped | unknown | default | 10.0 / 20.0 | 5.00 | 2.00 | 0.40 (0.30) | 2/5 | 0/5 | 0/5 |" in text
    assert "| table_lift | dropped | known | default | 3.0 / 6.0 | 1.50 | 1.00 | 0.90 (0.80) | 0/5 | 1/5 | 1/5 |" in text
    path = tmp_path / "results.md"
    paper = f"# Measured results\n\n{BEGIN}\npaper table\n{END}\n\n## Trials\n\nkept\n"
    path.write_text(paper)
    write_section(path, text, HANDLED_BEGIN, HANDLED_END)
    write_section(path, text.replace("10.0 / 20.0", "9.0 / 18.0"), HANDLED_BEGIN, HANDLED_END)
    out = path.read_text()
    assert out.startswith(paper) and out.count(HANDLED_BEGIN) == 1 and "9.0 / 18.0" in out and "10.0 / 20.0" not in out
    assert "| table_lift | occluder | robot | realtime | 2.5 / 5.0 | 1.25 |" in text
    assert variant_key("dropped", "known") == "dropped/known" and variant_key("clear", None) == "clear"
