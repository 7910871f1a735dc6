"""The import direction docs/architecture.md states, read from the sources.

The product's packages are layered ``fdi`` ← ``replay`` ← ``calibration`` ← ``thresholds``
← ``rimu`` (:data:`ORDER`): a package imports only packages before it. Every ``import``
and ``from … import`` in every module is checked, including those inside functions, for
every pair of packages. ``studies`` (the evidence and the tests' simulated truth, which
the wheel does not install) may import the product; no product package imports it.

What does not hold yet is listed, not hidden: :data:`KNOWN_BACK_EDGES` (imports against
the order) and :data:`KNOWN_MODULE_CYCLES` (modules that import each other). Each entry
must still exist (a stale entry fails), and nothing else may be added.
"""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
ORDER = ("fdi", "replay", "calibration", "thresholds", "rimu")
"""The layers, lowest first: each package may import the packages before it."""
PRODUCT = ORDER
PACKAGES = (*ORDER, "studies")
KNOWN_BACK_EDGES = {
    ("replay/chain.py", "thresholds.select"),
}
"""Imports against :data:`ORDER` that are still there (file, module imported). The
monitoring chain picks its thresholds with ``thresholds.select`` (a thresholds file or
computed for a rate) while ``thresholds.campaign`` and ``thresholds.evaluate`` fly
``replay``'s simulated flights: ``replay`` ↔ ``thresholds``. Breaking it means handing the
chain a chosen ``Thresholds`` (or moving ``select`` below ``replay``)."""
KNOWN_MODULE_CYCLES = {
    frozenset({"replay.chain", "replay.live"}),
}
"""Groups of modules that import each other (strongly connected, imports inside functions
counted): ``replay.live`` builds the chain of :mod:`replay.chain` for a bus and the chain
imports the live decoder for ``rimu monitor``."""


def _modules() -> dict[str, Path]:
    out = {}
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(parts)] = path
    return out


MODULES = _modules()


def _imports(name: str, path: Path) -> list[tuple[str, int]]:
    """(module imported, line) of every import in the file, absolute and relative, at any
    depth (inside functions too); ``from a import b`` gives ``a`` and ``a.b``."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(a.name, node.lineno) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[:len(package) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            out.append((mod, node.lineno))
            out += [(f"{mod}.{a.name}", node.lineno) for a in node.names]
    return out


def _package_edges() -> dict[tuple[str, str], list[str]]:
    """(importing package, imported package) → ``file:line module`` of each import."""
    edges: dict[tuple[str, str], list[str]] = {}
    for name, path in MODULES.items():
        src = name.split(".")[0]
        for mod, line in _imports(name, path):
            dst = mod.split(".")[0]
            if dst in PACKAGES and dst != src and (mod in MODULES or mod.count(".") == 0):
                rel = path.relative_to(ROOT).as_posix()
                edges.setdefault((src, dst), []).append(f"{rel}:{line} {mod}")
    return edges


EDGES = _package_edges()


def _allowed(src: str, dst: str) -> bool:
    if src == "studies":
        return dst in PRODUCT
    if dst == "studies":
        return False
    return ORDER.index(dst) < ORDER.index(src)


def _known(site: str) -> bool:
    path, mod = site.split(":")[0], site.split(" ", 1)[1]
    return (path, mod) in KNOWN_BACK_EDGES


@pytest.mark.parametrize("package", PRODUCT)
def test_imports_point_one_way(package):
    """Every pair: ``package`` imports no package after it in :data:`ORDER`, nor
    ``studies``, apart from :data:`KNOWN_BACK_EDGES`."""
    bad = []
    for (src, dst), sites in sorted(EDGES.items()):
        if src == package and not _allowed(src, dst):
            bad += [s for s in sites if not _known(s)]
    assert not bad, "imports against fdi ← replay ← calibration ← thresholds ← rimu:\n" + \
        "\n".join(bad)


def test_every_pair_of_packages_is_checked():
    """The rule covers every ordered pair of the five packages and studies, and the pairs
    that import each other at all are exactly those the known back edges explain."""
    pairs = {(a, b) for a in PACKAGES for b in PACKAGES if a != b}
    assert len(pairs) == 30
    both_ways = {frozenset(p) for p in EDGES if p[::-1] in EDGES}
    explained = {frozenset((Path(f).parts[0], m.split(".")[0])) for f, m in KNOWN_BACK_EDGES}
    assert both_ways <= explained, both_ways - explained


def test_known_back_edges_still_exist():
    """A known back edge that was removed must leave :data:`KNOWN_BACK_EDGES` too."""
    sites = {(s.split(":")[0], s.split(" ", 1)[1]) for v in EDGES.values() for s in v}
    stale = KNOWN_BACK_EDGES - sites
    assert not stale, f"no longer imported, remove from KNOWN_BACK_EDGES: {sorted(stale)}"


def _module_cycles() -> set[frozenset[str]]:
    """Strongly connected groups (more than one module) of the product's module graph."""
    graph = {m: {d for d, _ in _imports(m, p) if d in MODULES and d != m}
             for m, p in MODULES.items() if m.split(".")[0] in PRODUCT}
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: set[frozenset[str]] = set()

    def visit(v: str) -> None:          # Tarjan; the graph is a few hundred modules deep
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = set()
            while True:
                w = stack.pop()
                on.discard(w)
                comp.add(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.add(frozenset(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_module_cycles_are_the_known_ones():
    """No modules import each other (imports inside functions counted) except the groups
    of :data:`KNOWN_MODULE_CYCLES`, each of which must still be a cycle."""
    found = _module_cycles()
    assert found == KNOWN_MODULE_CYCLES, (
        f"new cycles: {[sorted(c) for c in found - KNOWN_MODULE_CYCLES]}; "
        f"gone (remove from KNOWN_MODULE_CYCLES): "
        f"{[sorted(c) for c in KNOWN_MODULE_CYCLES - found]}")


def test_wheel_packages_are_the_product():
    """``packages.find`` of pyproject.toml selects the five product packages and their
    subpackages, never ``studies``, ``tests`` or ``benchmarks``."""
    import tomllib

    from setuptools import find_packages

    conf = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    include = conf["tool"]["setuptools"]["packages"]["find"]["include"]
    found = find_packages(where=str(ROOT), include=include)
    assert {p.split(".")[0] for p in found} == set(PRODUCT)
    on_disk = {p for p in find_packages(where=str(ROOT)) if p.split(".")[0] in PRODUCT}
    assert on_disk <= set(found)
