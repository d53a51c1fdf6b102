"""The packages' contract, read from their import statements (module level and inside functions):

- ``recon`` never imports the simulator (``sim``, ``scenes``, Mitsuba, drjit) nor the
  application (``kaleidospec``): it sees raw frames and captures only;
- ``sim`` never imports the application;
- inside ``kaleidospec`` only :mod:`kaleidospec.instrument` imports ``sim``, Mitsuba or drjit;
- no package imports itself in a circle.
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


def cycles(package: str) -> list[list[str]]:
    """The import circles among the modules of ``package`` (strongly connected components)."""
    found = imports(package)
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


def test_recon_sees_no_simulator_and_no_application():
    assert offenders("recon", ("sim", "scenes", "mitsuba", "drjit", "kaleidospec")) == {}


def test_sim_does_not_import_the_application():
    assert offenders("sim", ("kaleidospec",)) == {}


def test_only_the_instrument_stage_imports_the_simulator():
    assert offenders("kaleidospec", ("sim", "mitsuba", "drjit"),
                     allowed=("kaleidospec.instrument",)) == {}


@pytest.mark.parametrize("package", ["sim", "recon", "scenes", "kaleidospec"])
def test_no_import_circles(package):
    assert cycles(package) == []
