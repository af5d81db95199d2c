"""The sweep's report: ``report.md`` (fronts, knob effects, presets), ``pareto_<scene>.png``
(accuracy against time with the front) and ``results.json`` (every measured row)."""

from __future__ import annotations

import json
import math
from pathlib import Path

from .. import fsio
from . import _labels, _pareto
from ._machine import machine_line

PRESET_NAMES = ("draft", "balanced", "final")
BUDGETS_MIN = (1, 3, 10, 30)
SHARED_LOAD = 1.25  # load above this many times the cores: other jobs were running


def _fmt(value, digits: int = 1) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "–"
    return f"{value:.{digits}f}"


def ok_rows(rows: list[dict]) -> list[dict]:
    """Rows of finished runs with both a time and an F1."""
    return [r for r in rows if r.get("rc") == 0 and r.get("f1") is not None]


PANELS = (("seconds", "f1", "wall-clock seconds (log)", "F1@0.01 (%)"),
          ("cpu_seconds", "f1", "CPU seconds of the process (log)", "F1@0.01 (%)"),
          ("seconds", "relit_psnr", "wall-clock seconds (log)", "relit PSNR (dB)"))


def plot(rows: list[dict], scene: str, path: Path) -> None:
    """F1@0.01 against wall-clock and against CPU seconds, and relit PSNR against wall-clock;
    each panel's front drawn as a staircase."""
    import matplotlib  # here: only the plots need matplotlib (slow to load)

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker

    # only the panels with points (a video scene has no relit views, so no relit panel)
    panels = [(p, [r for r in rows if r.get(p[1]) is not None and r.get(p[0]) is not None]) for p in PANELS]
    panels = [(p, pts) for p, pts in panels if pts]
    fig, axes = plt.subplots(1, max(len(panels), 1), figsize=(5.2 * max(len(panels), 1), 4.3), squeeze=False)
    labelled = []
    for ax, ((tkey, key, xlabel, ylabel), pts) in zip(axes[0], panels):
        idx = _pareto.front([r[tkey] for r in pts], [r[key] for r in pts])
        on = set(idx)
        for i, r in enumerate(pts):
            preset = r["name"] in PRESET_NAMES
            ax.scatter(r[tkey], r[key], s=60 if preset else 28, marker="D" if preset else "o",
                       color="tab:red" if i in on else "tab:gray", zorder=3, edgecolors="k", linewidths=0.4)
        xs = [pts[i][tkey] for i in idx]
        ys = [pts[i][key] for i in idx]
        ax.step(xs + [max(r[tkey] for r in pts) * 1.15], ys + ys[-1:], where="post", color="tab:red",
                lw=1.2, label="Pareto front")
        ax.set_xscale("log")
        ax.xaxis.set_major_formatter(matplotlib.ticker.FuncFormatter(lambda x, _: f"{x:g}"))
        lo, hi = ax.get_xlim()
        narrow = hi / max(lo, 1e-9) < 10  # within a decade: label every minor tick, else 2x and 5x
        ax.xaxis.set_minor_formatter(matplotlib.ticker.FuncFormatter(
            lambda x, _, narrow=narrow: f"{x:g}" if narrow or f"{x:e}"[0] in "25" else ""))
        ax.tick_params(axis="x", which="minor", labelsize=7)
        ax.set_xlabel(xlabel)
        ax.set_ylabel(ylabel)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(loc="best", fontsize=8)
        labelled.append((ax, pts, on, tkey, key))
    fig.suptitle(f"{scene}: accuracy against time ({len(rows)} runs; diamonds: presets)")
    fig.tight_layout()
    for ax, pts, on, tkey, key in labelled:
        # labels last, on the final layout: the front and the presets first, so they get the near places
        order = sorted(range(len(pts)), key=lambda i: (i not in on, pts[i]["name"] not in PRESET_NAMES))
        _labels.place(ax, [pts[i][tkey] for i in order], [pts[i][key] for i in order],
                      [pts[i]["name"].replace("draft:", "") for i in order],
                      ["k" if i in on else "0.45" for i in order])
    with fsio.atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=100, format="png")
    plt.close(fig)


