"""The layering of docs/architecture.md, enforced: one direction of imports, no cycles between
packages, nothing of trustnav changing global state when it is imported.

Every module under src/trustnav is parsed with ``ast``; every import counts, at module level or
inside a function (a lazy import is still a dependency), ``import trustnav.x`` and
``from trustnav.x import y`` alike, and relative imports resolved.
"""

from __future__ import annotations

import ast
import json
import os
import re
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src" / "trustnav"

#: package -> the trustnav packages it may import (besides itself). ``geometry`` is the optional
#: package "below both" perception and sim (camera geometry), importing nothing of ours;
#: ``schema`` (the one validation mechanism of what users type) likewise imports nothing of ours.
ALLOWED: dict[str, set[str]] = {
    # the thin entry points may reach any layer below them (downward only; `estimate` wires
    # perception and trust directly)
    "cli": {"sim", "campaigns", "carla_bridge", "viz", "perception", "control", "trust"},
    "campaigns": {"sim", "control", "perception", "trust", "viz"},  # viz: the campaign figures' style
    "carla_bridge": {"sim", "perception", "control", "trust"},
    "sim": {"perception", "control", "trust"},
    "perception": {"trust"},
    "control": {"trust"},
    "trust": set(),
    "viz": set(),
    "geometry": set(),
    "schema": set(),
    "progress": set(),  # the one progress report (trustnav/progress.py): bars and log lines
    "outputs": set(),  # output folders written whole or not at all (trustnav/outputs.py)
}
#: lower packages that every layer may use (the geometry package below perception and sim; the
#: validation rules of trustnav.schema)
BELOW_ALL = {"geometry", "schema", "progress", "outputs"}
ROOT_MODULE = "__init__"  # trustnav/__init__.py: imports nothing of ours (checked below)


def _package(module: str) -> str:
    """'trustnav.sim.driving.world' -> 'sim'; 'trustnav.cli' -> 'cli'; 'trustnav' -> '__init__'."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else ROOT_MODULE


def _module_name(path: Path) -> str:
    rel = path.relative_to(SRC.parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _imports(path: Path) -> list[tuple[str, int]]:
    """(imported trustnav module, line) for every import in the file, relative ones resolved."""
    out = []
    for node, target in _import_nodes(path):
        if isinstance(node, ast.Import):
            out += [(a.name, node.lineno) for a in node.names if a.name.split(".")[0] == "trustnav"]
        elif target == "trustnav":  # from trustnav import sim
            out += [(f"trustnav.{a.name}", node.lineno) for a in node.names]
        else:
            out.append((target, node.lineno))
    return out


def _import_nodes(path: Path) -> Iterator[tuple[ast.Import | ast.ImportFrom, str]]:
    """Every import statement of the file with the trustnav module a ``from`` import names (relative
    ones resolved; ``""`` for a plain ``import``); ``from`` imports of other packages left out."""
    module = _module_name(path)
    is_pkg = path.name == "__init__.py"
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            yield node, ""
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = module.split(".")
                base = base if is_pkg else base[:-1]
                base = base[: len(base) - (node.level - 1)]
                target = ".".join([*base, node.module] if node.module else base)
            else:
                target = node.module or ""
            if target.split(".")[0] == "trustnav":
                yield node, target


def _edges() -> list[tuple[str, str, str, int]]:
    """(from package, to package, file, line) for every import between two different packages."""
    edges = []
    for path in sorted(SRC.rglob("*.py")):
        src_pkg = _package(_module_name(path))
        for target, line in _imports(path):
            dst_pkg = _package(target)
            if dst_pkg != src_pkg:
                edges.append((src_pkg, dst_pkg, str(path.relative_to(SRC.parent.parent)), line))
    return edges


def test_the_parser_sees_lazy_relative_and_plain_imports(tmp_path, monkeypatch):
    pkg = tmp_path / "trustnav" / "viz"
    pkg.mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    f = pkg / "plots.py"
    f.write_text(
        "import trustnav.sim.paper\n"
        "from trustnav import perception\n"
        "from ..control import mpc\n"
        "from . import style\n"
        "def draw():\n"
        "    from trustnav.trust.estimator import TrustEstimator\n"
    )
    monkeypatch.setattr(sys.modules[__name__], "SRC", tmp_path / "trustnav")
    got = [t for t, _ in _imports(f)]
    assert got == [
        "trustnav.sim.paper",
        "trustnav.perception",
        "trustnav.control",
        "trustnav.viz",
        "trustnav.trust.estimator",
    ]


def test_every_package_has_a_rule():
    packages = {p.name for p in SRC.iterdir() if p.is_dir() and (p / "__init__.py").exists()}
    packages |= {p.stem for p in SRC.glob("*.py") if p.stem != "__init__"}
    assert packages <= set(ALLOWED), f"packages without a layering rule: {sorted(packages - set(ALLOWED))}"


def test_imports_follow_the_one_direction():
    """cli -> sim / campaigns / carla_bridge -> perception + control -> trust (downward only);
    viz reads results only (imported by cli alone); perception and control never import each other."""
    bad = [
        f"{file}:{line}: {a} imports {b}"
        for a, b, file, line in _edges()
        if b not in ALLOWED.get(a, set()) | BELOW_ALL or (b in BELOW_ALL and a == b)
    ]
    assert not bad, "imports against the layering of docs/architecture.md:\n" + "\n".join(bad)


def test_viz_is_imported_by_nothing_but_the_cli_and_the_campaign_figures():
    users = sorted({f"{file}:{line} ({a})" for a, b, file, line in _edges()
                    if b == "viz" and a != "cli" and not file.endswith("campaigns/plots.py")})  # fmt: skip
    assert not users, "viz imported outside the cli and the campaign figures:\n" + "\n".join(users)


def test_perception_and_control_never_import_each_other():
    cross = [f"{file}:{line}" for a, b, file, line in _edges() if {a, b} == {"perception", "control"}]
    assert not cross, cross


def test_the_package_root_imports_nothing_of_ours():
    assert not _imports(SRC / "__init__.py")


def test_no_import_cycle_between_packages():
    graph: dict[str, set[str]] = {}
    for a, b, _, _ in _edges():
        graph.setdefault(a, set()).add(b)
    cycles = []

    def visit(node: str, path: list[str]) -> None:
        for nxt in sorted(graph.get(node, ())):
            if nxt in path:
                cycles.append(" -> ".join([*path[path.index(nxt) :], nxt]))
            elif len(path) < len(graph) + 1:
                visit(nxt, [*path, nxt])

    for start in sorted(graph):
        visit(start, [start])
    assert not cycles, "import cycles between packages:\n" + "\n".join(sorted(set(cycles)))


_PROBE = r"""
import importlib, json, os, pkgutil, sys, sysconfig, warnings
import matplotlib
import matplotlib.pyplot  # noqa: F401
matplotlib.use("svg")  # a backend of the user's choice, set before trustnav is imported
import trustnav

