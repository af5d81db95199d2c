"""Cycles work in a child Blender, so the artist's Blender never waits on it.

Run as a script: ``blender --background --python addon/worker.py -- COMMAND ...`` (or, with
the bpy module, ``python addon/worker.py COMMAND ...``). It speaks the add-on's JSON-lines
protocol on stdout (``start``, ``progress`` with ``fraction`` and ``stage``, ``done``, or
``error`` and exit code 2) and writes only into the folder it is given; the add-on moves
the result into place once it is complete, so a worker stopped midway leaves nothing.

- ``render BLEND SCENE``: append scene SCENE from BLEND and render it with Cycles to the
  PNG its render path names (Relit Preview);
- ``export BLEND OBJECT OUT [--bake] [--size N] [--device D]``: append object OBJECT and
  write it as binary glTF to OUT, its textures baked by Cycles (:func:`addon.export.export_gltf`).
"""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

import bpy

ROOT = Path(__file__).resolve().parents[1]  # holds addon/


def emit(event: str, **fields) -> None:
    print(json.dumps({"event": event, **fields}), flush=True)


def _append(blend: str, kind: str, name: str):
    bpy.ops.wm.read_homefile(use_empty=True)
    with bpy.data.libraries.load(blend, link=False) as (_src, dst):
        setattr(dst, kind, [name])
    block = getattr(dst, kind)[0]
    if block is None:
        raise SystemExit(f"{blend} holds no {kind[:-1]} '{name}'")
    return block


SAMPLE = re.compile(r"Sample (\d+)/(\d+)")


def render(blend: str, scene_name: str) -> None:
    scene = _append(blend, "scenes", scene_name)

    def stats(text, *_args):
        found = SAMPLE.search(str(text))
        if found and int(found[2]):
            emit("progress", stage=f"rendering, sample {found[1]}/{found[2]}", fraction=int(found[1]) / int(found[2]))

    bpy.app.handlers.render_stats.append(stats)
    emit("progress", stage="rendering", fraction=0.0)
    bpy.ops.render.render(write_still=True, scene=scene.name)
    emit("done", path=scene.render.filepath)


def export(blend: str, name: str, out: str, bake: bool, size: int, device: str) -> None:
    sys.path.insert(0, str(ROOT))
    from addon import export as exporter  # the add-on's own code, imported as a plain package
    from addon.io.errors import AddonInputError

    obj = _append(blend, "objects", name)
    try:
        info = exporter.export_gltf(bpy.context, obj, Path(out), bake, size, device=device, use_run=False,
                                    progress=lambda fraction, stage: emit("progress", stage=stage, fraction=fraction))
    except AddonInputError as err:
        emit("error", message=str(err))
        raise SystemExit(2) from None
    emit("done", **info)


def main(argv: list[str]) -> int:
    emit("start", command=argv[0] if argv else "")
    if argv[:1] == ["render"] and len(argv) == 3:
        render(argv[1], argv[2])
    elif argv[:1] == ["export"] and len(argv) >= 4:
        options = argv[4:]
        size = int(options[options.index("--size") + 1]) if "--size" in options else 0
        device = options[options.index("--device") + 1] if "--device" in options else "AUTO"
        export(argv[1], argv[2], argv[3], "--bake" in options, size, device)
    else:
        emit("error", message=f"unknown worker command: {' '.join(argv)}")
        return 2
    return 0


if __name__ == "__main__":
    args = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else sys.argv[1:]
    sys.exit(main(args))
