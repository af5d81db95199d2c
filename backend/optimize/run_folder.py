"""The run folder (docs/protocol.md): snapshots, resumable state, STOP requests, results.

Every write is atomic. A snapshot writes its display mesh, then the state for --resume,
then ``snapshot.json``, so ``snapshot.json`` always names a complete mesh and the state
is never older than the snapshot it belongs to; only the newest two display meshes stay."""

from __future__ import annotations

import dataclasses
import io
import json
from pathlib import Path

import numpy as np

from .. import fsio
from ..errors import InputError
from ..geometry.mesh import Mesh, save_mesh

KEEP_SNAPSHOTS = 2


class StopRequested(Exception):
    """A client created RUN/STOP."""


class RunFolder:
    def __init__(self, path: str | Path):
        self.path = Path(path)

    @classmethod
    def create(cls, path: str | Path, resume: bool, overwrite: bool) -> "RunFolder":
        path = Path(path)
        if path.exists() and not path.is_dir():
            raise InputError(path, "the run folder is a file", "give --out a folder (new, or an earlier run's)")
        if resume:
            if not (path / "state" / "state.json").is_file():
                raise InputError(path, "nothing to resume (no state/state.json)",
                                 "start a new run without --resume")
        elif path.exists() and any(path.iterdir()):
            if not overwrite:
                raise InputError(path, "run folder exists and is not empty",
                                 "choose a new folder, pass --resume to continue it, or --overwrite")
            for name in ("snapshots", "state"):
                for f in sorted((path / name).glob("*")) if (path / name).is_dir() else []:
                    f.unlink()
            for name in ("events.jsonl", "snapshot.json", "result.ply", "report.json", "accuracy_time.png", "STOP",
                         cls.COMMAND):
                (path / name).unlink(missing_ok=True)
        path.mkdir(parents=True, exist_ok=True)
        (path / "STOP").unlink(missing_ok=True)
        return cls(path)

    COMMAND = "command.json"

    def record_command(self, argv: list[str]) -> None:
        """Keep the command line that started the run (``RUN/command.json``), so a client can
        resume it with the same options."""
        fsio.write_json(self.path / self.COMMAND, {"argv": [str(a) for a in argv]})

    @property
    def events(self) -> Path:
        return self.path / "events.jsonl"

    def check_stop(self) -> None:
        if (self.path / "STOP").exists():
            raise StopRequested

    # -- snapshots -------------------------------------------------------------------------------
    def snapshot(self, display: Mesh, info: dict, state: dict, material) -> str:
        """Write a snapshot; returns the mesh path relative to the run folder."""
        rel = f"snapshots/{int(info['iteration']):06d}.ply"
        save_mesh(self.path / rel, display)
        self.save_state(state, material)
        fsio.write_json(self.path / "snapshot.json", {"mesh": rel, **info})
        meshes = sorted((self.path / "snapshots").glob("[0-9]*.ply"))
        for old in meshes[:-KEEP_SNAPSHOTS]:
            old.unlink(missing_ok=True)
        return rel

    # -- state for --resume ----------------------------------------------------------------------
    def save_state(self, state: dict, material) -> None:
        """``state``: JSON-able schedule position plus ``vertices`` and ``faces`` arrays.

        The mesh and material go to files named by the iteration; ``state/state.json``,
        written last, names them, so the three always belong together."""
        folder = self.path / "state"
        stem = f"{int(state['iteration']):06d}"
        buf = io.BytesIO()
        np.savez(buf, vertices=np.asarray(state["vertices"]), faces=np.asarray(state["faces"]))
        fsio.write_bytes(folder / f"{stem}.mesh.npz", buf.getvalue())
        material.save(folder / f"{stem}.material.npz")
        info = {k: v for k, v in state.items() if k not in ("vertices", "faces")}
        info.update(mesh=f"{stem}.mesh.npz", material=f"{stem}.material.npz")
        fsio.write_json(folder / "state.json", info)
        for old in folder.glob("*.npz"):
            if not old.name.startswith(stem + "."):
                old.unlink(missing_ok=True)

    def load_state(self) -> tuple[dict, Path]:
        """The saved schedule position with ``vertices``/``faces``, and the material file."""
        folder = self.path / "state"
        try:
            state = json.loads((folder / "state.json").read_text())
            data = np.load(folder / state["mesh"])
            state["vertices"], state["faces"] = data["vertices"], data["faces"]
        except (OSError, ValueError, KeyError) as err:
            raise InputError(folder, f"cannot read the saved state ({err})", "start a new run") from err
        return state, folder / state["material"]


@dataclasses.dataclass
class Result:
    """How a run ended: ``exit_code`` 0 (done) or 130 (cancelled), and its folder."""

    exit_code: int
    folder: Path

    @property
    def report(self) -> dict | None:
        path = self.folder / "report.json"
        return json.loads(path.read_text()) if self.exit_code == 0 and path.is_file() else None


def snapshot_interval(config, snapshot_seconds: float) -> float:
    """``snapshot_every_s``, or longer so that writing snapshots of ``snapshot_seconds`` each
    takes at most ``snapshot_share`` of the run."""
    c = config
    return max(c.snapshot_every_s, snapshot_seconds / c.snapshot_share if c.snapshot_share > 0 else 0.0)
