"""Choose and load the Mitsuba variant.

``cuda_ad_rgb`` when a CUDA device works, else ``llvm_ad_rgb``. Override with the
``--variant`` option or the ``SFT_VARIANT`` environment variable. Dr.Jit's LLVM backend
needs libLLVM >= 17; the one shipped in the virtual environment is used when present.
Dr.Jit reads ``DRJIT_LIBLLVM_PATH`` when it is first imported, so ``backend/__init__``
configures it before anything imports drjit. :func:`readiness` is the ``check`` command's
report: whether this interpreter can run the backend at all."""

from __future__ import annotations

import functools
import glob
import importlib
import os
import sys
from importlib import metadata
from pathlib import Path

from .errors import InputError

_chosen: str | None = None
MODULES = ["numpy", "mitsuba", "drjit", "pymeshlab", "pycolmap", "OpenEXR", "cholespy", "PIL", "scipy", "av"]


def _find_libllvm() -> str | None:
    candidates = [Path(sys.prefix) / "lib" / "libLLVM.so"]
    candidates += sorted(Path(p) for p in glob.glob(str(Path(sys.prefix) / "lib" / "libLLVM*.so*")))
    for version in (23, 22, 21, 20, 19, 18, 17):
        candidates += [Path(f"/usr/lib/llvm-{version}/lib/libLLVM.so"),
                       Path(f"/usr/lib/x86_64-linux-gnu/libLLVM-{version}.so")]
    for path in candidates:
        if path.exists():
            return str(path)
    return None


def configure_llvm() -> None:
    """Point Dr.Jit at a libLLVM >= 17 unless the user already chose one."""
    if not os.environ.get("DRJIT_LIBLLVM_PATH"):
        lib = _find_libllvm()
        if lib:
            os.environ["DRJIT_LIBLLVM_PATH"] = lib


def _cuda_works() -> bool:
    import drjit as dr
    try:
        return bool(dr.has_backend(dr.JitBackend.CUDA))
    except Exception:
        return False


def choose(requested: str | None = None, announce=None) -> str:
    """Set the Mitsuba variant once per process and return its name."""
    global _chosen
    configure_llvm()
    import mitsuba as mi

    requested = requested or os.environ.get("SFT_VARIANT") or None
    if _chosen and (requested in (None, _chosen)):
        return _chosen
    if requested:
        if requested not in mi.variants():
            raise InputError(None, f"unknown Mitsuba variant '{requested}'",
                             f"use one of {', '.join(mi.variants())}")
        variant = requested
    else:
        variant = "cuda_ad_rgb" if _cuda_works() else "llvm_ad_rgb"
    try:
        mi.set_variant(variant)
    except Exception as err:  # Dr.Jit reports a missing backend as ImportError/RuntimeError
        raise InputError(None, f"Mitsuba variant '{variant}' cannot start ({err})",
                         "run ./dev.sh setup, or set SFT_VARIANT to another variant") from err
    if variant.startswith("llvm"):
        import drjit as dr

        major = dr.detail.llvm_version()[0]
        if major < 17:  # LLVM <= 16 aborts the process on some kernels ("Cannot select fminimum")
            raise InputError(None, f"Dr.Jit loaded libLLVM {major}, but it needs libLLVM >= 17",
                             "import backend before drjit/mitsuba, or set DRJIT_LIBLLVM_PATH "
                             "to the libLLVM.so in .venv/lib")
    _chosen = variant
    if announce:  # the libLLVM path only where the LLVM backend runs: on CUDA it names nothing in use
        llvm = {"llvm": os.environ.get("DRJIT_LIBLLVM_PATH")} if variant.startswith("llvm") else {}
        announce("variant", variant=variant, **llvm)
    return variant


@functools.lru_cache(maxsize=1)
def _distributions() -> dict:
    return metadata.packages_distributions()


def _version(name: str, module) -> str:
    """The installed distribution's version: some modules' ``__version__`` lags their wheel's
    (cholespy 2.2.0 says 1.0.0), and pymeshlab has none."""
    for dist in _distributions().get(name, [name]):
        try:
            return metadata.version(dist)
        except metadata.PackageNotFoundError:
            continue
    return str(getattr(module, "__version__", "ok"))


def readiness(requested: str | None = None) -> dict:
    """Whether this interpreter can run the backend: its Python, each needed module's version
    (or why it cannot load), the variant :func:`choose` picks and whether CUDA works; ``ok``
    when nothing is missing."""
    report = {"python": sys.version.split()[0], "executable": sys.executable, "missing": [], "versions": {}}
    for name in MODULES:
        try:
            mod = importlib.import_module(name)
            report["versions"][name] = _version(name, mod)
        except Exception as err:  # any import failure means the module is unusable
            report["missing"].append(f"{name} ({err.__class__.__name__}: {err})")
    if "mitsuba" in report["versions"]:
        try:
            report["variant"] = choose(requested)
            import drjit as dr  # only here: Dr.Jit reads DRJIT_LIBLLVM_PATH when first imported

            report["cuda"] = bool(dr.has_backend(dr.JitBackend.CUDA))
            if report["variant"].startswith("llvm"):
                report["llvm_version"] = ".".join(map(str, dr.detail.llvm_version()))
        except Exception as err:
            report["missing"].append(f"mitsuba variant ({err})")
    report["ok"] = not report["missing"]
    return report
