"""Each built-in effect's name is written in one product module, its spec
(:mod:`fdi.effect_specs.builtin`): every other module reads names, units and forms from the
specs, so adding or renaming an effect touches one module (docs/effects.md).

Walks the product packages' ``.py`` files with :mod:`ast` and collects the string constants
equal to a built-in effect's name (docstrings and f-string fragments are other constants).
"""

from __future__ import annotations

import ast
from collections import defaultdict
from functools import lru_cache
from pathlib import Path

from fdi.effect_specs import builtin_names

ROOT = Path(__file__).resolve().parents[1]
PRODUCT = ("fdi", "calibration", "replay", "thresholds", "rimu")
SPEC_MODULE = "fdi/effect_specs/builtin.py"

HOMONYMS = {
    "temperature": "also the run-time input and the auxiliary channel kind (a °C stream)",
    "misalignment": "also the calibration's axis-misalignment parameter (sd factor key)",
}
"""Built-in names that are also the word for another concept: allowed outside the spec,
but not in the modules that consume the effects (:data:`CONSUMERS`)."""
CONSUMERS = ("fdi/effects.py", "fdi/effects_monitor.py", "fdi/export/c.py",
             "calibration/effects.py", "calibration/simulate.py", "calibration/compare.py",
             "calibration/diagnose/", "rimu/commands/calibrate_effects.py",
             "rimu/commands/diagnose_flight.py")
"""Modules (or folders) that use effects and so must read their names from the specs."""
def effect_name_strings(root: Path, names: tuple[str, ...]) -> dict[str, dict[str, list[int]]]:
    """name → module (relative path) → line numbers of string constants equal to it."""
    hits: dict[str, dict[str, list[int]]] = defaultdict(lambda: defaultdict(list))
    for pkg in PRODUCT:
        for path in sorted((root / pkg).rglob("*.py")):
            tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
            rel = path.relative_to(root).as_posix()
            for node in ast.walk(tree):
                if isinstance(node, ast.Constant) and node.value in names:
                    hits[node.value][rel].append(node.lineno)
    return hits


@lru_cache(maxsize=1)
def _product_hits() -> dict[str, dict[str, list[int]]]:
    return effect_name_strings(ROOT, builtin_names())


def violations(hits: dict[str, dict[str, list[int]]], names: tuple[str, ...]) -> list[str]:
    """What breaks "one module per name", one line each."""
    out = []
    for name in names:
        modules = set(hits.get(name, {}))
        if SPEC_MODULE not in modules:
            out.append(f"{name}: not in {SPEC_MODULE}")
        for m in sorted(modules - {SPEC_MODULE}):
            if name in HOMONYMS and not m.startswith(CONSUMERS):
                continue
            out.append(f"{name}: also in {m} (lines {hits[name][m]})")
    return out


def test_each_builtin_effect_name_is_written_in_one_module() -> None:
    names = builtin_names()
    assert names
    bad = violations(_product_hits(), names)
    assert not bad, "\n".join(bad)


def test_the_exceptions_are_still_needed() -> None:
    hits = _product_hits()
    for name in HOMONYMS:
        assert set(hits[name]) - {SPEC_MODULE}, name


def test_the_check_sees_a_name_written_twice(tmp_path: Path) -> None:
    """The check can fail: a consumer that writes an effect's name is reported."""
    for rel, text in ((SPEC_MODULE, 'A = "warmup"\nB = "temperature"\n'),
                      ("calibration/simulate.py", 'X = {"warmup": 1}\n'),
                      ("calibration/diagnose/x.py", 'T = "temperature"\n'),
                      ("replay/aux.py", 'K = "temperature"\n')):
        p = tmp_path / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(text, encoding="utf-8")
    names = ("warmup", "temperature")
    bad = violations(effect_name_strings(tmp_path, names), names)
    assert bad == ["warmup: also in calibration/simulate.py (lines [1])",
                   "temperature: also in calibration/diagnose/x.py (lines [1])"]
