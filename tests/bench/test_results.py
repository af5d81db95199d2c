"""``bench results``: docs/results.md and the README's figures are what the records give, and
a benchmark's new record changes its own table only."""

from __future__ import annotations

import json
import shutil

from backend.bench import _all, _records, results
from tests.helpers import REPO, run_cli

RECORDS = REPO / "bench" / "records"


def test_the_committed_document_and_readme_are_what_the_records_give(tmp_path):
    readme = tmp_path / "README.md"
    shutil.copy(REPO / "README.md", readme)
    changed = results.generate(RECORDS, tmp_path / "results.md", readme)
    assert (tmp_path / "results.md").read_bytes() == (REPO / "docs" / "results.md").read_bytes()
    assert readme.read_bytes() == (REPO / "README.md").read_bytes() and changed == [tmp_path / "results.md"]
    assert len((REPO / "docs" / "results.md").read_text()) < 21_500  # a table and a line for each of about 35 records
    assert len((REPO / "README.md").read_text()) < 12_000 and results.BEGIN in readme.read_text()


def test_check_on_the_checkout_changes_nothing():
    proc = run_cli("bench", "results", "--records", RECORDS, "--check", timeout=120)
    assert proc.returncode == 0, proc.stderr


def test_a_new_record_changes_only_its_own_table(tmp_path):
    folder = tmp_path / "records"
    shutil.copytree(RECORDS, folder)
    before = results.document(_records.load_all(folder))
    path = _records.write_record("sfm", title="Structure from motion", context="a new run", into=folder,
                                 rows=[{"capture": "dino", "registered": "16/16", "minutes": 0.4}],
                                 command="python -m backend bench sfm --out OUT/sfm.json")
    record = json.loads(path.read_text())
    assert record["commit"] and record["date"] and record["machine"]["cores"] >= 1 and record["figures"]["rows"]
    after = results.document(_records.load_all(folder))
    start = before.index("## Structure from motion")
    end = before.index("\n## ", start + 1)
    assert after[:start] == before[:start]
    assert after[after.index("\n## ", start + 1):] == before[end:]
    own = after[start:after.index("\n## ", start + 1)]
    assert "A new run." in own and "|dino|16/16|0.4|" in own and "fox" not in own


def test_records_go_where_sft_records_points_and_merge_on_a_column(tmp_path, monkeypatch):
    committed = (RECORDS / "hdr.json").read_bytes()
    monkeypatch.setenv(_records.ENV, str(tmp_path))
    _records.write_record("hdr", title="t", context="c", rows=[{"scene": "a", "ratio": 1.5}], merge_on="scene",
                          command="python -m backend bench hdr --out A")
    _records.write_record("hdr", title="t", context="c", rows=[{"scene": "b", "ratio": 1.2}], merge_on="scene",
                          command="python -m backend bench hdr --out B")
    _records.write_record("hdr", title="t", context="c", rows=[{"scene": "a", "ratio": 1.4}], merge_on="scene",
                          command="python -m backend bench hdr --out A", variant="cuda_ad_rgb")
    record = _records.read(tmp_path / "hdr.json")
    assert [(r["scene"], r["ratio"]) for r in record["figures"]["rows"]] == [("a", 1.5), ("b", 1.2)]
    assert record["commands"] == ["python -m backend bench hdr --out A", "python -m backend bench hdr --out B"]
    assert _records.read(tmp_path / "hdr-cuda.json")["figures"]["rows"] == [{"scene": "a", "ratio": 1.4}]
    assert (RECORDS / "hdr.json").read_bytes() == committed


def test_every_job_has_a_record_and_every_record_a_command():
    names = {p.stem for p in RECORDS.glob("*.json")}
    for job in _all.JOBS:
        assert job.record in names, job.name
        assert job.commands and job.hours > 0
    for name, record in _records.load_all(RECORDS).items():
        assert record["benchmark"] == name and record["command"] and record["figures"]["rows"], name
        assert {"title", "context", "commit", "machine", "date", "plots"} <= set(record), name
        assert all((REPO / p).is_file() for p in record["plots"]), name