SRC = os.path.dirname(trustnav.__file__)
SKIP = (sysconfig.get_paths()["stdlib"], os.path.dirname(matplotlib.__file__), "<frozen")
calls = []  # (what, file:line of the first caller outside the stdlib and matplotlib)


def actor():
    f = sys._getframe(2)
    while f is not None and f.f_code.co_filename.startswith(SKIP):
        f = f.f_back
    return "?" if f is None else f"{f.f_code.co_filename}:{f.f_lineno}"


def hook(owner, name, what):
    real = getattr(owner, name)

    def wrapper(*args, **kwargs):
        calls.append((what(*args), actor()))
        return real(*args, **kwargs)

    setattr(owner, name, wrapper)


hook(os._Environ, "__setitem__", lambda self, k, v: f"os.environ[{k!r}] = {v!r}")
hook(os._Environ, "__delitem__", lambda self, k: f"del os.environ[{k!r}]")
hook(warnings, "filterwarnings", lambda *a, **k: f"warnings.filterwarnings{a}")
hook(warnings, "simplefilter", lambda *a, **k: f"warnings.simplefilter{a}")
hook(warnings, "resetwarnings", lambda *a, **k: "warnings.resetwarnings()")
hook(matplotlib, "use", lambda *a, **k: f"matplotlib.use{a}")


def state():
    return dict(os.environ), list(map(repr, warnings.filters)), matplotlib.rcParams["backend"]


failed, changed, third_party = {}, [], []
for info in pkgutil.walk_packages(trustnav.__path__, "trustnav."):
    before, n = state(), len(calls)
    try:
        importlib.import_module(info.name)
    except ImportError as exc:  # an optional dependency (carla, ...) that is not installed
        failed[info.name] = repr(exc)
        continue
    ours = [f"{what} at {where}" for what, where in calls[n:] if where.startswith(SRC)]
    others = [f"{what} at {where}" for what, where in calls[n:] if not where.startswith(SRC)]
    after = state()
    if after != before and not calls[n:]:  # changed without any call we watch: direct edits
        ours.append("os.environ / warnings.filters / backend edited directly")
    if after[2] != before[2] and not any("matplotlib" in w for w in others):
        ours.append(f"matplotlib backend {before[2]} -> {after[2]}")
    changed += [f"{info.name}: {c}" for c in ours]
    third_party += [f"{info.name}: {c}" for c in others]
