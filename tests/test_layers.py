"""Imports go one way, down DESIGN.md's list of layers:

    errors, backend, timing, registry, color -> metrics, sampling -> scene -> lights, directions -> transport
    -> probes, vpl -> techniques -> experiments -> viewer -> cli

Read statically from the source (every ``import`` and ``from ... import``, also inside functions,
relative ones resolved), so a hidden import inside a function counts as much as one at the top.
A module may import its own layer's package and any layer below it; an import of a higher layer
is an *upward* import. Among the layer packages the import graph must have no cycle. A technique
module never imports another technique (DESIGN: techniques compose the layers below).

``KNOWN`` lists the violations that exist today, each with the issue that removes it: the test
fails on any violation not in it (a new upward import), and on an entry that no longer occurs (so
the list only shrinks)."""
from __future__ import annotations

import ast
import os

import pytest

SRC = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "src", "dyngi")

# layer of each top-level module/package of dyngi, lowest first (DESIGN.md, "Layout by concept")
LAYERS = {
    "errors": 0, "backend": 0, "timing": 0, "registry": 0, "color": 0, "rays": 0, "__init__": 0,
    "metrics": 1, "sampling": 1,
    "scene": 2,
    "lights": 3, "directions": 3,
    "transport": 4,
    "probes": 5, "vpl": 5,
    "techniques": 6,
    "experiments": 7,
    "viewer": 8,
    "cli": 9, "__main__": 9,
}

# (importer module, imported module) pairs that break the rule today, with the issue that removes them
KNOWN: dict[tuple[str, str], str] = {}


def _modules():
    for root, _, files in os.walk(SRC):
        for f in files:
            if f.endswith(".py"):
                path = os.path.join(root, f)
                rel = os.path.relpath(path, os.path.dirname(SRC))[:-3].replace(os.sep, ".")
                if rel.endswith(".__init__"):
                    rel = rel[: -len(".__init__")]
                yield rel, path


def _is_module(name: str) -> bool:
    rel = os.path.join(os.path.dirname(SRC), *name.split("."))
    return os.path.exists(rel + ".py") or os.path.exists(os.path.join(rel, "__init__.py"))


def _from_target(node: ast.ImportFrom, pkg: str) -> str:
    """The absolute module a ``from ... import`` names (relative levels resolved against ``pkg``)."""
    if not node.level:
        return node.module or ""
    base = pkg.split(".")
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def _imports(mod: str, path: str):
    """Every dyngi module that ``mod`` imports (absolute names)."""
    tree = ast.parse(open(path, encoding="utf-8").read(), path)
    is_pkg = path.endswith("__init__.py")
    pkg = mod if is_pkg else mod.rsplit(".", 1)[0]
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names if a.name.split(".")[0] == "dyngi")
        elif isinstance(node, ast.ImportFrom):
            target = _from_target(node, pkg)
            if target.split(".")[0] != "dyngi":
                continue
            # ``from pkg import a``: ``a`` is a submodule when one of that name exists, else a name of pkg
            for a in node.names:
                sub = f"{target}.{a.name}"
                out.add(sub if _is_module(sub) else target)
    return out


def _top(mod: str) -> str:
    parts = mod.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def _technique_unit(mod: str) -> str | None:
    """The technique a module belongs to (``techniques.ddgi``, ``techniques.adgi``), None for the
    shared ``techniques`` modules (``base``, ``vpl_base``: the VPL techniques' common base, the package)."""
    parts = mod.split(".")
    if len(parts) < 3 or parts[1] != "techniques" or parts[2] in ("base", "vpl_base", "probe_base", "__init__"):
        return None
    return parts[2]


def violations():
    found: dict[tuple[str, str], str] = {}
    graph: dict[str, set[str]] = {}
    for mod, path in _modules():
        a = _top(mod)
        for imp in _imports(mod, path):
            b = _top(imp)
            if a not in LAYERS or b not in LAYERS:
                found[(mod, imp)] = f"layer not declared in DESIGN.md: {a if a not in LAYERS else b}"
                continue
            if a != b:
                graph.setdefault(a, set()).add(b)
            if LAYERS[b] > LAYERS[a]:
                found[(mod, imp)] = f"upward import: {a} (layer {LAYERS[a]}) imports {b} (layer {LAYERS[b]})"
            ta, tb = _technique_unit(mod), _technique_unit(imp)
            if ta and tb and ta != tb:
                found[(mod, imp)] = f"technique imports technique: {ta} -> {tb}"
    return found, graph


