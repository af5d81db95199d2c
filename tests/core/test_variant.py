"""The variant module's report: installed versions and the libLLVM it names."""

from importlib import metadata

from backend import variant


def test_check_reports_the_installed_wheels_versions():
    report = variant.readiness()
    assert report["ok"], report["missing"]
    # cholespy's __version__ lags its wheel's; pymeshlab has no __version__ at all
    assert report["versions"]["cholespy"] == metadata.version("cholespy")
    assert report["versions"]["pymeshlab"] == metadata.version("pymeshlab") != "ok"
    assert report["versions"]["PIL"] == metadata.version("pillow")


def test_variant_event_names_libllvm_only_on_an_llvm_variant():
    events = []
    variant._chosen = None  # announce again: the first choice in this process may have been silent
    name = variant.choose(announce=lambda kind, **fields: events.append((kind, fields)))
    (kind, fields), = events
    assert kind == "variant" and fields["variant"] == name
    assert ("llvm" in fields) == name.startswith("llvm")
    if name.startswith("llvm"):
        assert fields["llvm"].endswith(".so") or ".so." in fields["llvm"]
