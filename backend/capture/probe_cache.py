"""What a capture's runs measured before their first step, kept beside the capture for its
later runs: ``CAPTURE/.sft-cache/NAME.json``, ``{key: entry}``.

A key is a hash of everything the measurement depends on (``key``): the capture's content
(``fingerprint``: the size and modification time of every file in its folder and of the
files it names outside it), the caller's inputs, the code that measures (``code_version`` of
its source files), the Mitsuba version and variant, and the machine where timings enter
(``machine``).
A key that matches gives back the entry an earlier run stored, so the decision made from it
is the same; anything edited misses. A folder that cannot be written keeps nothing and a
file that cannot be read is a miss: the cache only ever saves time."""

from __future__ import annotations

import hashlib
import json
import os
import platform
from pathlib import Path

from .. import fsio
from ..errors import InputError

FOLDER = ".sft-cache"
MOST_ENTRIES = 16  # entries a cache file keeps (the newest)


def fingerprint(capture) -> str:
    """The capture's content, cheaply: (relative path, size, mtime) of every file under its
    folder except the cache and of the environment map it names outside it, and the capture
    as this process holds it (its frames with their cameras and lights, the environment, the
    camera response: a run may hold views out or light the capture with ``--env``)."""
    root = Path(capture.root)
    rows = []
    for path in sorted(root.rglob("*")):
        rel = path.relative_to(root)
        if rel.parts and rel.parts[0] == FOLDER or not path.is_file():
            continue
        st = path.stat()
        rows.append(f"{rel.as_posix()}:{st.st_size}:{st.st_mtime_ns}")
    env = capture.environment
    if env is not None:
        rows.append(json.dumps({**env.to_json(root), "frame": env.frame}, sort_keys=True, default=str))
        if Path(env.path).is_file() and root not in Path(env.path).resolve().parents:
            st = Path(env.path).stat()
            rows.append(f"{Path(env.path).resolve()}:{st.st_size}:{st.st_mtime_ns}")
    rows += [json.dumps(f.to_json(root), sort_keys=True, default=str) for f in capture.frames]
    rows.append(json.dumps(capture.camera_response.to_json(), sort_keys=True, default=str))
    return hashlib.sha256("\n".join(rows).encode()).hexdigest()


def code_version(*files: str | os.PathLike) -> str:
    """A hash of the source ``files`` (a module's ``__file__``; folders: their ``*.py``)."""
    digest = hashlib.sha256()
    for f in files:
        path = Path(f)
        for p in sorted(path.rglob("*.py")) if path.is_dir() else [path]:
            digest.update(p.name.encode())
            digest.update(p.read_bytes())
    return digest.hexdigest()[:16]


def machine() -> dict:
    """The CPU model and core count (for entries that hold timings)."""
    model = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            model = next((line.split(":", 1)[1].strip() for line in f if line.startswith("model name")), model)
    except OSError:
        pass
    return {"cpu": model, "cores": os.cpu_count()}


def key(capture, **parts) -> str:
    """The key of a measurement on ``capture`` with ``parts`` (JSON-able; ``str`` for the rest:
    the caller's inputs, its ``code_version``, the Mitsuba version and variant it rendered
    with), the capture's ``fingerprint`` included."""
    doc = {"capture": fingerprint(capture), **parts}
    return hashlib.sha256(json.dumps(doc, sort_keys=True, default=str).encode()).hexdigest()[:24]


def path(capture, name: str) -> Path:
    return Path(capture.root) / FOLDER / f"{name}.json"


def load(capture, name: str, entry_key: str):
    """The entry stored under ``entry_key`` in the cache ``name`` of ``capture``, or None."""
    try:
        entries = json.loads(path(capture, name).read_text())
    except (OSError, ValueError):
        return None
    return entries.get(entry_key) if isinstance(entries, dict) else None


def store(capture, name: str, entry_key: str, entry, most: int = MOST_ENTRIES) -> bool:
    """Keep ``entry`` under ``entry_key`` (the newest ``most`` stay); False when the capture's
    folder cannot be written."""
    file = path(capture, name)
    try:
        entries = json.loads(file.read_text()) if file.is_file() else {}
    except (OSError, ValueError):
        entries = {}
    entries = {k: v for k, v in (entries if isinstance(entries, dict) else {}).items() if k != entry_key}
    entries = dict(list(entries.items())[len(entries) - most + 1:] if len(entries) >= most else entries)
    entries[entry_key] = entry
    try:
        fsio.write_text(file, json.dumps(entries, default=_plain))
    except (OSError, InputError):  # a read-only or full disk: nothing kept
        return False
    return True


def _plain(value):
    """NumPy scalars and arrays as JSON takes them."""
    if hasattr(value, "tolist"):
        return value.tolist()
    raise TypeError(f"{type(value).__name__} is not JSON serialisable")
