"""The layers of brdfscale, checked on the source (docs/architecture.md).

Every module under ``brdfscale/`` and ``fitting/`` (installed as ``brdfscale.fitting``) belongs to
one *unit* — a subpackage (``brdfscale.stats``) or a top-level module (``brdfscale.geometry``,
``brdfscale._errors``) — and every unit to one layer, lowest first:

0. core utilities — the exceptions, argument checks, special functions, geometry, quadrature,
   interpolation, the compact display (``show``), files, the Laplace approximation, the figure
   seam (``brdfscale._figures``), and the ``brdfscale`` package itself (its lazy table);
1. models — ``stats``, ``lobes``, ``_evolve``, ``plus``, ``so3``, ``scene``, ``synth``, the
   measurements (``_measurement``) and what they rest on;
2. I/O — ``exr``, ``topography``;
3. fitting — ``brdfscale.fitting``;
4. plot — ``brdfscale.plot``, a leaf: no module of layers 0–3 imports it;
5. applications — the command line (``brdfscale._cli``, ``brdfscale.__main__``) and ``brdfscale.library``.

A module may import its own unit and lower layers, never a higher layer; within a layer the
units' imports form no cycle, and across all units there is no cycle either. Every import
counts: at the top of a module or inside a function, relative ones resolved, and
``importlib.import_module("...")`` with a literal name; ``from brdfscale import NAME`` counts as
an import of the module that the lazy table (``brdfscale._LAZY``) names for ``NAME``, and so
does ``brdfscale.NAME`` after ``import brdfscale``. Imports under ``if TYPE_CHECKING:`` do not
run and do not count.

The one allowed exception is the figure seam: :mod:`brdfscale._figures` imports
:mod:`brdfscale.plot` by name when a user calls an object's ``.plot()`` (``lobe.plot()``,
``density.plot()``, ``mset.plot()``, ``plan.plot()``, ``fit_result.plot(problem)``,
``samples.plot()``), so the objects keep
their figures without the library depending on matplotlib or on the plot package.
``ALLOWED_UPWARD`` lists that edge and nothing else.

Also checked: no module imports a private module of another package (``brdfscale.x._y`` from
outside ``brdfscale.x``; the top-level private modules ``brdfscale._errors`` and the like are the
package's shared internals) or an underscored name of another unit; nothing imports ``fitting``
under its folder's name; pyproject installs every package folder, ``fitting/`` as
``brdfscale.fitting``.
"""

import ast
import functools
import importlib
import importlib.util
import sys
from pathlib import Path

import pytest


ROOT = Path(__file__).resolve().parents[1]

LAYERS = {
    0: (
        "brdfscale",
        "brdfscale._errors",
        "brdfscale._validation",
        "brdfscale.checks",
        "brdfscale._special",
        "brdfscale.special",
        "brdfscale.geometry",
        "brdfscale._show",
        "brdfscale.show",
        "brdfscale._files",
        "brdfscale.files",
        "brdfscale._quadrature",
        "brdfscale._interpolate",
        "brdfscale.laplace",
        "brdfscale._figures",
        "brdfscale._figure_style",
        "brdfscale._choices",
        "brdfscale.choices",
        "brdfscale._shown_figure",
        "brdfscale._compilation_cache",
        "brdfscale._json",
        "brdfscale._shadow",
        "brdfscale._slopes",
        "brdfscale._mitsuba",
        "brdfscale._cluster",
        "brdfscale._watchdog",
    ),
    1: (
        "brdfscale.stats",
        "brdfscale.lobes",
        "brdfscale._evolve",
        "brdfscale._existence",
        "brdfscale._blocks",
        "brdfscale._surfaces",
        "brdfscale.plus",
        "brdfscale.so3",
        "brdfscale.scene",
        "brdfscale.synth",
        "brdfscale._measurement",
    ),
    2: ("brdfscale.exr", "brdfscale.topography", "brdfscale.instrument"),
    3: ("brdfscale.fitting", "brdfscale.render"),
    4: ("brdfscale.plot",),
    5: ("brdfscale._cli", "brdfscale.__main__", "brdfscale.library"),
}
LAYER = {unit: layer for layer, units in LAYERS.items() for unit in units}
ALLOWED_UPWARD = {("brdfscale._figures", "brdfscale.plot")}
"""The figure seam (docs/architecture.md): the only import of a higher layer."""


