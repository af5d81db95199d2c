"""Shape from Tracing add-on: a thin Blender layer over the backend process.

Two layers, as Blender's glTF add-on keeps ``io/`` apart from ``blender/``:

- ``io/``: the bpy-free logic (backend interpreter and process, event stream and run state,
  capture, frame and PLY files, the preset file); it imports without Blender.
- the rest is the Blender layer: the modules beside ``io/`` (scene objects, world, images,
  jobs, preferences, properties), ``operators/`` and ``ui/``. They stay at this level, not
  in a ``blender/`` folder, because ``operators/`` and ``ui/`` are Blender code too: "all but
  ``io/`` needs bpy" is one rule.

Mitsuba is never imported: the backend runs as ``<python> -m backend`` in its own
interpreter (docs/protocol.md)."""

ROOT_PACKAGE = __package__.rpartition(".")[0] or __package__  # the extension's module name


def _modules():
    from . import capture_state, operators, preferences, properties, ui

    return (preferences, properties, capture_state, operators, ui)


def register():
    for module in _modules():
        module.register()


def unregister():
    for module in reversed(_modules()):
        module.unregister()
