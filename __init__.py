"""Shape from Tracing: the Blender extension package (the repository root).

The add-on lives in ``addon/`` (its bpy-free layer in ``addon/io/``); the ``backend/`` folder
beside it is run by a separate Python interpreter and is never imported here. ``addon`` is
imported when Blender registers the extension, so importing this package elsewhere (tests)
needs no Blender."""


def register():
    from .addon import register as _register

    _register()


def unregister():
    from .addon import unregister as _unregister

    _unregister()