def _modules() -> dict[str, Path]:
    """Every module of the distribution by its installed name."""
    found = {}
    for folder, package in ((ROOT / "brdfscale", "brdfscale"), (ROOT / "fitting", "brdfscale.fitting")):
        for path in sorted(folder.rglob("*.py")):
            parts = list(path.relative_to(folder).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            found[".".join([package, *parts])] = path
    return found


MODULES = _modules()


def _is_package(module: str) -> bool:
    return MODULES[module].name == "__init__.py"


@functools.cache
def _lazy_table() -> dict[str, str]:
    """``brdfscale._LAZY``: public name → the module that defines it (absolute)."""
    import brdfscale

    return {name: importlib.util.resolve_name(where, "brdfscale") for name, where in brdfscale._LAZY.items()}


def _type_checking_lines(tree) -> set[int]:
    lines = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            for child in node.body:
                lines.update(range(child.lineno, (child.end_lineno or child.lineno) + 1))
    return lines


def _known(name: str) -> str | None:
    """The module of the distribution ``name`` is or lies in (``a.b.c`` → the longest known prefix)."""
    while name and name not in MODULES:
        name = name.rpartition(".")[0]
    return name or None


@functools.cache
def imports(module: str) -> list[tuple[str, int, str]]:
    """(imported module of the distribution, line, source text) for every import in ``module``."""
    path = MODULES[module]
    tree = ast.parse(path.read_text(), str(path))
    skip = _type_checking_lines(tree)
    package = module if _is_package(module) else module.rpartition(".")[0]
    lazy = _lazy_table()
    found = []

    def add(target, node):
        if target is not None and node.lineno not in skip and (target, node.lineno) not in {f[:2] for f in found}:
            found.append((target, node.lineno, ast.get_source_segment(path.read_text(), node) or ""))

    facade = set()  # the names `import brdfscale` (as …) binds: `brdfscale.NAME` is an import of NAME's module
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name == "fitting" or alias.name.startswith("fitting."):
                    add(alias.name, node)  # flagged by test_nothing_imports_fitting_by_its_folder_name
                elif alias.name.split(".")[0] == "brdfscale":
                    add(_known(alias.name), node)
                    if alias.name == "brdfscale" or alias.asname is None:
                        facade.add(alias.asname or "brdfscale")
        elif isinstance(node, ast.ImportFrom):
            base = (
                importlib.util.resolve_name("." * node.level + (node.module or ""), package)
                if node.level
                else node.module
            )
            if base == "fitting" or (base or "").startswith("fitting."):
                add(base, node)
                continue
            if base is None or base.split(".")[0] != "brdfscale":
                continue
            for alias in node.names:
                if base == "brdfscale" and alias.name in lazy:
                    add(_known(lazy[alias.name]), node)
                elif f"{base}.{alias.name}" in MODULES:
                    add(f"{base}.{alias.name}", node)
                else:
                    add(_known(base), node)
        elif (
            isinstance(node, ast.Call)
            and ast.unparse(node.func) in ("importlib.import_module", "import_module")
            and node.args
            and isinstance(node.args[0], ast.Constant)
            and isinstance(node.args[0].value, str)
        ):
            name = node.args[0].value
            if name.startswith("."):
                name = importlib.util.resolve_name(name, package)
            if name.split(".")[0] == "brdfscale":
                add(_known(name), node)
    for node in ast.walk(tree):
        if (
            isinstance(node, ast.Attribute)
            and isinstance(node.value, ast.Name)
            and node.value.id in facade
            and node.attr in lazy
        ):
            add(_known(lazy[node.attr]), node)
    return found


def unit(module: str) -> str:
    """The unit of ``module``: its subpackage of brdfscale, or the top-level module itself."""
    parts = module.split(".")
    return ".".join(parts[:2])


@functools.cache
def edges() -> list[tuple[str, str, str, int, str]]:
    """(from unit, to unit, from module, line, source) for every import between two units."""
    found = []
    for module in MODULES:
        for target, line, text in imports(module):
            if target in MODULES and unit(target) != unit(module):
                found.append((unit(module), unit(target), module, line, text))
    return found


def _where(edge) -> str:
    _, _, module, line, text = edge
    return f"{MODULES[module].relative_to(ROOT)}:{line}: {text.splitlines()[0] if text else ''}"


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one node (Tarjan)."""
    index, low, stack, on, found = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10_000))
    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_every_unit_has_a_layer():
    assert sorted({unit(m) for m in MODULES} - set(LAYER)) == []
    assert sorted(set(LAYER) - {unit(m) for m in MODULES}) == []


def test_no_module_imports_a_higher_layer():
    upward = [
        _where(e) + f"  ({e[0]}, layer {LAYER[e[0]]} → {e[1]}, layer {LAYER[e[1]]})"
        for e in edges()
        if e[0] in LAYER
        and e[1] in LAYER  # a unit without a layer: the test above
        and LAYER[e[1]] > LAYER[e[0]]
        and (e[0], e[1]) not in ALLOWED_UPWARD
    ]
    assert upward == []


def test_the_figure_seam_is_the_only_upward_edge_and_it_exists():
    """The allow-list is not dead: the seam imports the plot package, and nothing else does from below."""
    seam = [e for e in edges() if (e[0], e[1]) in ALLOWED_UPWARD]
    assert seam and {e[2] for e in seam} == {"brdfscale._figures"}
    into_plot = sorted(
        {e[0] for e in edges() if e[1] == "brdfscale.plot" and LAYER.get(e[0], 0) < LAYER["brdfscale.plot"]}
    )
    assert into_plot == ["brdfscale._figures"]  # plot is a leaf of the library: only the applications import it


def test_no_import_cycle_between_units():
    graph: dict[str, set[str]] = {}
    for e in edges():
        if (e[0], e[1]) not in ALLOWED_UPWARD:
            graph.setdefault(e[0], set()).add(e[1])
    found = cycles(graph)
    detail = [[_where(e) for e in edges() if e[0] in c and e[1] in c] for c in found]
    assert found == [], detail


def test_no_import_cycle_between_modules():
    """Module level, inside each package too (a package's ``__init__`` importing its submodules,
    which import their siblings directly, is no cycle; one importing the ``__init__`` back is)."""
    graph: dict[str, set[str]] = {}
    for module in MODULES:
        for target, _, _ in imports(module):
            if target in MODULES and target != module and (unit(module), unit(target)) not in ALLOWED_UPWARD:
                graph.setdefault(module, set()).add(target)
    assert cycles(graph) == []


def private_imports() -> dict[tuple[str, str], str]:
    """(module, private target) → where, for every import of ``brdfscale.x._y`` from outside
    ``brdfscale.x``, and every private name (``_name``) imported from another unit."""
    found = {}
    for module in MODULES:
        for target, line, text in imports(module):
            parts = target.split(".")
            private = [i for i, p in enumerate(parts) if p.startswith("_") and i >= 2]
            owner = ".".join(parts[: private[0]]) if private else module
            if module != owner and not module.startswith(owner + "."):
                found[(module, target)] = f"{MODULES[module].relative_to(ROOT)}:{line}: {text.splitlines()[0]}"
        path = MODULES[module]
        package = module if _is_package(module) else module.rpartition(".")[0]
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom):
                base = (
                    importlib.util.resolve_name("." * node.level + (node.module or ""), package)
                    if node.level
                    else node.module
                ) or ""
                source = _known(base)
                for alias in node.names:
                    name = alias.name
                    if (
                        source is not None
                        and name.startswith("_")
                        and not name.startswith("__")
                        and f"{base}.{name}" not in MODULES
                        and unit(source) != unit(module)
                    ):
                        found[(module, f"{base}.{name}")] = f"{path.relative_to(ROOT)}:{node.lineno}: {name}"
    return found


def test_no_private_import_across_packages():
    """``brdfscale.x._y`` (or a name from it) only from inside ``brdfscale.x``; no ``_name`` of
    another unit."""
    assert sorted(private_imports().values()) == []


def test_nothing_imports_fitting_by_its_folder_name():
    """The folder ``fitting/`` is installed as ``brdfscale.fitting``; ``import fitting`` would find
    the folder only from the repository's root. Tests, experiments, docs and notebooks too."""
    import json
    import re

    pattern = re.compile(r"^\s*(import fitting\b|from fitting\b)", re.MULTILINE)
    texts = [
        *ROOT.glob("brdfscale/**/*.py"),
        *ROOT.glob("fitting/**/*.py"),
        *ROOT.glob("tests/**/*.py"),
        *ROOT.glob("experiments/**/*.py"),
        *ROOT.glob("docs/**/*.md"),
        ROOT / "README.md",
    ]
    offenders = [str(p.relative_to(ROOT)) for p in texts if pattern.search(p.read_text())]
    for notebook in ROOT.glob("docs/**/*.ipynb"):
        cells = json.loads(notebook.read_text())["cells"]
        code = "\n".join("".join(c["source"]) for c in cells if c["cell_type"] == "code")
        offenders += [str(notebook.relative_to(ROOT))] if pattern.search(code) else []
    offenders += [
        f"{MODULES[m].relative_to(ROOT)}:{line}"
        for m in MODULES
        for t, line, _ in imports(m)
        if t.split(".")[0] == "fitting"
    ]
    assert offenders == []


@pytest.mark.parametrize("module", sorted(MODULES))
def test_the_walk_sees_every_module(module):
    """The checks above are only as good as the walk: every module parses, and the graph knows
    every brdfscale module it names (no import of a brdfscale module the walk cannot place)."""
    for target, line, text in imports(module):
        assert target in MODULES, f"{MODULES[module].relative_to(ROOT)}:{line}: {text}"


def test_pyproject_installs_every_package_folder_and_fitting_under_brdfscale():
    """pyproject lists the packages by hand (the fitting/ folder needs ``package-dir``): every
    package folder is listed, so a new subpackage cannot be left out of the wheel."""
    import tomllib

    setuptools = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    assert setuptools["package-dir"] == {"brdfscale": "brdfscale", "brdfscale.fitting": "fitting"}
    folders = sorted(m for m in MODULES if _is_package(m))
    assert sorted(setuptools["packages"]) == folders
