"""No module of ``replay`` uses another module's private names (``_name``), read from the sources.

Checked: ``from m import _name`` of any rimu package, and ``name._attr`` where ``name`` was
bound by an import (a module or anything imported from one), inside functions too.
"""

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("fdi", "calibration", "thresholds", "replay", "rimu")


def _private(name: str) -> bool:
    return name.startswith("_") and not name.startswith("__")


def _uses(path: Path) -> list[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    imported: set[str] = set()
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            imported |= {(a.asname or a.name).split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            internal = node.level > 0 or (node.module or "").split(".")[0] in PACKAGES
            for a in node.names:
                imported.add(a.asname or a.name)
                if internal and _private(a.name):
                    out.append(f"{node.lineno}: from {node.module} import {a.name}")
    for node in ast.walk(tree):
        if (isinstance(node, ast.Attribute) and _private(node.attr)
                and isinstance(node.value, ast.Name) and node.value.id in imported):
            out.append(f"{node.lineno}: {node.value.id}.{node.attr}")
    return out


def test_the_check_sees_both_forms(tmp_path):
    p = tmp_path / "m.py"
    p.write_text("from replay.logio import _norm_channel\nimport replay.assemble as a\n"
                 "def f():\n    return a._Rows, _norm_channel\n")
    assert _uses(p) == ["1: from replay.logio import _norm_channel", "4: a._Rows"]


def test_no_replay_module_uses_private_names_of_another():
    bad = [f"{p.relative_to(ROOT)}:{u}" for p in sorted((ROOT / "replay").rglob("*.py"))
           for u in _uses(p)]
    assert not bad, "\n".join(bad)