def _cycles(graph):
    """Package-level cycles (each as a sorted tuple of its members), by Tarjan's SCC."""
    index, low, stack, on, out = {}, {}, [], set(), []
    counter = [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
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
                out.append(tuple(sorted(comp)))

    for v in list(graph):
        if v not in index:
            visit(v)
    return out


# -- module cycles and imports inside functions -------------------------------------------------------

# module-level import cycles that are plug-in discovery (a package's __init__ imports its plug-ins, each
# plug-in registers itself with the package's base): allowed, named
ALLOWED_MODULE_CYCLES = {
    ("dyngi.lights", "dyngi.lights.base"): "lights/__init__ discovers the light samplers, which register in base",
    ("dyngi.directions", "dyngi.directions.base"): "directions/__init__ discovers the direction samplers",
}

# imports of dyngi modules inside functions, per module: the count may only fall (a new one fails; a
# module whose count fell must lower its entry). Permanent reasons (optional dependencies, plug-in
# discovery, the cluster worker's environment set before Dr.Jit loads) are in FUNCTION_IMPORTS_WHY.
FUNCTION_IMPORTS: dict[str, int] = {   # one module a line
    "dyngi.color": 1,
    "dyngi.directions.base": 1,
    "dyngi.directions.walk": 1,
    "dyngi.experiments.cluster": 6,
    "dyngi.experiments.reproduce": 1,
    "dyngi.lights.base": 1,
}
FUNCTION_IMPORTS_WHY: dict[str, str] = {
    "dyngi.color": "optional dependency: Mitsuba only for a Dr.Jit argument, so NumPy-only users (metrics) stay "
                   "free of the renderer",
    "dyngi.directions.base": "plug-in discovery: names() imports the package, which imports every direction sampler",
    "dyngi.directions.walk": "optional module: dyngi.directions.cdq imported only for kind='cdq' (a clear error where "
                             "it cannot be imported), so that the techniques that use the walk load without it "
                             "(tests/techniques/test_neept.py)",
    "dyngi.experiments.cluster": "worker set-up: a Ray worker loads this module and sets the driver's environment and "
                                 "variant before Dr.Jit loads, so no module that loads Dr.Jit is imported at its top",
    "dyngi.experiments.reproduce": "plug-in discovery: the reproductions register themselves with this module",
    "dyngi.lights.base": "plug-in discovery: the registry imports the package, which imports every light sampler",
}


def _function_imports(mod: str, path: str) -> list[str]:
    """The dyngi modules ``mod`` imports inside a function body (one entry per import statement)."""
    tree = ast.parse(open(path, encoding="utf-8").read(), path)
    is_pkg = path.endswith("__init__.py")
    pkg = mod if is_pkg else mod.rsplit(".", 1)[0]
    out = []
    for fn in ast.walk(tree):
        if not isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
            continue
        for node in ast.walk(fn):
            if isinstance(node, ast.Import):
                out += [a.name for a in node.names if a.name.split(".")[0] == "dyngi"]
            elif isinstance(node, ast.ImportFrom):
                target = _from_target(node, pkg)
                if target.split(".")[0] == "dyngi":
                    out.append(target)
    return out


def function_import_counts() -> dict[str, int]:
    """``{module: imports of dyngi modules inside its functions}`` (modules with none left out; an import
    inside a nested function counts once per enclosing function)."""
    out = {}
    for mod, path in _modules():
        n = len(_function_imports(mod, path))
        if n:
            out[mod] = n
    return out


def module_cycles() -> list[tuple]:
    """Import cycles among dyngi modules (every import, in functions too), less the allowed ones."""
    graph = {}
    for mod, path in _modules():
        graph[mod] = {i for i in _imports(mod, path) if i != mod}
    return [c for c in _cycles(graph) if c not in ALLOWED_MODULE_CYCLES]


def test_no_module_cycle():
    """No circle of modules closed by an import inside a function (or at the top): a module's dependencies
    are what its top says. Plug-in discovery cycles are allowed and named."""
    cycles = module_cycles()
    assert not cycles, "module import cycles: " + "; ".join(" <-> ".join(c) for c in cycles)


def test_imports_at_the_top():
    """Imports of dyngi modules stand at the top of a module, except the counted ones in FUNCTION_IMPORTS
    (a list that only shrinks) and the permanent ones it explains (FUNCTION_IMPORTS_WHY)."""
    got = function_import_counts()
    grown = {m: (n, FUNCTION_IMPORTS.get(m, 0)) for m, n in got.items() if n > FUNCTION_IMPORTS.get(m, 0)}
    assert not grown, "imports inside functions (move them to the top): " + ", ".join(
        f"{m} {n} (allowed {a})" for m, (n, a) in sorted(grown.items()))
    shrunk = {m: (got.get(m, 0), a) for m, a in FUNCTION_IMPORTS.items() if got.get(m, 0) < a}
    assert not shrunk, "fewer imports inside functions than FUNCTION_IMPORTS allows, lower the entries: " + \
        ", ".join(f"{m} {n} (allowed {a})" for m, (n, a) in sorted(shrunk.items()))
    assert set(FUNCTION_IMPORTS_WHY) <= set(FUNCTION_IMPORTS)


def test_parser_sees_relative_and_function_level_imports(tmp_path):
    """The checker itself can fail: a module with an upward import hidden in a function is caught."""
    f = tmp_path / "x.py"
    f.write_text("def f():\n    from ..techniques import ddgi\n    from dyngi.experiments import compare\n")
    got = _imports("dyngi.sampling.x", str(f))
    assert got == {"dyngi.techniques.ddgi", "dyngi.experiments.compare"}


def test_no_new_upward_import():
    found, _ = violations()
    new = {k: v for k, v in found.items() if k not in KNOWN}
    assert not new, "imports against DESIGN.md's layer order:\n" + "\n".join(
        f"  {a} -> {b}: {why}" for (a, b), why in sorted(new.items()))


def test_known_violations_are_still_real():
    """An entry of KNOWN that no longer occurs must be removed (the list only shrinks)."""
    found, _ = violations()
    stale = sorted(k for k in KNOWN if k not in found)
    assert not stale, "fixed, remove from KNOWN: " + ", ".join(f"{a} -> {b}" for a, b in stale)


def test_no_package_cycle():
    found, graph = violations()
    known_edges = {(_top(a), _top(b)) for a, b in KNOWN}
    pruned = {a: {b for b in bs if (a, b) not in known_edges} for a, bs in graph.items()}
    cycles = _cycles(pruned)
    assert not cycles, f"import cycles among packages: {cycles}"


# -- private names across packages ------------------------------------------------------------------

def _private_uses(mod: str, path: str) -> list[tuple[str, str]]:
    """``(module, name)`` for each private name (``_x``, not ``__x__``) that ``mod`` takes from a dyngi module of
    another top-level package: ``from X import _x``, or ``M._x`` on a module ``M`` imported by name
    (``import dyngi.X as M``, ``from dyngi import X as M``)."""
    tree = ast.parse(open(path, encoding="utf-8").read(), path)
    pkg = mod if path.endswith("__init__.py") else mod.rsplit(".", 1)[0]

    def private(name: str) -> bool:
        return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))

    aliases: dict[str, str] = {}      # local name -> the dyngi module it binds
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                if a.name.split(".")[0] == "dyngi":      # ``import dyngi.x.y`` binds ``dyngi``
                    aliases[a.asname or "dyngi"] = a.name if a.asname else "dyngi"
        elif isinstance(node, ast.ImportFrom):
            target = _from_target(node, pkg)
            if target.split(".")[0] != "dyngi":
                continue
            for a in node.names:
                sub = f"{target}.{a.name}"
                if _is_module(sub):
                    aliases[a.asname or a.name] = sub
                elif private(a.name) and _top(target) != _top(mod):
                    out.append((target, a.name))
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and private(node.attr):
            base = node.value
            dotted = []
            while isinstance(base, ast.Attribute):
                dotted.append(base.attr)
                base = base.value
            if isinstance(base, ast.Name) and base.id in aliases:
                target = ".".join([aliases[base.id]] + dotted[::-1])
                if _top(target) != _top(mod):
                    out.append((target, node.attr))
    return out


