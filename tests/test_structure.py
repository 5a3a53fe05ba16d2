"""The package's structure, read from its source with ``ast`` (nothing is imported).

The modules are every ``.py`` file of ``geosynth/`` (the kernels included:
``geosynth/kernels/``). Only module-level imports are read: statements at the top of a
module, including those inside top-level ``if``/``try`` blocks, but not those inside a
function or class body. A module-level import runs while the importing module is half
initialised, so a cycle of them can fail with "partially initialized module" or hand out
names that do not exist yet, depending on which module is imported first. An import
inside a function runs when the function is called, after every module has finished
loading, so it cannot cause that; the code uses it deliberately to break a dependency
(the backends are imported that way by ``geosynth.compute.backend``). A second graph counts those
imports too: it must have no cycle either (issue 33). ``if TYPE_CHECKING:`` blocks never run
and are skipped.

The layout (issue 33): the top level holds only the public API and the command line; every
other module lives in one subpackage per shared layer (core, io, kernels, _backends, compute,
geometry), per method (volume, pointtexture, texturing, completion) or per application built
on the methods (relief). Counting the imports inside functions, a module imports only its own
subpackage and lower layers, and no method imports another.
"""

from __future__ import annotations

import ast
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = {"geosynth": ROOT / "geosynth"}


def _modules() -> dict[str, Path]:
    """``{dotted module name: source file}`` for every module of the package."""
    out = {}
    for package, folder in PACKAGES.items():
        for path in sorted(folder.rglob("*.py")):
            if ".venv" in path.parts:
                continue
            parts = list(path.relative_to(folder).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join([package, *parts])] = path
    return out


MODULES = _modules()


def _is_package(name: str) -> bool:
    return MODULES[name].name == "__init__.py"


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _top_level_imports(tree: ast.Module):
    """The module-level Import/ImportFrom nodes (into if/try/with blocks, not into defs)."""
    stack = list(tree.body)
    while stack:
        node = stack.pop(0)
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            yield node
        elif isinstance(node, ast.If):
            if not _is_type_checking(node.test):
                stack.extend(node.body)
            stack.extend(node.orelse)
        elif isinstance(node, ast.Try):
            stack.extend(node.body + node.orelse + node.finalbody)
            for handler in node.handlers:
                stack.extend(handler.body)
        elif isinstance(node, ast.With):
            stack.extend(node.body)


