"""Running the cases: by name, guarded, or each in its own process (peak memory), and their table."""

from __future__ import annotations

import multiprocessing
import resource
import time
from pathlib import Path

from ...errors import InputError
from .faults import full_disk, killed_mid_write
from .gradients import gradient_geometry, gradient_meshcolors
from .pipeline import pipeline_cases, run_pipeline_case
from .results import MEMORY_LIMIT_GB, Result


GRADIENT_CASES = {"gradient_geometry": gradient_geometry, "gradient_meshcolors": gradient_meshcolors}
PROCESS_CASES = {"killed_mid_write": killed_mid_write, "full_disk": full_disk}


def case_names(quick: bool) -> list[str]:
    return list(pipeline_cases(quick)) + list(GRADIENT_CASES) + list(PROCESS_CASES)


def run_case(name: str, work: Path, quick: bool) -> Result:
    """Run one case in ``work`` (an empty folder)."""
    if name in GRADIENT_CASES:
        return GRADIENT_CASES[name](work, quick)
    if name in PROCESS_CASES:
        return PROCESS_CASES[name](work, quick)
    cases = pipeline_cases(quick)
    if name not in cases:
        raise InputError(None, f"no stability case '{name}'", f"choose from {', '.join(case_names(quick))}")
    return run_pipeline_case(name, cases[name], work, quick)


def peak_rss_gb() -> float:
    """Peak resident memory of this process so far (Linux reports kilobytes)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / (1 << 20)


def guarded(name: str, work: Path, quick: bool) -> dict:
    """``run_case`` with a crash reported as a failed case; peak memory added."""
    start = time.perf_counter()
    try:
        result = run_case(name, work, quick)
    except Exception as err:  # the table reports a crash as a failure instead of stopping
        result = Result(name, problems=[f"crashed: {type(err).__name__}: {err}"])
        result.seconds = round(time.perf_counter() - start, 1)
    result.peak_rss_gb = round(peak_rss_gb(), 2)
    if name.startswith("faces_"):
        result.check(result.peak_rss_gb < MEMORY_LIMIT_GB, f"peak memory {result.peak_rss_gb} GB")
    return result.to_json()


def _child(name: str, work: str, quick: bool, conn) -> None:
    conn.send(guarded(name, Path(work), quick))
    conn.close()


def isolated(name: str, work: Path, quick: bool) -> dict:
    """``guarded`` in a fresh process (its own peak memory; a hard crash is a failure too)."""
    ctx = multiprocessing.get_context("spawn")
    receive, send = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_child, args=(name, str(work), quick, send))
    proc.start()
    send.close()
    try:
        record = receive.recv()
    except EOFError:
        record = Result(name, problems=[f"process died (exit code {proc.exitcode})"]).to_json()
    proc.join()
    if proc.exitcode not in (0, None) and record.get("passed"):
        record["problems"].append(f"process exit code {proc.exitcode}")
        record["passed"] = False
    return record


def _number(x, digits: int = 4) -> str:
    return "-" if x is None else f"{x:.{digits}g}"


def table(records: list[dict]) -> str:
    """The report: one row per case."""
    head = ["case", "steps", "caught", "final loss", "peak GB", "seconds", "result", "note"]
    rows = []
    for r in records:
        notes = r["notes"]
        if r["problems"]:
            note = r["problems"][0]
        elif "relative_errors" in notes:
            note = "max relative error " + f"{100 * max(notes['relative_errors'].values()):.1f}% (final loss column)"
        elif "error" in notes:
            note = "input error: " + notes["error"].split(": ", 1)[-1]
        elif "skipped" in notes:
            note = "skipped: " + "; ".join(notes["skipped"])
        elif "warnings" in notes:
            note = notes["warnings"][-1]
        elif "kills" in notes:
            note = f"{notes['kills']} kills ({notes['killed_during_a_write']} mid-write), resumed"
        elif r["case"] == "full_disk":
            note = "; ".join(f"{k}: exit {v['exit']}" for k, v in notes.items() if isinstance(v, dict))
        else:
            note = ""
        rows.append([r["case"], str(r["steps"]), str(r["caught"]), _number(r["final_loss"]),
                     _number(r["peak_rss_gb"], 3), f"{r['seconds']:.1f}", "pass" if r["passed"] else "FAIL",
                     note[:110]])
    widths = [max(len(head[i]), *(len(row[i]) for row in rows)) for i in range(len(head) - 1)]
    lines = ["  ".join(h.ljust(w) for h, w in zip(head, widths)) + "  " + head[-1]]
    lines.append("  ".join("-" * w for w in widths) + "  " + "-" * 4)
    lines += ["  ".join(c.ljust(w) for c, w in zip(row, widths)) + "  " + row[-1] for row in rows]
    return "\n".join(lines)