def private_cross_package_uses() -> dict[str, list[tuple[str, str]]]:
    """``{module: [(module, private name), ...]}`` over src/dyngi (modules with none left out)."""
    out = {}
    for mod, path in _modules():
        uses = _private_uses(mod, path)
        if uses:
            out[mod] = uses
    return out


def test_no_private_cross_package_import():
    """No module takes another package's private (``_x``) name: what a package shares it names publicly."""
    got = private_cross_package_uses()
    assert not got, "private names used across packages (make them public): " + "; ".join(
        f"{m} uses {t}.{n}" for m, uses in sorted(got.items()) for t, n in uses)


def test_private_checker_can_fail(tmp_path):
    """The checker itself can fail: a from-import of another package's private name and an attribute access on an
    imported module of another package are caught; the same package's private names are not."""
    f = tmp_path / "x.py"
    f.write_text("from ...probes.states import _cell_extents\nfrom .base import _helper\n"
                 "from ...probes import accumulator as acc\nimport dyngi.probes.estimator\n"
                 "def f():\n    return acc._count_sum, dyngi.probes.estimator._int_power_dr, acc.__name__\n")
    got = sorted(_private_uses("dyngi.techniques.isddgi.x", str(f)))
    assert got == [("dyngi.probes.accumulator", "_count_sum"), ("dyngi.probes.estimator", "_int_power_dr"),
                   ("dyngi.probes.states", "_cell_extents")]
