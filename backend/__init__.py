"""Shape from Tracing backend: capture I/O, initialisation, differentiable rendering,
optimization, metrics and reports. Free of bpy; run as ``python -m backend <command>``."""

__version__ = "0.1.0"
