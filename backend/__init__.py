"""Shape from Tracing backend: capture I/O, initialisation, differentiable rendering,
optimization, metrics and reports. Free of bpy; run as ``python -m backend <command>``."""

__version__ = "0.1.0"

from .variant import configure_llvm as _configure_llvm

_configure_llvm()  # before any module imports drjit (it reads DRJIT_LIBLLVM_PATH on import)
