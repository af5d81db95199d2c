"""Backend layering, read from the source (ast): no import cycle between modules nor between
top-level packages, no command importing another command nor any other module importing a
command, commands kept thin (argparse, one library call, an exit code), ``geometry`` free of
``render`` and ``synth``, a function-level import of the project's own modules giving its
reason (never the Mitsuba variant, which the cli chooses first), and a module over 400 lines
saying why at its top."""

from __future__ import annotations

import ast
import re
from pathlib import Path

BACKEND = Path(__file__).resolve().parents[2] / "backend"
KNOWN_CYCLES: set[frozenset[str]] = set()  # none: add one here only with the reason it must stay
KNOWN_PACKAGE_CYCLES: set[frozenset[str]] = set()  # none, as above


def module_name(path: Path) -> str:
    parts = list(path.relative_to(BACKEND.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def modules() -> dict[str, Path]:
    return {module_name(p): p for p in BACKEND.rglob("*.py") if "__pycache__" not in p.parts}


def _resolve(name: str, known: dict[str, Path]) -> str | None:
    """The longest known module that ``name`` (a module or a module's attribute) lies in."""
    while name and name not in known:
        name = name.rpartition(".")[0]
    return name or None


def imports(name: str, path: Path, known: dict[str, Path]) -> set[str]:
    """Backend modules that ``name`` imports anywhere in its body (functions included)."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")
                anchor = anchor[:len(anchor) - node.level + 1]
                base = ".".join(anchor + ([base] if base else []))
            targets = [f"{base}.{a.name}" for a in node.names] + [base]
        else:
            continue
        for t in targets:
            hit = _resolve(t, known)
            # `from pkg import name` imports the package too; a submodule only when named
            if hit and hit != name and hit.startswith("backend"):
                out.add(hit)
    return out


def graph() -> dict[str, set[str]]:
    known = modules()
    return {m: imports(m, p, known) for m, p in known.items()}


def cycles(g: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in g.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(g):
        if v not in index:
            visit(v)
    return out


def _package_edge(a: str, b: str) -> bool:
    """A package's ``__init__`` re-exporting its own submodules is not a cycle of concern."""
    return b.startswith(a + ".")


def test_no_import_cycles():
    g = {m: {t for t in ts if not _package_edge(m, t)} for m, ts in graph().items()}
    found = [c for c in cycles(g) if frozenset(c) not in KNOWN_CYCLES]
    assert not found, f"import cycles: {found}"


def package(module: str) -> str:
    """The top-level backend package (or root module) ``module`` belongs to: backend.X."""
    return ".".join(module.split(".")[:2])


def package_graph(g: dict[str, set[str]]) -> dict[str, set[str]]:
    """Edges between top-level packages: backend.X -> backend.Y when a module of X imports one of Y."""
    out: dict[str, set[str]] = {}
    for m, ts in g.items():
        out.setdefault(package(m), set()).update(package(t) for t in ts if package(t) != package(m))
    return out


def test_no_cycles_between_packages():
    """The top-level packages form a DAG: no backend.X <-> backend.Y, directly or via a chain."""
    found = [c for c in cycles(package_graph(graph())) if frozenset(c) not in KNOWN_PACKAGE_CYCLES]
    assert not found, f"import cycles between packages: {found}"


def test_package_cycles_are_found():
    """The check itself: a direct and a three-package cycle are reported, a chain is not."""
    g = {"backend.a.x": {"backend.b.y"}, "backend.b.y": {"backend.c"}, "backend.c": {"backend.a"},
         "backend.a": set(), "backend.d.z": {"backend.e.w"}, "backend.e.w": {"backend.d"}, "backend.d": set(),
         "backend.f": {"backend.a.x"}}
    assert sorted(cycles(package_graph(g))) == [["backend.a", "backend.b", "backend.c"], ["backend.d", "backend.e"]]


def test_commands_do_not_import_commands():
    bad = [(m, t) for m, ts in graph().items() if m.startswith("backend.commands.")
           for t in ts if t.startswith("backend.commands.")]
    assert not bad, f"commands importing commands: {bad}"


def test_only_the_cli_reaches_commands():
    """Commands are entry points, not libraries: benches and libraries import the library a
    command calls (the cli loads commands by name, with importlib)."""
    bad = [(m, t) for m, ts in graph().items() if not m.startswith("backend.commands")
           for t in ts if t.startswith("backend.commands")]
    assert not bad, f"modules importing commands (import the library the command calls): {bad}"


RUN_LINES = 12  # run(): the library call, printing its result, the exit code
OTHER_LINES = 20  # everything else but add_arguments: small helpers for --help or for the options


def _code_lines(lines: list[str], node: ast.AST) -> int:
    """Lines of code in a def or class: no docstring, blank or comment-only lines."""
    body = node.body
    if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant) \
            and isinstance(body[0].value.value, str):
        body = body[1:]
    if not body:
        return 0
    return sum(1 for line in lines[body[0].lineno - 1:node.end_lineno]
               if line.strip() and not line.strip().startswith("#"))


def _command_sizes() -> dict[str, tuple[int | None, int]]:
    """{command: (lines of run(), lines of its other defs and classes but add_arguments)}."""
    out = {}
    for path in sorted((BACKEND / "commands").glob("*.py")):
        if path.name == "__init__.py":
            continue
        lines = path.read_text(encoding="utf-8").splitlines()
        defs = [n for n in ast.parse("\n".join(lines)).body
                if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef))]
        run = next((n for n in defs if n.name == "run"), None)
        out[path.stem] = (None if run is None else _code_lines(lines, run),
                          sum(_code_lines(lines, n) for n in defs if n.name not in ("run", "add_arguments")))
    return out


