"""The import direction the README and docs/architecture.md state, read from the sources.

``fdi`` imports nothing else of rimu; no package imports the command line (``rimu``);
``calibration`` does not import ``thresholds``. Every ``import`` and ``from … import`` in
every module is checked, including those inside functions.
"""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("fdi", "calibration", "thresholds", "replay", "rimu")
FORBIDDEN = {
    "fdi": {"calibration", "thresholds", "replay", "rimu"},
    "calibration": {"thresholds", "rimu"},
    "thresholds": {"rimu"},
    "replay": {"rimu"},
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
