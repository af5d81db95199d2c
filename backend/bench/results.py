"""Regenerate docs/results.md and the README's figures from the benchmark records.

``python -m backend bench results [--records DIR] [--doc PATH] [--readme PATH] [--check]``
reads every record of ``bench/records`` (:mod:`backend.bench._records`) and writes:

- docs/results.md: what the scores mean, then per record a heading (its title), its context,
  its table (the columns of ``show`` where the record names them; none where ``display`` is
  ``"scalars"``), its scalars, its notes, links to its plots, its reproducing command and a
  link to the record;
- the README's figures: the lines between ``<!-- results:begin -->`` and ``<!-- results:end -->``,
  one line per benchmark from :data:`HEADLINES`.

The output depends on the records alone (no clock, no machine), so running it on a clean
checkout changes nothing; ``--check`` writes nothing and exits 1 where a file would change.
Provenance (date, commit, machine) stays in the records."""

from __future__ import annotations

import os
import re
import sys
from pathlib import Path

from .. import fsio
from . import _records
from ._machine import REPO

DOC = REPO / "docs" / "results.md"
README = REPO / "README.md"
BEGIN, END = "<!-- results:begin -->", "<!-- results:end -->"

# the order of the sections; records not named here follow in alphabetical order
ORDER = ("demo", "table1", "material", "geometry", "effects", "hdr", "torus-effects", "armadillo",
         "estimated-lighting", "captures", "realworld", "sfm", "journey", "stability", "sweep", "calibrate", "plan",
         "forecast", "demo-cuda", "hdr-cuda", "plan-cuda")

INTRO = """\
# Results

The latest figures of every benchmark, generated from [bench/records/](../bench/records/)
(command, commit, machine, date) by `python -m backend bench results`; a 2-core x86-64 CPU,
no GPU, unless a table says otherwise. Each table ends with its command (`python -m backend`
left out). Method: [method.md](method.md); experiments: [notes/](notes/).

- **Chamfer-L1**, **F1@0.01/0.005**: the surface against the true mesh, in units of its
  longest side (perfect: 0, 100).
- **held-out** / **relit** PSNR (dB): renders at views never fitted, under the run's / unseen
  lighting; sRGB, within the masks. Times: wall clock unless marked CPU.
"""


def anchor(title: str) -> str:
    """GitHub's anchor of a heading."""
    return re.sub(r"[^\w\- ]", "", title.strip().lower()).replace(" ", "-")


def cell(value) -> str:
    if value is None:
        return ""
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return format(value, "g")
    return str(value).replace("|", "\\|")


def table(rows: list[dict], columns: list[str] | None = None) -> list[str]:
    """A Markdown table of ``rows``; columns empty in every row are left out, numeric ones right-aligned."""
    columns = [c for c in (columns or _records.columns(rows)) if any(r.get(c) not in (None, "") for r in rows)]
    if not columns:
        return []
    numeric = {c: all(isinstance(r.get(c), (int, float)) or r.get(c) is None for r in rows) for c in columns}
    lines = ["|" + "|".join(columns) + "|", "|" + "|".join("--:" if numeric[c] else "--" for c in columns) + "|"]
    lines += ["|" + "|".join(cell(r.get(c)) for c in columns) + "|" for r in rows]
    return lines


def ordered(records: dict[str, dict]) -> list[str]:
    return [n for n in ORDER if n in records] + sorted(n for n in records if n not in ORDER)


def section(name: str, record: dict, link_base: str = "../") -> list[str]:
    """One record's part of docs/results.md."""
    out = [f"## {record.get('title') or name}", ""]
    out += [f'<a id="{a}"></a>' for a in record.get("aliases", [])]
    if record.get("aliases"):
        out.append("")
    context = record.get("context", "").strip()
    if context:
        out += [context[0].upper() + context[1:] + ("" if context.endswith(".") else "."), ""]
    figures = record.get("figures", {})
    rows = figures.get("rows") or []
    if rows and record.get("display") != "scalars":
        out += table(rows, record.get("show") or figures.get("columns")) + [""]
    scalars = figures.get("scalars") or {}
    if scalars:
        out += ["; ".join(f"{k}: **{cell(v)}**" for k, v in scalars.items()) + ".", ""]
    for note in record.get("notes", []):
        out.append(f"- {note[0].upper() + note[1:]}{'' if note.endswith('.') else '.'}")
    if record.get("notes"):
        out.append("")
    plots = [p for p in record.get("plots", []) if not os.path.isabs(p)]
    if plots:
        out += ["Plots: " + ", ".join(f"[{Path(p).stem}]({link_base}{p})" for p in plots) + ".", ""]
    command = record.get("command", "").removeprefix("python -m backend ")
    out += [f"`{command}` · [record]({link_base}bench/records/{name}.json)", ""]
    return out


