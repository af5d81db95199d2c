"""The variant module: its report (installed versions, the libLLVM it names), the variant
event, and the commands that need no variant."""

import subprocess
import sys
from importlib import metadata

from backend import variant
from tests.helpers import REPO


def test_check_reports_the_installed_wheels_versions():
    report = variant.readiness()
    assert report["ok"], report["missing"]
    # cholespy's __version__ lags its wheel's; pymeshlab has no __version__ at all
    assert report["versions"]["cholespy"] == metadata.version("cholespy")
    assert report["versions"]["pymeshlab"] == metadata.version("pymeshlab") != "ok"
    assert report["versions"]["PIL"] == metadata.version("pillow")


def test_variant_event_names_libllvm_only_on_an_llvm_variant():
    events = []
    variant._announced = False  # the first sink in this process is the one that hears it
    name = variant.choose(announce=lambda kind, **fields: events.append((kind, fields)))
    (kind, fields), = events
    assert kind == "variant" and fields["variant"] == name
    assert ("llvm" in fields) == name.startswith("llvm")
    if name.startswith("llvm"):
        assert fields["llvm"].endswith(".so") or ".so." in fields["llvm"]
    assert variant.choose(announce=lambda kind, **fields: events.append(kind)) == name and len(events) == 1


def test_the_variant_option_is_read_from_the_command_line():
    assert variant.requested(["synth", "--out", "x", "--variant", "scalar_rgb"]) == "scalar_rgb"
    assert variant.requested(["reconstruct", "--variant=llvm_ad_rgb", "c"]) == "llvm_ad_rgb"
    assert variant.requested(["check"]) is None


def test_commands_that_do_not_render_load_no_mitsuba():
    """--help, listing the benchmarks and ``import --help`` never import Mitsuba; importing
    backend.render without a variant stops with one line naming the fix."""
    code = ("import sys\nfrom backend.cli import main\n"
            "for argv in (['--help'], ['bench'], ['import', '--help'], ['check', '--help']):\n"
            "    try:\n        main(argv)\n    except SystemExit:\n        pass\n"
            "print('LOADED' if 'mitsuba' in sys.modules or 'drjit' in sys.modules else 'FREE')\n")
    proc = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0 and proc.stdout.strip().endswith("FREE"), proc.stderr
    proc = subprocess.run([sys.executable, "-c", "import backend.render.scene"], cwd=REPO, capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode != 0 and proc.stderr.strip().splitlines()[-1].startswith(
        "RuntimeError: backend.render needs a Mitsuba variant: call backend.variant.choose()")
