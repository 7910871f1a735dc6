"""The import direction docs/architecture.md states, read from the sources.

The product's packages are layered ``fdi`` ← ``replay`` ← ``calibration`` ← ``thresholds``
← ``rimu`` (:data:`ORDER`): a package imports only packages before it. Every ``import``
and ``from … import`` in every module is checked, including those inside functions, for
every pair of packages. ``studies`` (the evidence and the tests' simulated truth, which
the wheel does not install) may import the product; no product package imports it.

No exception is pinned: no import points against the order and no two product modules
import each other (:func:`test_no_module_cycles`).
"""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
ORDER = ("fdi", "replay", "calibration", "thresholds", "rimu")
"""The layers, lowest first: each package may import the packages before it."""
PRODUCT = ORDER
PACKAGES = (*ORDER, "studies")


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


@pytest.mark.parametrize("package", PRODUCT)
def test_imports_point_one_way(package):
    """Every pair: ``package`` imports no package after it in :data:`ORDER`, nor
    ``studies``."""
    bad = []
    for (src, dst), sites in sorted(EDGES.items()):
        if src == package and not _allowed(src, dst):
            bad += sites
    assert not bad, "imports against fdi ← replay ← calibration ← thresholds ← rimu:\n" + \
        "\n".join(bad)


def test_every_pair_of_packages_is_checked():
    """The rule covers every ordered pair of the five packages and studies, and no two
    packages import each other."""
    pairs = {(a, b) for a in PACKAGES for b in PACKAGES if a != b}
    assert len(pairs) == 30
    both_ways = {frozenset(p) for p in EDGES if p[::-1] in EDGES}
    assert not both_ways, sorted(sorted(p) for p in both_ways)


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


def test_no_module_cycles():
    """No product modules import each other, directly or round a loop (imports inside
    functions counted)."""
    found = _module_cycles()
    assert not found, f"module cycles: {[sorted(c) for c in found]}"


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
