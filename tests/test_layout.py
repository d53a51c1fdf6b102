"""The house's contract, read from the import statements (module level and inside functions).

The packages stand in layers, and a module imports only from its own layer or those below:

    recon  <  scenes  <  sim  <  kaleidospec  <  tools/ (scripts)

- ``recon`` never imports the simulator (``sim``, ``scenes``, Mitsuba, drjit) nor the
  application (``kaleidospec``): it sees raw frames and captures only;
- ``scenes`` (the hyperspectral targets and their spectra) never imports ``sim``: the simulator
  renders scenes, scenes know nothing of it;
- inside ``sim`` the rooms stand in layers too (:data:`SIM_LAYERS`): the bands and the
  sensor, the optics, the transport integrated over them, frames and measurements, captures;
- inside ``kaleidospec`` only :mod:`kaleidospec.instrument` imports ``sim``, Mitsuba or drjit;
- no import circle, inside a package or across packages;
- the scripts in ``tools/`` use the packages' public names only: no ``sys.path`` edits, no
  script imports another, no private (``_``) name of a package.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def imports(package: str) -> dict[str, set[str]]:
    """``{module: the modules it imports}`` for every module of ``package``; ``from a import b``
    counts as importing ``a`` and ``a.b``."""
    out = {}
    for path in sorted((ROOT / package).rglob("*.py")):
        mod = ".".join(path.relative_to(ROOT).with_suffix("").parts)
        mod = mod.removesuffix(".__init__")
        names = set()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                names |= {a.name for a in node.names}
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                names.add(node.module)
                names |= {f"{node.module}.{a.name}" for a in node.names}
        out[mod] = names
    return out


def offenders(package: str, forbidden: tuple[str, ...], allowed=()) -> dict[str, list[str]]:
    bad = {}
    for mod, names in imports(package).items():
        if mod in allowed:
            continue
        hit = sorted(n for n in names if n.split(".")[0] in forbidden)
        if hit:
            bad[mod] = hit
    return bad


def cycles(*packages: str) -> list[list[str]]:
    """The import circles among the modules of ``packages`` (strongly connected components)."""
    found = {m: names for p in packages for m, names in imports(p).items()}
    graph = {m: {n for n in names if n in found and n != m} for m, names in found.items()}
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph[v]:
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

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


#: The packages from the bottom up: each imports only those before it.
LAYERS = ("recon", "scenes", "sim", "kaleidospec")
#: ``sim``'s rooms from the bottom up (a sub-package or a module directly in ``sim``).
SIM_LAYERS = (("sim.bands",), ("sim.sensor",), ("sim.optics",), ("sim.transport",),
              ("sim.frame", "sim.measure"), ("sim.captures",))


def test_recon_sees_no_simulator_and_no_application():
    assert offenders("recon", ("sim", "scenes", "mitsuba", "drjit", "kaleidospec")) == {}


def test_scenes_see_no_simulator_and_no_application():
    assert offenders("scenes", ("sim", "mitsuba", "drjit", "kaleidospec")) == {}


@pytest.mark.parametrize("package", LAYERS)
def test_no_arrow_points_up_across_packages(package):
    above = LAYERS[LAYERS.index(package) + 1:]
    assert offenders(package, above) == {}


def room(module: str) -> str:
    """The room of a module of ``sim``: its sub-package, or itself directly under ``sim``."""
    return ".".join(module.split(".")[:2])


def test_no_arrow_points_up_between_the_rooms_of_sim():
    found = imports("sim")
    level = {r: i for i, rooms in enumerate(SIM_LAYERS) for r in rooms}
    assert {room(m) for m in found} - {"sim"} == set(level), "a room of sim is not in SIM_LAYERS"
    bad = {}
    for mod, names in found.items():
        if mod == "sim":
            continue
        up = sorted(n for n in names if n in found and n != "sim"
                    and level[room(n)] > level[room(mod)])
        if up:
            bad[mod] = up
    assert bad == {}


def test_only_the_instrument_stage_imports_the_simulator():
    assert offenders("kaleidospec", ("sim", "mitsuba", "drjit"),
                     allowed=("kaleidospec.instrument",)) == {}


@pytest.mark.parametrize("package", ["sim", "recon", "scenes", "kaleidospec"])
def test_no_import_circles(package):
    assert cycles(package) == []


def test_no_import_circle_across_packages():
    assert cycles(*LAYERS) == []


# ------------------------------------------------------------------------------- tools
TOOLS = sorted((ROOT / "tools").glob("*.py"))


def _names_of_packages(tree) -> dict[str, str]:
    """Local name → the project module it is bound to by an import."""
    bound = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                if a.name.split(".")[0] in LAYERS:
                    # ``import a.b as x`` binds x to a.b; ``import a.b`` binds a.
                    bound[a.asname or a.name.split(".")[0]] = a.name if a.asname else \
                        a.name.split(".")[0]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            if node.module.split(".")[0] in LAYERS:
                for a in node.names:
                    bound[a.asname or a.name] = f"{node.module}.{a.name}"
    return bound


@pytest.mark.parametrize("path", TOOLS, ids=lambda p: p.name)
def test_tools_use_public_names_only(path):
    tree = ast.parse(path.read_text(encoding="utf-8"))
    # A script runs (a ``__main__`` block); a module of tools/ without one is a library file
    # of the benchmarks (the plain reference GAP-TV).
    scripts = {p.stem for p in TOOLS if '__name__ == "__main__"' in p.read_text(encoding="utf-8")}
    bad = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Attribute) \
                and isinstance(node.value.value, ast.Name) and node.value.value.id == "sys" \
                and node.value.attr == "path":
            bad.append(f"line {node.lineno}: edits sys.path")
        if isinstance(node, ast.Import):
            bad += [f"line {node.lineno}: imports the script {a.name}" for a in node.names
                    if a.name in scripts]
        if isinstance(node, ast.ImportFrom) and node.module:
            if node.module.split(".")[0] in scripts:
                bad.append(f"line {node.lineno}: imports the script {node.module}")
            if node.module.split(".")[0] in LAYERS:
                bad += [f"line {node.lineno}: imports {node.module}.{a.name}" for a in node.names
                        if a.name.startswith("_")]
    bound = _names_of_packages(tree)
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) \
                and node.value.id in bound and node.attr.startswith("_") \
                and not node.attr.startswith("__"):
            bad.append(f"line {node.lineno}: uses {bound[node.value.id]}.{node.attr}")
    assert bad == []