def _resolve_from(module: str, node: ast.ImportFrom) -> str:
    """The absolute module name ``from X import ...`` names (relative imports resolved)."""
    if not node.level:
        return node.module or ""
    base = module.split(".") if _is_package(module) else module.split(".")[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def _every_import(tree: ast.Module):
    """Every Import/ImportFrom node, inside functions and classes too (``if TYPE_CHECKING:``
    blocks still skipped: they never run)."""
    skip = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and _is_type_checking(node.test):
            skip.update(id(n) for child in node.body for n in ast.walk(child))
    for node in ast.walk(tree):
        if isinstance(node, (ast.Import, ast.ImportFrom)) and id(node) not in skip:
            yield node


def _imports(module: str, inside_functions: bool = False):
    """``(imported geosynth module, imported name or None, line)`` for each module-level import
    (``inside_functions``: every import, wherever it runs).

    ``from a.b import c`` imports the module ``a.b.c`` when there is one, else the name
    ``c`` of ``a.b``.
    """
    tree = ast.parse(MODULES[module].read_text(), filename=str(MODULES[module]))
    for node in (_every_import(tree) if inside_functions else _top_level_imports(tree)):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name in MODULES:
                    yield alias.name, None, node.lineno
            continue
        source = _resolve_from(module, node)
        for alias in node.names:
            sub = f"{source}.{alias.name}"
            if sub in MODULES:
                yield sub, None, node.lineno
            elif source in MODULES:
                yield source, alias.name, node.lineno


def _graph(inside_functions: bool = False) -> dict[str, set[str]]:
    return {m: {target for target, _, _ in _imports(m, inside_functions) if target != m} for m in MODULES}


def find_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Every strongly connected group of more than one module (Tarjan), each as one cycle
    through it ``[a, b, ..., a]``, sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on_stack: set[str] = set()
    stack: list[str] = []
    groups: list[set[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = set()
            while True:
                w = stack.pop()
                on_stack.discard(w)
                group.add(w)
                if w == v:
                    break
            if len(group) > 1:
                groups.append(group)

    for v in sorted(graph):
        if v not in index:
            visit(v)

    cycles = []
    for group in groups:  # one concrete cycle per group: a shortest path back to its first module
        start = min(group)
        paths = {start: [start]}
        frontier = [start]
        cycle = None
        while frontier and cycle is None:
            nxt = []
            for v in frontier:
                for w in sorted(graph[v] & group):
                    if w == start:
                        cycle = paths[v] + [start]
                        break
                    if w not in paths:
                        paths[w] = paths[v] + [w]
                        nxt.append(w)
                if cycle:
                    break
            frontier = nxt
        cycles.append(cycle)
    return sorted(cycles)


def test_modules_found():
    for name in ("geosynth", "geosynth.core.arrays", "geosynth.compute.backend", "geosynth._backends.base",
                 "geosynth.kernels.ssd"):
        assert name in MODULES


def test_cycle_finder_finds_a_cycle():
    """The finder itself: a planted cycle is reported, a chain is not."""
    assert find_cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c", "a"]]
    assert find_cycles({"a": {"b"}, "b": {"c"}, "c": set()}) == []


def test_no_import_cycle():
    cycles = find_cycles(_graph())
    assert not cycles, "module-level import cycles: " + "; ".join(" -> ".join(c) for c in cycles)


def test_no_import_cycle_even_through_function_level_imports():
    """The modules draw as a tree with no arrow back up (issue 33): counting the imports that
    run inside a function too, no module reaches itself. A function-level import may still
    put off a heavy or optional dependency, never hide a cycle."""
    package = {m for m in MODULES if not _is_package(m)}  # geosynth/__init__ re-exports lazily
    graph = {m: targets & package for m, targets in _graph(inside_functions=True).items() if m in package}
    cycles = find_cycles(graph)
    assert not cycles, "import cycles through function-level imports: " + "; ".join(" -> ".join(c) for c in cycles)


def test_arrays_is_a_leaf():
    """geosynth.core.arrays, imported by the API and the backends alike, imports no geosynth module,
    not even inside a function."""
    assert _graph()["geosynth.core.arrays"] == set()
    assert _graph(inside_functions=True)["geosynth.core.arrays"] == set()


def test_backends_do_not_import_the_device_switch():
    """The backends take DeviceArray from geosynth.core.arrays, never from geosynth.compute.backend."""
    graph = _graph()
    for name in MODULES:
        if name.startswith("geosynth._backends."):
            assert "geosynth.compute.backend" not in graph[name], f"{name} imports geosynth.compute.backend at module level"



# -- the layout: one subpackage per shared layer and per method (issue 33) -----------

TOP_LEVEL = {"__init__.py", "__main__.py", "_launch.py", "cli.py"}  # the public API and the command line
METHODS = {"volume": "M1", "pointtexture": "M2", "texturing": "M3", "completion": "M4"}
# Each subpackage's layer, lowest first. A module imports only modules of its own subpackage and
# of subpackages of a lower layer, counting the imports inside functions; the top level
# (geosynth/__init__, cli, _launch, __main__) stands above them all and nothing below imports it.
# Above the methods, the applications built from them: relief over any mesh (issue 34) grows with M4's
# matching, so it stands on the methods' layer instead of beside them.
APPLICATIONS = {"relief": "relief over any mesh (M4's growth)"}
LAYERS = {"core": 0, "io": 1, "kernels": 1, "_backends": 2, "compute": 3, "geometry": 4, **{m: 5 for m in METHODS},
          **{a: 6 for a in APPLICATIONS}}


def _layer_of(module: str) -> str | None:
    """The subpackage ``module`` belongs to (``geosynth.volume.tiled`` -> ``volume``); None for
    the top level."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 and parts[1] in LAYERS else None


def test_top_level_is_the_api_and_the_command_line():
    """``ls geosynth/`` shows the architecture: the four top-level modules, then one folder per
    shared layer and per method, each a package."""
    folder = PACKAGES["geosynth"]
    assert {p.name for p in folder.glob("*.py")} == TOP_LEVEL
    folders = {p.name for p in folder.iterdir() if p.is_dir() and p.name != "__pycache__"}
    assert folders == set(LAYERS)
    assert all((folder / name / "__init__.py").is_file() for name in LAYERS)


def test_each_layer_imports_only_layers_below_it():
    """core imports nothing of geosynth outside core; io only core; the backends only core and
    the kernels; compute adds the backends; geometry adds compute and io; a method any shared
    layer. Nothing imports the top level. Imports inside functions count."""
    bad = []
    for module, targets in _graph(inside_functions=True).items():
        mine = _layer_of(module)
        if mine is None:
            continue
        for target in sorted(targets):
            theirs = _layer_of(target)
            if theirs != mine and (theirs is None or LAYERS[theirs] >= LAYERS[mine]):
                bad.append(f"{module} ({mine}) -> {target} ({theirs or 'top level'})")
    assert not bad, "imports against the layer order:\n" + "\n".join(bad)


def test_no_method_imports_another_method():
    """Each method's subpackage (M1 volume, M2 pointtexture, M3 texturing, M4 completion)
    imports no other method's, not even inside a function: what they share lives in a shared layer."""
    bad = sorted(f"{METHODS[_layer_of(m)]}: {m} -> {t}" for m, targets in _graph(inside_functions=True).items()
                 for t in targets if _layer_of(m) in METHODS and _layer_of(t) in METHODS and _layer_of(t) != _layer_of(m))
    assert not bad, "\n".join(bad)


def test_subpackages_import_nothing_when_imported():
    """A subpackage's ``__init__`` only documents it: importing ``geosynth.volume`` loads none of
    its modules (``import geosynth`` and each folder stay cheap)."""
    for name in MODULES:
        if name != "geosynth" and _is_package(name):
            tree = ast.parse(MODULES[name].read_text())
            assert not [n for n in ast.walk(tree) if isinstance(n, (ast.Import, ast.ImportFrom))], name


# -- private names ------------------------------------------------------------------


def _private_uses(module: str):
    """``(line, text)`` for each use in ``module`` of another geosynth module's private name:
    ``from geosynth.m import _name`` (at any depth: imports inside functions count too,
    since the rule is about whose name it is, not when it is loaded), and ``m._name`` where
    ``m`` is a name bound to a geosynth module by an import. A private module imported as
    a module (``from geosynth import _backends``, ``geosynth._backends.base``) is not a
    private name: such modules are private to the package and shared inside it by design.
    """
    tree = ast.parse(MODULES[module].read_text(), filename=str(MODULES[module]))
    bound: dict[str, str] = {}  # local name -> geosynth module it refers to
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name in MODULES:  # `import a.b` binds a; `import a.b as c` binds c to a.b
                    if alias.asname:
                        bound[alias.asname] = alias.name
                    else:
                        bound[alias.name.split(".")[0]] = alias.name.split(".")[0]
        elif isinstance(node, ast.ImportFrom):
            source = _resolve_from(module, node)
            if not source.startswith("geosynth"):
                continue
            for alias in node.names:
                sub = f"{source}.{alias.name}"
                if sub in MODULES:
                    bound[alias.asname or alias.name] = sub
                elif alias.name.startswith("_") and source != module:
                    out.append((node.lineno, f"from {source} import {alias.name}"))
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and node.attr.startswith("_") and not node.attr.startswith("__"):
            target = _dotted(node.value, bound)
            if target is not None and target in MODULES and target != module and f"{target}.{node.attr}" not in MODULES:
                out.append((node.lineno, f"{target}.{node.attr}"))
    return sorted(set(out))


def _dotted(node: ast.expr, bound: dict[str, str]) -> str | None:
    """The geosynth module an expression such as ``volume`` or ``geosynth.compute.backend`` names, if any."""
    if isinstance(node, ast.Name):
        return bound.get(node.id)
    if isinstance(node, ast.Attribute):
        base = _dotted(node.value, bound)
        return f"{base}.{node.attr}" if base is not None else None
    return None


# Private names of geosynth.texturing.parameterize still imported while R2's split of texture.py
# (issue 15) is in flight: that split makes them public. Each entry must still match a
# use, so the lead deletes the entry once the merge has removed it.
PENDING_PRIVATE_USES: set[tuple[str, str]] = set()


def test_private_use_finder(tmp_path):
    """The finder on planted source: a private name imported or read through a module is
    found; a private module imported as a module, and a module's own names, are not."""
    source = ("from geosynth import _backends\nfrom geosynth.volume.synthesis import _x, y\nimport geosynth.compute.backend as b\n"
              "def f():\n    from geosynth.volume.pyramid import _z\n    return b._w, _backends.base\n")
    path = tmp_path / "planted.py"
    path.write_text(source)
    MODULES["geosynth._planted"] = path
    try:
        found = [text for _, text in _private_uses("geosynth._planted")]
    finally:
        del MODULES["geosynth._planted"]
    assert found == ["from geosynth.volume.synthesis import _x", "from geosynth.volume.pyramid import _z", "geosynth.compute.backend._w"]


def test_no_module_imports_a_private_name():
    """No geosynth module uses another geosynth module's private (underscore) name.

    The rule: a name is private to the module that defines it. Another module that needs
    it gets it made public (no underscore, documented) in its home module. Private
    *modules* (``geosynth._backends.*``) are shared inside the package by design: importing
    them, and their public names, is fine.
    Tests are not held to this (they may reach into internals to test them).
    """
    found = {(m, text): line for m in MODULES for line, text in _private_uses(m)}
    stale = sorted(PENDING_PRIVATE_USES - set(found))
    assert not stale, f"entries of PENDING_PRIVATE_USES no longer found, delete them: {stale}"
    bad = sorted(f"{MODULES[m].relative_to(ROOT)}:{line}: {text}" for (m, text), line in found.items()
                 if (m, text) not in PENDING_PRIVATE_USES)
    assert not bad, "modules using another module's private name:\n" + "\n".join(bad)


# -- the public API ------------------------------------------------------------------

ENTRY_POINTS = ["synthesize_geometry", "synthesize_volume", "texture_points", "mesh_distance", "pointset_distance",
                "Field", "PointSet", "read_point_set", "write_point_set", "read_geometry", "load_mesh", "save_mesh",
                "read_texture", "write_texture", "write_image", "DeviceArray", "to_device", "devices", "argmin"]


def test_public_api_is_complete():
    """Every method's entry point and data type is exported; every exported name resolves
    (lazy ones to the very object of their home module) and is listed by dir()."""
    import importlib

    import geosynth

    assert set(ENTRY_POINTS) <= set(geosynth.__all__)
    assert len(set(geosynth.__all__)) == len(geosynth.__all__)
    for name in geosynth.__all__:
        value = getattr(geosynth, name)
        home = geosynth._LAZY.get(name)
        if home is not None:
            assert value is getattr(importlib.import_module(home), name)
    assert set(geosynth.__all__) <= set(dir(geosynth))
    assert callable(geosynth.Field.load) and callable(geosynth.Field.save)
    with pytest.raises(AttributeError, match="no attribute 'not_a_name'"):
        geosynth.not_a_name  # noqa: B018


def test_import_stays_light():
    """``import geosynth`` imports none of the heavy libraries nor the modules exported lazily."""
    code = ("import sys, geosynth; print(' '.join(m for m in sys.modules if m.split('.')[0] in "
            "('trimesh', 'scipy', 'skimage', 'PIL', 'warp', 'pyopencl') or m in set(geosynth._LAZY.values())))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == []


DOC_FILES = ["README.md", *sorted(str(p.relative_to(ROOT)) for p in (ROOT / "docs").glob("*.md"))]


@pytest.mark.parametrize("doc", DOC_FILES)
def test_readme_uses_public_names(doc):
    """The Python examples of the README and of every docs/*.md page (its ```python blocks)
    import only ``geosynth`` and use names it exports."""
    import geosynth

    blocks = re.findall(r"```python\n(.*?)```", (ROOT / doc).read_text(), re.S)
    if doc == "README.md":
        assert blocks
    for block in blocks:
        tree = ast.parse(block)
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                assert not (node.module or "").startswith("geosynth"), f"{doc}: from {node.module} import ..."
            if isinstance(node, ast.Import):
                for alias in node.names:
                    assert not alias.name.startswith("geosynth."), f"{doc}: import {alias.name}"
            if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id == "geosynth":
                assert node.attr in geosynth.__all__, f"{doc} uses geosynth.{node.attr}, which is not exported"
