"""Pareto fronts, knob effects and the calibration's preset choice (no rendering)."""

from __future__ import annotations

import json
import math

import numpy as np

from backend.bench import _pareto
from tests.helpers import REPO
from backend.bench.calibrate import overrides
from backend.planning.presets import preset_for_budget
from backend.bench.sweep import GRIDS, Setting


def brute_front(times, scores):
    """Indices no other point dominates (by definition), ordered by time."""
    n = len(times)
    keep = []
    for i in range(n):
        dominated = any(times[j] <= times[i] and scores[j] >= scores[i]
                        and (times[j], scores[j]) != (times[i], scores[i]) for j in range(n))
        if not dominated:
            keep.append(i)
    return keep


def test_front_of_a_small_set():
    times = [10, 20, 15, 30, 5, 25]
    scores = [50, 70, 40, 65, 30, 80]
    # 5 s/30, 10 s/50, 20 s/70, 25 s/80; 15 s/40 and 30 s/65 are dominated
    assert _pareto.front(times, scores) == [4, 0, 1, 5]


def test_front_matches_the_definition_on_random_points():
    rng = np.random.default_rng(3)
    for _ in range(50):
        n = int(rng.integers(1, 30))
        times = rng.integers(1, 12, n).astype(float).tolist()  # small ranges: many ties
        scores = rng.integers(0, 8, n).astype(float).tolist()
        got = _pareto.front(times, scores)
        want = brute_front(times, scores)
        # identical points: the front keeps one of them
        assert sorted({(times[i], scores[i]) for i in got}) == sorted({(times[i], scores[i]) for i in want})
        assert len(got) == len({(times[i], scores[i]) for i in got})
        assert [times[i] for i in got] == sorted(times[i] for i in got)
        assert all(scores[a] < scores[b] for a, b in zip(got, got[1:]))


def test_front_skips_non_finite_points_and_handles_empty_input():
    assert _pareto.front([], []) == []
    assert _pareto.front([1.0, math.nan, 3.0], [5.0, 9.0, math.inf]) == [0]


def rows():
    base = {"max_size": 96, "spp": 16, "bounces": 1}
    return [{"name": "draft", "knobs": dict(base), "seconds": 100.0, "f1": 70.0},
            {"name": "draft:max_size=128", "knobs": dict(base, max_size=128), "seconds": 160.0, "f1": 82.0},
            {"name": "draft:spp=32", "knobs": dict(base, spp=32), "seconds": 150.0, "f1": 69.5},
            {"name": "draft:spp=8", "knobs": dict(base, spp=8), "seconds": 80.0, "f1": 69.0},
            {"name": "both", "knobs": dict(base, spp=32, max_size=128), "seconds": 300.0, "f1": 90.0}]


def test_knob_effects_are_one_knob_changes_best_rate_first():
    effects = _pareto.knob_effects(rows(), "draft")
    assert [e["name"] for e in effects] == ["draft:max_size=128", "draft:spp=8", "draft:spp=32"]
    first = effects[0]
    assert (first["knob"], first["from"], first["to"]) == ("max_size", 96, 128)
    assert first["per_second"] == 12.0 / 60.0
    assert effects[1]["per_second"] == (69.0 - 70.0) / (80.0 - 100.0)  # cheaper and a little worse
    assert _pareto.knob_effects(rows(), "absent") == []


def test_front_steps_name_the_knobs_each_budget_buys():
    steps = _pareto.front_steps(rows())
    assert [(s["from"], s["to"]) for s in steps] == [("draft:spp=8", "draft"), ("draft", "draft:max_size=128"),
                                                      ("draft:max_size=128", "both")]
    assert steps[1]["knobs"] == {"max_size": (96, 128)}
    assert steps[2]["knobs"] == {"spp": (16, 32)}
    assert steps[2]["d_seconds"] == 140.0 and steps[2]["d_score"] == 8.0
    assert _pareto.rate(1.0, 0.0) == math.inf and math.isnan(_pareto.rate(0.0, 0.0))


def test_preset_for_budget_picks_the_most_accurate_preset_that_fits(tmp_path):
    path = tmp_path / "presets.json"
    assert preset_for_budget(5, path) == "balanced"  # no calibration: the default
    path.write_text(json.dumps({"machine": "test", "presets": {
        "draft": {"expected_minutes": 2.0, "expected_f1": 0.80},
        "balanced": {"expected_minutes": 9.0, "expected_f1": 0.90},
        "final": {"expected_minutes": 40.0, "expected_f1": 0.93}}}))
    assert preset_for_budget(1, path) == "draft"  # nothing fits: the fastest
    assert preset_for_budget(2, path) == "draft"
    assert preset_for_budget(9.5, path) == "balanced"
    assert preset_for_budget(60, path) == "final"
    # a budget the best fit would mostly leave unused runs the next preset, cut at the budget
    assert preset_for_budget(3.9, path) == "draft" and preset_for_budget(4, path) == "balanced"
    assert preset_for_budget(27, path) == "final"
    # a kind without its own calibration reads the point-lit one; one with its own reads it
    assert preset_for_budget(9.5, path, kind="environment") == "balanced"
    doc = json.loads(path.read_text())
    doc["kinds"] = {"point": {"presets": doc["presets"]}, "environment": {"presets": {
        "draft": {"expected_minutes": 5.0, "expected_f1": 0.95},
        "balanced": {"expected_minutes": 22.0, "expected_f1": 0.97}}}}
    path.write_text(json.dumps(doc))
    assert preset_for_budget(9.5, path, kind="environment") == "draft"
    assert preset_for_budget(9.5, path) == "balanced"
    path.write_text("{broken")
    assert preset_for_budget(60, path) == "balanced"


