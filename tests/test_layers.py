"""The import direction the README and docs/architecture.md state, read from the sources.

``fdi`` imports nothing else of rimu; no package imports the command line (``rimu``);
``calibration`` does not import ``thresholds``; no product package imports ``studies`` (the
evidence and the tests' simulated truth, which the wheel does not install). Every ``import``
and ``from … import`` in every module is checked, including those inside functions.
"""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("fdi", "calibration", "thresholds", "replay", "rimu", "studies")
PRODUCT = ("fdi", "calibration", "thresholds", "replay", "rimu")
FORBIDDEN = {
    "fdi": {"calibration", "thresholds", "replay", "rimu", "studies"},
    "calibration": {"thresholds", "rimu", "studies"},
    "thresholds": {"rimu", "studies"},
    "replay": {"rimu", "studies"},
    "rimu": {"studies"},
}


def _imported_packages(path: Path) -> set[tuple[str, int]]:
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out |= {(a.name.split(".")[0], node.lineno) for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            out.add((node.module.split(".")[0], node.lineno))
    return {(m, ln) for m, ln in out if m in PACKAGES}


@pytest.mark.parametrize("package", sorted(FORBIDDEN))
def test_imports_point_one_way(package):
    bad = []
    for path in sorted((ROOT / package).rglob("*.py")):
        for mod, line in _imported_packages(path):
            if mod in FORBIDDEN[package]:
                bad.append(f"{path.relative_to(ROOT)}:{line} imports {mod}")
    assert not bad, "\n".join(bad)


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
