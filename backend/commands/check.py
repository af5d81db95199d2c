"""Report, as one JSON object on stdout, whether this interpreter can run the backend."""

from __future__ import annotations

import importlib
import json
import sys

MODULES = ["numpy", "mitsuba", "drjit", "pymeshlab", "pycolmap", "OpenEXR", "cholespy", "PIL", "scipy", "av"]


def add_arguments(parser):
    parser.add_argument("--variant", help="Mitsuba variant to try (default: automatic)")


def run(args) -> int:
    report = {"python": sys.version.split()[0], "executable": sys.executable, "missing": [], "versions": {}}
    for name in MODULES:
        try:
            mod = importlib.import_module(name)
            report["versions"][name] = getattr(mod, "__version__", "ok")
        except Exception as err:  # any import failure means the module is unusable
            report["missing"].append(f"{name} ({err.__class__.__name__}: {err})")
    if "mitsuba" in report["versions"]:
        from .. import variant

        try:
            report["variant"] = variant.choose(args.variant)
            import drjit as dr

            report["cuda"] = bool(dr.has_backend(dr.JitBackend.CUDA))
            if report["variant"].startswith("llvm"):
                report["llvm_version"] = ".".join(map(str, dr.detail.llvm_version()))
        except Exception as err:
            report["missing"].append(f"mitsuba variant ({err})")
    report["ok"] = not report["missing"]
    print(json.dumps(report))
    return 0 if report["ok"] else 1