def test_settings_turn_into_reconstruct_options_and_knobs():
    s = Setting("x", "draft", max_size=64, max_depth=3, time_budget=1.5)
    assert s.args() == ["--preset", "draft", "--material", "constant", "--max-size", "64", "--time-budget", "1.5",
                        "--integrator", "prb_projective", "--max-depth", "3"]
    k = s.knobs()
    assert k["max_size"] == 64 and k["bounces"] == 2 and k["time_budget_min"] == 1.5
    assert Setting("draft").knobs()["bounces"] == 1
    names = [s.name for s in GRIDS["full"]]
    assert len(names) == len(set(names)) and "draft" in names and "balanced" in names
    # every one-at-a-time setting differs from Draft in exactly one knob
    draft = Setting("draft").knobs()
    for s in GRIDS["full"]:
        if s.name.startswith("draft:"):
            assert len(_pareto.changed(draft, s.knobs())) == 1, s.name
    assert overrides(draft, dict(draft, max_size=128, bounces=2, time_budget_min=2.0)) == {
        "max_size": 128, "integrator": "prb_projective", "max_depth": 3, "time_budget_s": 120.0}
    # the fields are ReconstructConfig's, so the lead can paste them into PRESETS
    from backend.optimize.config import ReconstructConfig
    assert set(overrides(draft, dict(draft, max_size=128, bounces=2, time_budget_min=2.0))) <= set(
        ReconstructConfig.__dataclass_fields__)


def test_plot_labels_do_not_overlap_when_runs_cluster(tmp_path):
    """Twelve runs within a few percent of each other (as knobs that change little land): every
    label gets its own place, inside the axes; the report's plot is written with them."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from backend.bench import _labels, _report

    rng = np.random.default_rng(0)
    xs = (60 + rng.normal(0, 4, 12)).tolist()
    ys = (92 + rng.normal(0, 0.4, 12)).tolist()
    names = [f"knob_{i}={v}" for i, v in enumerate(rng.integers(1, 999, 12))]
    fig, ax = plt.subplots(figsize=(5.2, 4.3))
    ax.scatter(xs, ys)
    ax.set_xlim(20, 200)
    ax.set_ylim(84, 98)
    notes = _labels.place(ax, xs, ys, names)
    renderer = fig.canvas.get_renderer()
    boxes = [n.get_window_extent(renderer) for n in notes]
    frame = ax.get_window_extent(renderer)
    assert len(boxes) == 12
    for i, a in enumerate(boxes):
        assert frame.x0 <= a.x0 and a.x1 <= frame.x1 and frame.y0 <= a.y0 and a.y1 <= frame.y1
        for b in boxes[i + 1:]:
            assert not a.overlaps(b), (a, b)
    plt.close(fig)
    rows = [{"name": n, "seconds": x, "cpu_seconds": 2 * x, "f1": y, "relit_psnr": y / 4} for n, x, y in zip(names, xs, ys)]
    _report.plot(rows, "cluster", tmp_path / "p.png")
    assert (tmp_path / "p.png").stat().st_size > 10_000


def test_a_scene_without_relit_views_gets_no_empty_panel(tmp_path):
    """A video scene has F1 but no relit PSNR: its plot has the two F1 panels only."""
    from PIL import Image

    from backend.bench import _report

    rows = [{"name": f"draft:max_size={s}", "seconds": t, "cpu_seconds": 2 * t, "f1": f}
            for s, t, f in ((64, 104.0, 89.5), (128, 136.0, 90.2), (96, 222.0, 88.7))]
    _report.plot(rows, "video", tmp_path / "video.png")
    _report.plot([dict(r, relit_psnr=20.0) for r in rows], "lit", tmp_path / "lit.png")
    two, three = (Image.open(tmp_path / n).size[0] for n in ("video.png", "lit.png"))
    assert two < 0.75 * three, (two, three)


def test_report_says_the_cpu_was_shared_only_when_the_load_was_above_the_cores(tmp_path):
    """A sweep run alone keeps its own cores busy (load about the core count): the report says
    so, and says other jobs shared the CPU only when the load was well above the cores."""
    from backend.bench import _report
    from backend.bench.sweep import SCENES

    rows = json.loads((REPO / "bench" / "results.json").read_text())
    cores = rows[0]["machine"]["cores"]
    alone = [dict(r, load_before=float(cores), load_after=float(cores)) for r in rows]
    shared = [dict(r, load_after=3.0 * cores) for r in alone]
    said = {}
    for name, these in (("alone", alone), ("shared", shared)):
        said[name] = _report.write(these, tmp_path / name, SCENES).read_text()
    assert "had the CPU to themselves" in said["alone"] and "Other jobs shared" not in said["alone"]
    assert "Other jobs shared the CPU" in said["shared"]
