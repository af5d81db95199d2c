"""Shape from Tracing add-on: a thin Blender layer over the backend process.

The bpy-free modules (``interpreter``, ``process``, ``progress``, ``ply``, ``envmap``,
``capture_file``, ``frames``, ``presets``) hold the logic and import without Blender; the
rest registers operators, panels, properties and preferences. Mitsuba is never imported:
the backend runs as ``<python> -m backend`` in its own interpreter (docs/protocol.md)."""

ROOT_PACKAGE = __package__.rpartition(".")[0] or __package__  # the extension's module name


def _modules():
    from . import operators, preferences, properties, ui

    return (preferences, properties, operators, ui)


def register():
    for module in _modules():
        module.register()


def unregister():
    for module in reversed(_modules()):
        module.unregister()
