"""The shipped calibration file (``backend/presets.json``) describes the presets as they ship,
names the commits and the material it was measured with (reconstruct's default: the run the
panel's button starts), and no preset is dominated by a cheaper one unless the file says so.

These read the committed file, which ``python -m backend bench calibrate`` writes; they fail
when a preset changes without a new calibration. A costlier preset that is not more accurate
on a kind's scene (more levels buy no F1@0.01 at the calibration scenes' 128 px once the staged
material fits the surface) must be marked with the preset that dominates it: that keeps a time
budget off it and has the panel say so. The cheapest preset is never dominated, and the
presets left keep the panel's order in time and in accuracy."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest

from backend.bench.calibrate import (KINDS, MATERIAL, MATERIAL_CHOICES, calibration, calibration_rows, dominated,
                                     entry_material, materials_of, record_rows)
from backend.planning.presets import CALIBRATION_FILE, PRESETS, preset_for_budget

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def shipped() -> dict:
    assert CALIBRATION_FILE.is_file(), "backend/presets.json is missing: run python -m backend bench calibrate"
    return json.loads(CALIBRATION_FILE.read_text())


def kind_entries(shipped: dict, kind: str) -> dict:
    if kind not in shipped["kinds"]:
        pytest.skip(f"the {kind} kind is not calibrated (python -m backend bench calibrate --scenes {KINDS[kind]})")
    return shipped["kinds"][kind]["presets"]


def test_the_point_lit_kind_is_calibrated_and_is_the_top_level(shipped):
    assert "point" in shipped["kinds"] and set(shipped["kinds"]) <= set(KINDS)
    for kind, doc in shipped["kinds"].items():
        assert doc["scene"].startswith(KINDS[kind] + ":")
    assert shipped["presets"] == shipped["kinds"]["point"]["presets"] and shipped["scene"].startswith("dragon:")


@pytest.mark.parametrize("kind", sorted(KINDS))
def test_every_preset_is_calibrated_as_it_ships(shipped, kind):
    entries = kind_entries(shipped, kind)
    assert set(entries) == set(PRESETS)
    for name, entry in entries.items():
        assert entry["overrides"] == PRESETS[name], f"{name} changed since it was calibrated: rerun bench calibrate"
        assert entry["expected_minutes"] > 0 and 0 < entry["expected_f1"] <= 1
        assert entry_material(entry) in MATERIAL_CHOICES
    # the kind names its entries' materials (a file recalibrated a preset at a time may hold two)
    assert shipped["kinds"][kind].get("material", materials_of(entries)) == materials_of(entries)


def test_the_presets_are_calibrated_with_reconstructs_default_material():
    from backend.planning.job import DEFAULT_MATERIAL

    assert MATERIAL == DEFAULT_MATERIAL == "staged"


@pytest.mark.parametrize("kind", sorted(KINDS))
def test_a_preset_dominated_by_a_cheaper_one_is_marked_and_passed_by(shipped, kind):
    entries = kind_entries(shipped, kind)
    found = dict(dominated(entries))
    # the quick look and the default always buy what they cost
    assert not {"draft", "balanced"} & found.keys(), found
    # each dominated preset is marked, naming a preset that dominates it, and only those are
    assert {n: e["dominated_by"] for n, e in entries.items() if e.get("dominated_by")}.keys() == found.keys()
    for name, entry in entries.items():
        if entry.get("dominated_by"):
            by = entries[entry["dominated_by"]]
            assert by["expected_minutes"] <= entry["expected_minutes"] and by["expected_f1"] >= entry["expected_f1"]
            assert preset_for_budget(entry["expected_minutes"] + 1, kind=kind) != name
    # the costlier preset takes longer, so each capture's plan keeps the panel's order
    by_time = sorted(entries, key=lambda n: entries[n]["expected_minutes"])
    assert by_time == ["draft", "balanced", "final"]
    f1 = [entries[n]["expected_f1"] for n in by_time if n not in found]
    assert f1 == sorted(f1) and len(set(f1)) == len(f1)


@pytest.mark.parametrize("kind", sorted(KINDS))
def test_the_calibration_names_clean_commits_of_this_history(shipped, kind):
    """Each preset's run names the commit it ran (presets run one after the other, so a
    recalibrated preset may be newer); none from a tree with local changes."""
    kind_entries(shipped, kind)
    codes = [c.strip() for c in shipped["kinds"][kind]["code"].split(",")]
    assert all("+dirty" not in c and c != "unknown" for c in codes), codes
    if not (REPO / ".git").exists():
        pytest.skip("not a git checkout: the commits cannot be looked up")
    shallow = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--is-shallow-repository"],
                             capture_output=True, text=True).stdout.strip() == "true"
    for code in codes:
        known = subprocess.run(["git", "-C", str(REPO), "cat-file", "-e", f"{code}^{{commit}}"], capture_output=True)
        if known.returncode != 0 and shallow:
            pytest.skip("shallow clone: the calibration commits are not fetched")
        assert known.returncode == 0, f"{code} is not a commit of this repository"
        ancestor = subprocess.run(["git", "-C", str(REPO), "merge-base", "--is-ancestor", code, "HEAD"])
        assert ancestor.returncode == 0, f"{code} is not an ancestor of HEAD"


def test_dominance_is_found_in_a_calibration_built_from_rows():
    # the old Final: slower than Balanced and less accurate
    def row(name, seconds, f1):
        return {"scene": "dragon", "name": name, "rc": 0, "seconds": seconds, "cpu_seconds": seconds, "f1": f1,
                "knobs": {"material": MATERIAL}, "code": "abc", "overrides": PRESETS[name]}

    machine = {"cpu": "x", "cores": 2}
    doc = calibration([row("draft", 68, 91.9), row("balanced", 399, 97.2), row("final", 746, 95.7)], machine)
    assert dominated(doc["presets"]) == [("final", "balanced")]
    assert doc["presets"]["final"]["dominated_by"] == "balanced" and "dominated_by" not in doc["presets"]["balanced"]
    assert all(doc["presets"][n]["overrides"] == PRESETS[n] for n in PRESETS)
    assert doc["code"] == "abc" and list(doc["kinds"]) == ["point"]
    hdr = [{**row(n, t, f), "scene": "armadillo_env", "code": "def"} for n, t, f in
           (("draft", 50, 95.0), ("balanced", 300, 97.0), ("final", 600, 98.0))]
    # a row fitted with another material than the scene's is not the preset's
    stale = {**row("final", 100, 99.0), "scene": "armadillo_env", "code": "old", "knobs": {"material": "constant"}}
    doc = calibration([row("draft", 68, 91.9), row("balanced", 399, 97.2), row("final", 746, 97.9), stale] + hdr,
                      machine)
    assert dominated(doc["presets"]) == [] and doc["kinds"]["environment"]["code"] == "def"
    assert doc["kinds"]["environment"]["presets"]["final"]["expected_f1"] == 0.98
    assert "target" not in doc["kinds"]["environment"]["presets"]["draft"]  # the targets are the dragon's
    # a run that did not record its overrides cannot vouch for the preset as it ships
    legacy = {k: v for k, v in row("draft", 68, 91.9).items() if k != "overrides"}
    assert calibration([legacy], machine)["presets"]["draft"]["overrides"] is None


def _rows(scene: str, material: str, code: str, figures) -> list[dict]:
    return [{"scene": scene, "name": n, "rc": 0, "seconds": t, "cpu_seconds": t, "f1": f, "knobs": {"material": material},
             "code": code, "overrides": PRESETS[n]} for n, t, f in figures]


def test_one_kind_is_calibrated_at_a_time_and_the_others_are_kept():
    machine = {"cpu": "x", "cores": 2}
    point = calibration(_rows("dragon", MATERIAL, "abc", (("draft", 60, 92.0), ("balanced", 500, 97.0),
                                                          ("final", 900, 98.0))), machine)
    env = _rows("armadillo_env", MATERIAL, "def", (("draft", 120, 95.0), ("balanced", 400, 96.0), ("final", 700, 97.0)))
    doc = calibration(env, machine, previous=point)
    assert list(doc["kinds"]) == ["point", "environment"]
    assert doc["kinds"]["point"] == point["kinds"]["point"]  # kept as written, not rebuilt
    assert doc["presets"] == point["presets"] and doc["scene"] == point["scene"] and doc["code"] == "abc"
    assert doc["kinds"]["environment"]["code"] == "def"
    # recalibrating one preset of the point-lit kind keeps the others and the environment's entries
    again = calibration(_rows("dragon", MATERIAL, "ghi", (("final", 950, 98.5),)), machine, previous=doc)
    assert again["code"] == "abc, ghi" and again["kinds"]["environment"] == doc["kinds"]["environment"]
    assert list(again["presets"]) == ["draft", "balanced", "final"] and again["kinds"]["point"]["code"] == "abc, ghi"
    assert again["presets"]["final"]["expected_minutes"] == round(950 / 60, 2)
    assert again["presets"]["draft"] == point["presets"]["draft"]
    # once each entry names its commit, a preset measured again drops the commit it replaces
    final = calibration(_rows("dragon", MATERIAL, "jkl", (("final", 900, 98.6),)), machine, previous=again)
    assert final["code"] == "abc, jkl" and final["presets"]["final"]["code"] == "jkl"
    # a file written before kinds existed is the point-lit kind's
    legacy = {k: v for k, v in point.items() if k != "kinds"}
    assert calibration(env, machine, previous=legacy)["kinds"]["point"] == point["kinds"]["point"]


def test_a_dominated_preset_is_marked_and_a_budget_passes_it_by(tmp_path):
    machine = {"cpu": "x", "cores": 2}
    point = calibration(_rows("dragon", MATERIAL, "abc", (("draft", 60, 92.0), ("balanced", 500, 97.0),
                                                          ("final", 900, 98.0))), machine)
    env = _rows("armadillo_env", MATERIAL, "def", (("draft", 150, 96.2), ("balanced", 900, 97.35),
                                                      ("final", 1400, 97.31)))
    doc = calibration(env, machine, previous=point)
    assert doc["kinds"]["environment"]["presets"]["final"]["dominated_by"] == "balanced"
    path = tmp_path / "presets.json"
    path.write_text(json.dumps(doc))
    assert preset_for_budget(60, path, kind="environment") == "balanced"
    assert preset_for_budget(60, path, kind="point") == "final"
    # measured again and now the most accurate, the mark goes
    again = calibration(_rows("armadillo_env", MATERIAL, "ghi", (("final", 1300, 97.9),)), machine, previous=doc)
    assert "dominated_by" not in again["kinds"]["environment"]["presets"]["final"]
    path.write_text(json.dumps(again))
    assert preset_for_budget(60, path, kind="environment") == "final"


def test_each_material_is_calibrated_apart_and_every_entry_names_its_own():
    machine = {"cpu": "x", "cores": 2}
    constant = _rows("dragon", "constant", "old", (("draft", 60, 92.0), ("balanced", 500, 97.0), ("final", 900, 98.0)))
    staged = _rows("dragon", MATERIAL, "new", (("draft", 150, 93.0),))
    # the default material's calibration takes only its own rows
    doc = calibration(constant + staged, machine)
    assert list(doc["presets"]) == ["draft"] and doc["presets"]["draft"]["material"] == MATERIAL
    assert doc["presets"]["draft"]["expected_minutes"] == 2.5 and doc["material"] == MATERIAL
    # Constant is calibrated as rows of its own (bench calibrate --material constant)
    apart = calibration(constant + staged, machine, material="constant")
    assert [e["material"] for e in apart["presets"].values()] == ["constant"] * 3
    assert apart["kinds"]["point"]["material"] == "constant"
    # one preset recalibrated with the default material over a file of Constant's: the others are
    # kept, each entry says what it ran, and the kind lists both
    merged = calibration(staged, machine, previous=calibration(constant, machine, material="constant"))
    assert {n: entry_material(e) for n, e in merged["presets"].items()} == {
        "draft": MATERIAL, "balanced": "constant", "final": "constant"}
    assert merged["kinds"]["point"]["material"] == "constant, staged" and merged["code"] == "new, old"
    rows = record_rows(merged)
    assert [(r["preset"], r["material"], r["code"]) for r in rows] == [
        ("Draft", MATERIAL, "new"), ("Balanced", "constant", "old"), ("Final", "constant", "old")]
    assert rows[0]["wall min"] == 2.5 and rows[0]["F1@0.01"] == 93.0


def test_every_entry_names_the_machine_it_was_measured_on():
    first, second = {"cpu": "Alpha", "cores": 2, "variant": "llvm_ad_rgb"}, {"cpu": "Beta", "cores": 4, "variant": "llvm_ad_rgb"}
    old = calibration([{**r, "machine": first} for r in _rows("dragon", MATERIAL, "abc", (("draft", 60, 92.0),
                                                                                          ("balanced", 500, 97.0)))], first)
    doc = calibration([{**r, "machine": second} for r in _rows("dragon", MATERIAL, "def", (("draft", 90, 93.0),))],
                      second, previous=old)
    # the file's machine is the latest call's; each entry keeps its own
    assert doc["machine"] == "Beta, 4 cores, llvm_ad_rgb"
    assert {n: e["machine"] for n, e in doc["presets"].items()} == {
        "draft": "Beta, 4 cores, llvm_ad_rgb", "balanced": "Alpha, 2 cores, llvm_ad_rgb"}
    assert [(r["preset"], r["machine"]) for r in record_rows(doc)] == [
        ("Draft", "Beta, 4 cores, llvm_ad_rgb"), ("Balanced", "Alpha, 2 cores, llvm_ad_rgb")]
    # an entry written before entries named it is the machine of the file it was read from
    legacy = {k: v for k, v in old.items() if k != "kinds"}
    legacy["presets"] = {n: {k: v for k, v in e.items() if k != "machine"} for n, e in legacy["presets"].items()}
    again = calibration([{**r, "machine": second} for r in _rows("dragon", MATERIAL, "def", (("draft", 90, 93.0),))],
                        second, previous=legacy)
    assert again["presets"]["balanced"]["machine"] == "Alpha, 2 cores, llvm_ad_rgb"


@pytest.mark.parametrize("kind", sorted(KINDS))
def test_the_shipped_entries_name_their_machines(shipped, kind):
    assert all(e.get("machine") for e in kind_entries(shipped, kind).values())


def test_a_results_file_keeps_a_row_of_each_material(tmp_path):
    from backend.bench.sweep import append_result

    results = tmp_path / "results.jsonl"
    for r in (_rows("dragon", "constant", "a", (("draft", 60, 92.0),)) + _rows("dragon", MATERIAL, "b", (("draft", 90, 93.0),))
              + _rows("dragon", MATERIAL, "c", (("draft", 80, 93.5),))):
        append_result(results, r)
    rows = calibration_rows(results)
    assert sorted((r["knobs"]["material"], r["code"]) for r in rows) == [("constant", "a"), (MATERIAL, "c")]


def test_the_command_merges_a_kind_into_the_file_it_replaces(tmp_path):
    import sys

    from backend.bench.sweep import append_result

    machine = {"cpu": "x", "cores": 2}
    out = tmp_path / "presets.json"
    out.write_text(json.dumps(calibration(_rows("dragon", MATERIAL, "abc", (("draft", 60, 92.0),)), machine)))
    results = tmp_path / "results.jsonl"
    for r in _rows("armadillo_env", MATERIAL, "def", (("draft", 120, 95.0), ("balanced", 400, 96.0))):
        append_result(results, {**r, "machine": machine})
    cmd = [sys.executable, "-m", "backend", "bench", "calibrate", "--scenes", "armadillo_env", "--from-results",
           str(results), "--out", str(out)]
    done = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    doc = json.loads(out.read_text())
    assert doc["code"] == "abc" and set(doc["kinds"]) == {"point", "environment"}
    assert doc["kinds"]["environment"]["presets"]["balanced"]["expected_minutes"] == round(400 / 60, 2)
    # a file that is not a calibration is named, not overwritten
    out.write_text("{not json")
    bad = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True)
    assert bad.returncode == 2 and str(out) in bad.stderr and "Traceback" not in bad.stderr
    assert out.read_text() == "{not json"


def test_the_command_calibrates_constant_into_a_file_of_its_own(tmp_path):
    import sys

    from backend.bench.sweep import append_result

    machine = {"cpu": "x", "cores": 2}
    results = tmp_path / "results.jsonl"  # a sweep's rows: one constant material
    for r in _rows("dragon", "constant", "abc", (("draft", 60, 92.0), ("balanced", 500, 97.0))):
        append_result(results, {**r, "machine": machine})
    shipped = tmp_path / "presets.json"
    base = [sys.executable, "-m", "backend", "bench", "calibrate", "--scenes", "dragon", "--from-results", str(results)]
    # the default material has no rows there: one line naming the file and the way out, nothing written
    bad = subprocess.run(base + ["--out", str(shipped)], cwd=REPO, capture_output=True, text=True)
    assert bad.returncode == 2 and str(results) in bad.stderr and "--material constant" in bad.stderr
    assert "Traceback" not in bad.stderr and not shipped.exists()
    done = subprocess.run(base + ["--material", "constant", "--work", str(tmp_path / "work")], cwd=REPO,
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    doc = json.loads((tmp_path / "work" / "presets-constant.json").read_text())
    assert doc["material"] == "constant" and set(doc["presets"]) == {"draft", "balanced"}
    assert json.loads(done.stdout.splitlines()[-1])["material"] == "constant"