def document(records: dict[str, dict]) -> str:
    lines = [INTRO]
    for name in ordered(records):
        lines += section(name, records[name])
    return "\n".join(lines).rstrip() + "\n"


# -- the README's lines ------------------------------------------------------------------------------
def _rows(record: dict, **match) -> list[dict]:
    return [r for r in (record.get("figures") or {}).get("rows", []) if all(r.get(k) == v for k, v in match.items())]


def _first(record: dict, **match) -> dict:
    rows = _rows(record, **match)
    return rows[0] if rows else {}


def _value(record: dict, figure: str):
    return next((r.get("value") for r in _rows(record) if str(r.get("figure", "")).startswith(figure)), None)


def _demo(r):
    x = _first(r)
    return (f"F1@0.01 {cell(x.get('F1@0.01'))}, Chamfer {cell(x.get('Chamfer-L1'))}, held-out "
            f"{cell(x.get('held-out dB'))} dB, relit {cell(x.get('relit dB'))} dB in {cell(x.get('minutes'))} min")


def _table1(r):
    rec = [x for x in _rows(r) if str(x.get("row", "")).startswith("reconstruction")]
    return "held-out / relit dB: " + ", ".join(
        f"{x['mesh']} {str(x.get('full', '')).split(' /')[0]} / {cell(x.get('relit dB'))}" for x in rec)


def _geometry(r):
    return str(_first(r).get("result", ""))


def _effects(r):
    rows = _rows(r)
    ratios = [float(str(x.get("wall / CPU ratio", "")).split("x")[0]) for x in rows]
    diffs = [abs(float(a) - float(b)) for a, b in (str(x.get("F1 all / auto", "")).split(" / ") for x in rows)]
    return f"selection {cell(min(ratios))}-{cell(max(ratios))}x faster, F1 within {cell(round(max(diffs), 2))} points"


def _hdr(r):
    worst = [x for x in _rows(r) if x.get("ratio") is not None]
    if not worst:
        return ""
    lo, hi = min(x["ratio"] for x in worst), max(x["ratio"] for x in worst)
    return f"a step with shadow gradients {cell(lo)}-{cell(hi)}x one without"


def _scored(r):
    rows = _rows(r)
    runs = " / ".join(str(x["run"]) for x in rows)
    return (f"F1@0.01 {' / '.join(cell(x.get('F1@0.01')) for x in rows)}, held-out "
            f"{' / '.join(cell(x.get('held-out dB')) for x in rows)} dB" + (f" ({runs})" if len(rows) > 1 else ""))


def _estimated(r):
    rows = _rows(r)
    pairs = [(a, b) for a, b in zip(rows[::2], rows[1::2])]
    return "relit dB, map given / estimated: " + ", ".join(
        f"{str(a['run']).split(',')[0]} {cell(a.get('relit dB'))} / {cell(b.get('relit dB'))}" for a, b in pairs)


def _captures(r):
    return "held-out " + ", ".join(f"{x['capture']} {cell(x.get('held-out dB'))} dB" for x in _rows(r))


def _realworld(r):
    return (f"F1@0.01 {cell(_value(r, 'F1@0.01'))}, {cell(_value(r, 'minutes'))} min, environment rotation error "
            f"{cell(_value(r, 'environment rotation'))}°")


def _sfm(r):
    return "; ".join(f"{x['capture']} {x['registered']}, centres within {str(x.get('centre error max / mean %')).split(' /')[0]} %"
                     for x in _rows(r))


def _stability(r):
    s = (r.get("figures") or {}).get("scalars") or {}
    return f"{cell(s.get('passed'))}/{cell(s.get('cases'))} hard cases pass"