def _front_table(rows: list[dict]) -> list[str]:
    idx = _pareto.front([r["seconds"] for r in rows], [r["f1"] for r in rows])
    lines = ["| setting | wall s | CPU s | peak MB | Chamfer-L1 | F1@0.01 | novel PSNR | relit PSNR "
             "| load before–after |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for i in idx:
        r = rows[i]
        lines.append(f"| {r['name']} | {_fmt(r['seconds'], 0)} | {_fmt(r.get('cpu_seconds'), 0)} | "
                     f"{_fmt(r.get('peak_mb'), 0)} | {_fmt(r.get('chamfer_l1'), 4)} | {_fmt(r['f1'])} | "
                     f"{_fmt(r.get('novel_psnr'))} | {_fmt(r.get('relit_psnr'))} | "
                     f"{_fmt(r.get('load_before'))}–{_fmt(r.get('load_after'))} |")
    return lines


def _all_table(rows: list[dict]) -> list[str]:
    lines = ["| setting | wall s | CPU s | peak MB | F1@0.01 | Chamfer-L1 | novel PSNR | relit PSNR | front |",
             "|---|---:|---:|---:|---:|---:|---:|---:|:-:|"]
    on = set(_pareto.front([r["seconds"] for r in rows], [r["f1"] for r in rows]))
    for i in sorted(range(len(rows)), key=lambda i: rows[i]["seconds"]):
        r = rows[i]
        lines.append(f"| {r['name']} | {_fmt(r['seconds'], 0)} | {_fmt(r.get('cpu_seconds'), 0)} | "
                     f"{_fmt(r.get('peak_mb'), 0)} | {_fmt(r['f1'])} | {_fmt(r.get('chamfer_l1'), 4)} | "
                     f"{_fmt(r.get('novel_psnr'))} | {_fmt(r.get('relit_psnr'))} | {'●' if i in on else ''} |")
    return lines


def _summary_lines(by_scene: dict[str, list[dict]]) -> list[str]:
    """Per scene and wall-clock budget: the most accurate run that fit, and what the next step
    along the front buys (the knob with the best accuracy per second from there)."""
    lines = ["| scene | budget | best setting within it | wall s | F1@0.01 | Chamfer-L1 | relit PSNR | "
             "next step on the front |", "|---|---:|---|---:|---:|---:|---:|---|"]
    for scene, rows in by_scene.items():
        steps = _pareto.front_steps(rows)
        last = None
        for minutes in BUDGETS_MIN:
            fit = [r for r in rows if r["seconds"] <= 60 * minutes]
            if not fit:
                continue
            best = max(fit, key=lambda r: (r["f1"], -r["seconds"]))
            if best is last:
                continue
            last = best
            step = next((s for s in steps if s["from"] == best["name"]), None)
            nxt = "–" if step is None else (
                f"{', '.join(f'{k} {a}→{b}' for k, (a, b) in step['knobs'].items())}: "
                f"+{step['d_score']:.1f} F1 for +{step['d_seconds']:.0f} s")
            lines.append(f"| {scene} | ≤ {minutes} min | {best['name']} | {_fmt(best['seconds'], 0)} | "
                         f"{_fmt(best['f1'])} | {_fmt(best.get('chamfer_l1'), 4)} | {_fmt(best.get('relit_psnr'))} | "
                         f"{nxt} |")
    return lines


def _knob_lines(rows: list[dict]) -> list[str]:
    effects = _pareto.knob_effects(rows, "draft", time_key="cpu_seconds")
    if not effects:
        return []
    wall = {e["name"]: e["d_seconds"] for e in _pareto.knob_effects(rows, "draft")}
    base = next(r["cpu_seconds"] for r in rows if r["name"] == "draft")
    lines = ["| knob | from → to | Δ CPU s | Δ wall s | Δ F1 | F1 points per CPU minute |",
             "|---|---|---:|---:|---:|---:|"]
    for e in effects:
        per_minute = ("– (time change within 5 %)" if abs(e["d_seconds"]) < 0.05 * base
                      else _fmt(60 * e["per_second"], 2))
        lines.append(f"| {e['knob']} | {e['from']} → {e['to']} | {e['d_seconds']:+.0f} | {wall[e['name']]:+.0f} | "
                     f"{e['d_score']:+.1f} | {per_minute} |")
    return lines


def _step_lines(rows: list[dict]) -> list[str]:
    steps = _pareto.front_steps(rows)
    if not steps:
        return []
    lines = ["| at budget (s) | from → to | + s | + F1 | F1 per minute | knobs changed |",
             "|---:|---|---:|---:|---:|---|"]
    for s in steps:
        knobs = ", ".join(f"{k} {a}→{b}" for k, (a, b) in s["knobs"].items()) or "(same knobs; noise)"
        lines.append(f"| {s['budget_s']:.0f} | {s['from']} → {s['to']} | {s['d_seconds']:.0f} | "
                     f"{s['d_score']:+.1f} | {_fmt(60 * s['per_second'], 2)} | {knobs} |")
    return lines


def _presets_lines(presets: dict) -> list[str]:
    lines = [f"Calibration file `backend/presets.json`, measured on {presets.get('machine')} "
             f"({presets.get('measured', '?')}, scene {presets.get('scene', '?')}).", "",
             "| preset | expected min | expected F1@0.01 | target | met | recommended overrides |",
             "|---|---:|---:|---|:-:|---|"]
    for name, p in presets.get("presets", {}).items():
        target = p.get("target") or {}
        goal = (f"F1 ≥ {target['f1']:.2f} in ≤ {target['minutes']:g} min" if target else "–")
        met = "–" if target.get("met") is None else ("yes" if target.get("met") else "no")
        rec = p.get("recommended_overrides") or {}
        rec_text = ", ".join(f"{k}={v}" for k, v in rec.items()) or "none"
        if rec and p.get("recommended_expected_minutes") is not None:
            rec_text += (f" (measured {p['recommended_expected_minutes']:.1f} min, "
                         f"F1 {p['recommended_expected_f1']:.3f})")
        lines.append(f"| {name} | {_fmt(p.get('expected_minutes'), 1)} | {_fmt(p.get('expected_f1'), 3)} | {goal} | "
                     f"{met} | {rec_text} |")
    return lines


def _repeat_lines(history: list[dict]) -> list[str]:
    """Settings measured more than once (``--rerun``): every measurement, oldest first."""
    seen: dict[tuple, list[dict]] = {}
    for r in history:
        if r.get("rc") == 0 and r.get("f1") is not None:
            seen.setdefault((r["scene"], r["name"]), []).append(r)
    repeated = {k: v for k, v in seen.items() if len(v) > 1}
    if not repeated:
        return []
    lines = ["| scene | setting | measurements (wall s / CPU s / load before / F1@0.01), oldest first |",
             "|---|---|---|"]
    for (scene, name), rs in repeated.items():
        runs = "; ".join(f"{r['seconds']:.0f} / {r['cpu_seconds']:.0f} / {_fmt(r.get('load_before'))} / {r['f1']:.1f}"
                         for r in rs)
        lines.append(f"| {scene} | {name} | {runs} |")
    return lines


def write(rows: list[dict], out: Path, scenes: dict, presets_path: Path | None = None,
          history: list[dict] | None = None) -> Path:
    """Write the report for ``rows`` (the latest measurement of each setting) into ``out``;
    ``history`` (every measurement) adds a table of the settings measured more than once.
    Returns the path of ``report.md``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    fsio.write_json(out / "results.json", rows)
    good = ok_rows(rows)
    machines = {json.dumps(r.get("machine"), sort_keys=True): r.get("machine") for r in rows if r.get("machine")}
    loads = [x for r in good for x in (r.get("load_before"), r.get("load_after")) if x is not None]
    dates = sorted(r["measured"] for r in rows if r.get("measured"))
    md = ["# Accuracy against time", "",
          "Written by `python -m backend bench sweep` (see `backend/bench/sweep.py`); every measured run is "
          "in `results.json`. Time is the wall clock of the whole `reconstruct` process (start-up, "
          "initialisation and optimisation; scoring excluded), accuracy is F1@0.01 (percent of surface "
          "points within 1% of the object's size, both ways) against the true mesh; novel-view and relit "
          "PSNR score the result rendered with its estimated material at held-out cameras (relit: under a "
          "second environment alone).", ""]
    for m in machines.values():
        md.append(f"- Machine: {machine_line(m)} (Mitsuba {m.get('mitsuba', '?')}, {m.get('memory_gib', '?')} GiB).")
    if loads:
        cores = next(iter(machines.values()), {}).get("cores")
        # a run keeps its own cores busy: only a load well above them means other jobs shared the CPU
        shared = not isinstance(cores, int) or max(loads) > SHARED_LOAD * cores
        md.append(f"- 1-minute load average around the runs: {min(loads):.1f}–{max(loads):.1f} on "
                  f"{cores or '?'} cores. " + (
                      "Other jobs shared the CPU, so wall-clock times are inflated (by about load / cores when the "
                      "load exceeds the cores); the CPU seconds of the process are given too." if shared else
                      "The runs had the CPU to themselves (the load is their own); the CPU seconds of the process "
                      "are given too."))
    if dates:
        md.append(f"- Measured {dates[0]} to {dates[-1]}.")
    codes = sorted({r.get("code", "unknown") for r in rows})
    md.append(f"- Backend code measured: {', '.join(codes)} (commit the reconstruct processes ran from).")
    failed = [r for r in rows if r.get("rc") != 0]
    if failed:
        md.append(f"- Failed runs (not plotted): {', '.join(r['scene'] + '/' + r['name'] for r in failed)}.")
    md.append("")
    by_scene: dict[str, list[dict]] = {}
    for r in good:
        by_scene.setdefault(r["scene"], []).append(r)
    if by_scene:
        md += ["## Summary", "", "The most accurate run within each wall-clock budget (Pareto front per scene below):",
               ""] + _summary_lines(by_scene) + [""]
    for scene, srows in by_scene.items():
        png = out / f"pareto_{scene}.png"
        plot(srows, scene, png)
        desc = scenes[scene].description if scene in scenes else ""
        md += [f"## {scene}", "", desc + ".", "", f"![{scene}: accuracy against time]({png.name})", "",
               "Pareto front (no other run was both faster and more accurate):", ""]
        md += _front_table(srows) + [""]
        knob = _knob_lines(srows)
        if knob:
            md += ["One knob at a time around Draft, ranked by F1 bought per CPU second (CPU time is "
                   "steadier than wall time under a varying load; a cheaper, worse change shows F1 lost per "
                   "second saved):", ""] + knob + [""]
        steps = _step_lines(srows)
        if steps:
            md += ["Along the front: what the next budget buys:", ""] + steps + [""]
        md += ["<details><summary>All runs</summary>", ""] + _all_table(srows) + ["", "</details>", ""]
    repeats = _repeat_lines(history or [])
    if repeats:
        md += ["## Repeated measurements", "",
               "Settings run more than once; the sections above use the latest run. The spread shows the "
               "load's effect on wall time and the run-to-run variation of the result.", ""] + repeats + [""]
    presets_path = presets_path or Path(__file__).resolve().parents[1] / "presets.json"
    if presets_path.is_file():
        try:
            presets = json.loads(presets_path.read_text())
        except ValueError:
            presets = {}
        if presets.get("presets"):
            md += ["## Presets", ""] + _presets_lines(presets) + [""]
    path = out / "report.md"
    fsio.write_text(path, "\n".join(md))
    return path
