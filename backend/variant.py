"""Choose and load the Mitsuba variant, once per process, at its entry point.

``cuda_ad_rgb`` when a CUDA device works, else ``llvm_ad_rgb``. Override with the
``--variant`` option or the ``SFT_VARIANT`` environment variable. The cli calls
:func:`choose` before it imports a command that renders (as Mitsuba imports its integrators
once a variant is set), ``tests/conftest.py`` for the tests, a benchmark's Ray worker on
start; :func:`require` is the check ``backend.render`` makes when imported. Dr.Jit's LLVM
backend needs libLLVM >= 17; the one shipped in the virtual environment is used when present.
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
_announced = False  # whether a caller's event sink has reported the variant
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
    import drjit as dr  # here: only when a variant is being chosen (check and --help load no Dr.Jit)
    try:
        return bool(dr.has_backend(dr.JitBackend.CUDA))
    except Exception:
        return False


def choose(requested: str | None = None, announce=None) -> str:
    """Set the Mitsuba variant once per process and return its name.

    Parameters:
        requested: a variant name; None reads ``SFT_VARIANT``, else picks automatically.
        announce: an event sink, ``announce("variant", variant=..., llvm=...)``. The first call
            in the process that gives one announces the variant; the cli chooses it silently
            before the command runs, so the command's own call reports it as part of its events.

    Raises InputError for an unknown variant, one that cannot start, or a libLLVM < 17."""
    global _chosen, _announced
    requested = requested or os.environ.get("SFT_VARIANT") or None
    if not (_chosen and requested in (None, _chosen)):
        _chosen = _set_variant(requested)
    if announce and not _announced:
        _announced = True  # the libLLVM path only where the LLVM backend runs: on CUDA it names nothing in use
        llvm = {"llvm": os.environ.get("DRJIT_LIBLLVM_PATH")} if _chosen.startswith("llvm") else {}
        announce("variant", variant=_chosen, **llvm)
    return _chosen


def _set_variant(requested: str | None) -> str:
    configure_llvm()
    import mitsuba as mi  # here: importing Mitsuba takes a second, which check, import and --help skip

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
    return variant


def requested(argv: list[str]) -> str | None:
    """The value of the last ``--variant NAME`` (or ``--variant=NAME``) in ``argv``, else None:
    the cli reads it before it imports the command that defines the option."""
    found = None
    for i, arg in enumerate(argv):
        if arg == "--variant" and i + 1 < len(argv):
            found = argv[i + 1]
        elif arg.startswith("--variant="):
            found = arg.partition("=")[2]
    return found


def require(package: str) -> None:
    """Raise a one-line RuntimeError unless a Mitsuba variant is set: ``package`` (its modules
    define Mitsuba plugins and read variant types when imported) cannot load without one."""
    import mitsuba as mi  # here: only the rendering packages call this, and they load Mitsuba anyway

    if mi.variant() is None:
        raise RuntimeError(f"{package} needs a Mitsuba variant: call backend.variant.choose() before "
                           "importing it (python -m backend does so for the commands that render)")


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