def _calibrate(r):
    parts = []
    for scene in dict.fromkeys(x["scene"] for x in _rows(r)):
        rows = _rows(r, scene=scene)
        parts.append(f"{scene} {' / '.join(cell(x['wall min']) for x in rows)} min, "
                     f"F1 {' / '.join(cell(x['F1@0.01']) for x in rows)}")
    return f"{' / '.join(x['preset'] for x in _rows(r, scene=_first(r).get('scene')))}: " + "; ".join(parts)


def _plan(r):
    s = (r.get("figures") or {}).get("scalars") or {}
    n = s.get("runs", len(_rows(r)))
    return (f"{cell(s.get('within ±30 % in time'))} of {cell(n)} within ±30 % in time, {cell(s.get('within 2 dB'))} "
            f"of {cell(n)} within 2 dB held-out")


def _cuda(r):
    x = _first(r)
    return f"demo reconstructed in {cell(x.get('minutes'))} min, F1@0.01 {cell(x.get('F1@0.01'))}"


# per record: the README line's label and its figures
HEADLINES = {
    "demo": ("demo (`./dev.sh demo`)", _demo),
    "table1": ("Table 1 (20 / 10 min)", _table1),
    "geometry": ("geometry, dragon from carving", _geometry),
    "effects": ("effects measured, not all simulated", _effects),
    "hdr": ("HDR-lit step cost", _hdr),
    "torus-effects": ("effects by accuracy per second", _scored),
    "armadillo": ("HDR-lit armadillo (20 min)", _scored),
    "estimated-lighting": ("no HDR map: estimated lighting", _estimated),
    "captures": ("real captures (10 min)", _captures),
    "realworld": ("real-world video (spot, 40 frames)", _realworld),
    "sfm": ("structure from motion", _sfm),
    "stability": ("stability", _stability),
    "calibrate": ("presets", _calibrate),
    "plan": ("predicted time and held-out PSNR", _plan),
    "demo-cuda": ("CUDA (H200)", _cuda),
}


def readme_block(records: dict[str, dict]) -> str:
    """The README's lines between the markers: a table of one line per benchmark."""
    lines = [BEGIN, "| benchmark | figures |", "|---|---|"]
    for name in ordered(records):
        if name not in HEADLINES:
            continue
        label, headline = HEADLINES[name]
        try:
            text = headline(records[name])
        except (KeyError, TypeError, ValueError):
            text = ""
        if text:
            title = records[name].get("title") or name
            lines.append(f"| [{label}](docs/results.md#{anchor(title)}) | {text} |")
    return "\n".join(lines + [END])


def with_block(readme: str, block: str) -> str:
    """``readme`` with the text between the markers replaced by ``block``; unchanged without markers."""
    start, end = readme.find(BEGIN), readme.find(END)
    if start < 0 or end < start:
        return readme
    return readme[:start] + block + readme[end + len(END):]


# -- command ---------------------------------------------------------------------------------------
def add_arguments(parser) -> None:
    parser.add_argument("--records", type=Path, default=None,
                        help="folder of the records (default: $SFT_RECORDS, else bench/records)")
    parser.add_argument("--doc", type=Path, default=DOC, help="the document to write (default: docs/results.md)")
    parser.add_argument("--readme", type=Path, default=README,
                        help="the README whose block between the results markers is rewritten (default: README.md)")
    parser.add_argument("--check", action="store_true", help="write nothing; exit 1 where a file would change")


def generate(records_dir: Path | None, doc: Path, readme: Path | None, check: bool = False) -> list[Path]:
    """Write (or with ``check`` only compare) the document and the README block; the files that
    differ(ed) from what the records give."""
    records = _records.load_all(records_dir)
    outputs = {Path(doc): document(records)}
    if readme is not None and Path(readme).is_file():
        outputs[Path(readme)] = with_block(Path(readme).read_text(encoding="utf-8"), readme_block(records))
    changed = []
    for path, text in outputs.items():
        if not path.is_file() or path.read_text(encoding="utf-8") != text:
            changed.append(path)
            if not check:
                fsio.write_text(path, text)
    return changed


def run(args) -> int:
    changed = generate(args.records, args.doc, args.readme, args.check)
    for path in changed:
        print(f"{'differs' if args.check else 'wrote'}: {path}", file=sys.stderr if args.check else sys.stdout)
    return 1 if args.check and changed else 0
