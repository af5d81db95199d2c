"""The add-on's bpy-free layer: everything that needs neither ``bpy`` nor ``mathutils``.

Modules here import only the standard library, numpy and each other, so they run in tests
and scripts without Blender; ``install_backend.py`` also runs as a script under Blender's
Python. The Blender layer (``addon/`` around it) imports from here, never the reverse."""