def test_commands_are_thin():
    sizes = _command_sizes()
    assert {"reconstruct", "evaluate"} <= set(sizes)
    missing = [name for name, (run, _) in sizes.items() if run is None]
    assert not missing, f"commands without run(args): {missing}"
    thick = {name: run for name, (run, _) in sizes.items() if run > RUN_LINES}
    assert not thick, (f"run() over {RUN_LINES} lines of code: {thick}; move the work into a library "
                       "module and call it once")
    helpers = {name: other for name, (_, other) in sizes.items() if other > OTHER_LINES}
    assert not helpers, (f"over {OTHER_LINES} lines of code beside add_arguments and run: {helpers}; "
                         "the logic belongs in a library module")


def test_geometry_does_not_import_render_or_synth():
    bad = [(m, t) for m, ts in graph().items() if m.startswith("backend.geometry")
           for t in ts if t.startswith(("backend.render", "backend.synth"))]
    assert not bad, f"geometry importing render/synth: {bad}"


def _reason(line: str) -> str:
    """The words of the comment on ``line`` with any ``noqa: CODES`` marker left out."""
    comment = line.partition("#")[2] if "#" in line else ""
    return re.sub(r"noqa(:\s*[A-Z]+[0-9]+(,\s*[A-Z]+[0-9]+)*)?", "", comment).strip(" ()")


def local_imports() -> dict[str, list[tuple[int, str]]]:
    """{module path: [(line, reason)]} for each import of a backend module inside a def, with
    the reason its comment gives on that line or the comment line above ('' when none); an
    import right below another shares its reason (a group under one comment)."""
    out = {}
    for name, path in modules().items():
        lines = path.read_text(encoding="utf-8").splitlines()
        tree = ast.parse("\n".join(lines))
        sites = {}
        for fn in ast.walk(tree):
            if not isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            for node in ast.walk(fn):
                own = (isinstance(node, ast.ImportFrom) and (node.level or (node.module or "").startswith("backend"))) \
                    or (isinstance(node, ast.Import) and any(a.name.startswith("backend") for a in node.names))
                if own:
                    above = lines[node.lineno - 2].strip() if node.lineno > 1 else ""
                    reason = _reason(lines[node.lineno - 1]) or (_reason(above) if above.startswith("#") else "")
                    sites[node.lineno] = (node.end_lineno, reason)
        ends = {end: reason for end, reason in sites.values()}
        for n in sorted(sites):  # in line order, so a group's reason flows down it
            end, reason = sites[n]
            if not reason and ends.get(n - 1):
                sites[n] = (end, ends[n - 1])
                ends[end] = ends[n - 1]
        if sites:
            out[str(path.relative_to(BACKEND.parent))] = [(n, r) for n, (_, r) in sorted(sites.items())]
    return out


VARIANT_REASON = re.compile(r"variant", re.IGNORECASE)
LOCAL_IMPORTS_ELSEWHERE: tuple[str, ...] = ()  # none: every package keeps to the rule


def unexplained_local_imports(skip: tuple[str, ...] = ()) -> list[str]:
    """``path:line`` of function-level imports of backend modules with no reason, or with the
    variant as their reason (modules import at their tops once the cli has chosen it)."""
    return [f"{p}:{n}" + (f" ({r})" if r else " (no reason)") for p, sites in sorted(local_imports().items())
            if not p.startswith(skip) for n, r in sites if not r or VARIANT_REASON.search(r)]


def test_function_level_imports_give_a_reason():
    """A project import inside a def says why on its line or the comment line above: an
    optional part absent from the extension, a heavy import kept off a fast path (--help,
    check), a module that imports this one. "The Mitsuba variant" is no reason: the cli (and
    tests/conftest.py) choose it before anything renders, so such imports belong at the top."""
    bad = unexplained_local_imports(skip=LOCAL_IMPORTS_ELSEWHERE)
    assert not bad, f"function-level imports without a reason, or with the variant as it: {bad}"


MODULE_LINES = 400  # the size a module is read at in one sitting; a longer one says why at its top


def test_long_modules_state_why():
    """Outside ``bench``, a module over ``MODULE_LINES`` states the reason in its docstring
    ("Longer than 400 lines: ...")."""
    long = {}
    for name, path in modules().items():
        if name.startswith("backend.bench"):
            continue
        text = path.read_text(encoding="utf-8")
        n = text.count("\n")
        if n > MODULE_LINES and "Longer than 400 lines" not in (ast.get_docstring(ast.parse(text)) or ""):
            long[name] = n
    assert not long, f"modules over {MODULE_LINES} lines without the reason in their docstring: {long}"