print(json.dumps({"changed": changed, "third_party": third_party, "failed": failed}))
"""


@pytest.mark.skipif(os.environ.get("CI_NO_SUBPROCESS") == "1", reason="no subprocesses")
def test_importing_any_module_changes_no_global_state():
    """A fresh interpreter imports every trustnav module, one by one: no code of trustnav edits
    os.environ, the warnings filters or the matplotlib backend chosen by the user while it is
    imported. Edits made by third-party libraries when trustnav imports them (numpy's and scipy's
    warning filters, gymnasium's PYGAME_HIDE_SUPPORT_PROMPT) are theirs, not ours, and allowed."""
    proc = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    report = json.loads(proc.stdout.strip().splitlines()[-1])
    assert not report["changed"], "global state changed at import:\n" + "\n".join(report["changed"])
    # only optional extras may be missing, never a module of ours
    assert all("No module named 'trustnav" not in why for why in report["failed"].values()), report["failed"]


def _module_imports(path: Path) -> set[str]:
    """The trustnav modules a file imports, ``from package import module`` resolved to the module
    (a name that is no module of the package counts as the package's ``__init__``)."""
    out = set()
    for node, target in _import_nodes(path):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names if a.name.split(".")[0] == "trustnav"}
        else:
            folder = SRC.parent.joinpath(*target.split("."))
            for a in node.names:
                sub = folder / a.name
                out.add(f"{target}.{a.name}" if sub.with_suffix(".py").exists() or sub.is_dir() else target)
    return out


#: packages whose modules may still import each other in a circle: none (perception's frames <-> live
#: was the last; ``is_live_source`` now lives beside ``plan_sequences`` in frames).
MODULE_CYCLES_LEFT: set[str] = set()


def test_no_import_cycle_between_modules_of_a_package():
    """Inside a package too (control/ above all: costs -> models -> problem -> costs was one), no
    module reaches itself through the imports of its package's modules."""
    graph: dict[str, set[str]] = {}
    for path in sorted(SRC.rglob("*.py")):
        name = _module_name(path)
        if _package(name) in MODULE_CYCLES_LEFT:
            continue
        graph[name] = {t for t in _module_imports(path) if t != name and t.rsplit(".", 1)[0] == name.rsplit(".", 1)[0]}
    cycles = set()
    for start in sorted(graph):
        stack, seen = [(start, [start])], set()
        while stack:
            node, path = stack.pop()
            for nxt in sorted(graph.get(node, ())):
                if nxt == start:
                    cycles.add(" -> ".join([*path, nxt]))
                elif nxt not in seen:
                    seen.add(nxt)
                    stack.append((nxt, [*path, nxt]))
    assert not cycles, "import cycles inside a package:\n" + "\n".join(sorted(cycles))


def test_the_module_cycle_check_sees_a_circle(tmp_path, monkeypatch):
    pkg = tmp_path / "trustnav" / "control"
    pkg.mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("from trustnav.control import b\n")
    (pkg / "b.py").write_text("def f():\n    from . import a\n")
    monkeypatch.setattr(sys.modules[__name__], "SRC", tmp_path / "trustnav")
    assert _module_imports(pkg / "a.py") == {"trustnav.control.b"}
    assert _module_imports(pkg / "b.py") == {"trustnav.control.a"}
    with pytest.raises(AssertionError, match=re.escape("a -> trustnav.control.b -> trustnav.control.a")):
        test_no_import_cycle_between_modules_of_a_package()


#: the cli package's own modules, top to bottom: each may import only those below it (the package
#: root registers the commands; compare and demo reuse drive's options and summary; common is the floor)
CLI_BELOW: dict[str, set[str]] = {
    "trustnav.cli": {"compare", "demo", "drive", "estimate", "scenario", "sweep", "common"},
    "trustnav.cli.__main__": {"trustnav.cli"},
    "trustnav.cli.compare": {"drive", "common"},
    "trustnav.cli.demo": {"drive", "common"},
    "trustnav.cli.drive": {"common"},
    "trustnav.cli.estimate": {"common"},
    "trustnav.cli.scenario": {"common"},
    "trustnav.cli.sweep": {"common"},
    "trustnav.cli.common": set(),
}


def test_the_cli_package_imports_only_downward():
    """One module per command, each importing only the shared module below it (and drive's options),
    never the package root or a sibling command: no circle inside the CLI."""
    files = sorted((SRC / "cli").glob("*.py"))
    assert {_module_name(f) if f.stem != "__main__" else "trustnav.cli.__main__" for f in files} == set(CLI_BELOW)
    bad = []
    for f in files:
        name = "trustnav.cli.__main__" if f.stem == "__main__" else _module_name(f)
        allowed = {m if m.startswith("trustnav") else f"trustnav.cli.{m}" for m in CLI_BELOW[name]}
        ours = {m for m in _module_imports(f) if m == "trustnav.cli" or m.startswith("trustnav.cli.")}
        bad += [f"{name} imports {m}" for m in sorted(ours - allowed)]
    assert not bad, "imports against the cli package's order:\n" + "\n".join(bad)
