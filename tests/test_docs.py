"""The house a newcomer enters: the README is a door (short, the set-up commands first, a
Python example that runs), every page of docs/ is reachable from docs/index.md, the
licence pyproject names is there, the package docstrings name the imports that exist, and
the API reference builds from the docstrings."""

from __future__ import annotations

import ast
import os
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
PACKAGES = ("fdi", "calibration", "thresholds", "replay", "rimu")
SETUP = ('python3 -m venv .venv && . .venv/bin/activate && python3 -m pip install -e ".[dev]"'
         " && ")
DEMO = SETUP + "rimu demo"
TESTS = SETUP + "python3 -m pytest -n auto"


def _readme_lines() -> list[str]:
    return README.read_text(encoding="utf-8").splitlines()


def _python_blocks(text: str) -> list[str]:
    return re.findall(r"^```python\n(.*?)^```", text, flags=re.M | re.S)


def test_readme_is_short_with_both_set_up_commands_first():
    lines = _readme_lines()
    assert len(lines) <= 200, f"README.md has {len(lines)} lines (at most 200)"
    first = [s.strip() for s in lines[:40]]
    assert DEMO in first and TESTS in first


def test_ci_runs_the_readme_test_command():
    """.ci/run installs the dev extra editable and runs pytest with one worker per core, as
    the README's second command does (-q only shortens its output; the same options)."""
    run = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    assert re.search(r'pip install .*-e "\.\[dev\]"', run)
    line = next(s for s in run.splitlines() if "-m pytest" in s and not s.startswith("#"))
    readme = TESTS.split("python3 -m pytest", 1)[1].split()
    assert sorted(o for o in line.split("-m pytest", 1)[1].split() if o != "-q") == sorted(readme)


def test_readme_python_example_runs(tmp_path):
    """The README's Python block, run as it stands in a fresh process: gyro 3's 8σ step is
    detected and isolated, and the last answer excludes gyro 3 only."""
    blocks = _python_blocks(README.read_text(encoding="utf-8"))
    assert len(blocks) == 1, "README.md holds one Python example"
    code = blocks[0]
    assert len(code.splitlines()) <= 25
    script = tmp_path / "example.py"
    script.write_text(code, encoding="utf-8")
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    p = subprocess.run([sys.executable, str(script)], cwd=tmp_path, env=env,
                       capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr[-3000:]
    out = p.stdout
    assert re.search(r"sensor 3\s+isolated", out), out
    assert "healthy at the end: [ True  True False  True  True  True]" in out, out


def test_docs_index_links_every_page():
    index = ROOT / "docs" / "index.md"
    text = index.read_text(encoding="utf-8")
    targets = set(re.findall(r"\]\(([^)#\s]+)\)", text))
    for t in targets:
        assert (index.parent / t).exists(), f"docs/index.md links {t}, which does not exist"
    pages = {p.name for p in (ROOT / "docs").glob("*.md")} - {"index.md"}
    unlinked = sorted(pages - targets)
    assert not unlinked, f"not linked from docs/index.md (add a line there): {unlinked}"
    assert "index.md" in {Path(t).name for t in re.findall(r"\]\(([^)#\s]+)\)",
                                                             README.read_text("utf-8"))}


def test_licence_is_the_one_pyproject_names():
    conf = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    assert conf["project"]["license"] == {"text": "MIT"}
    text = (ROOT / "LICENSE").read_text(encoding="utf-8")
    assert text.startswith("MIT License") and "WITHOUT WARRANTY OF ANY KIND" in text


def test_docstrings_name_imports_that_exist():
    """No ``rimu.fdi`` / ``rimu.calibration`` / ... as a module name in the product (the
    packages import as ``fdi``, ``calibration``, ...): only file kinds such as
    ``rimu.calibration/3`` or ``a rimu.thresholds file`` may carry that prefix."""
    bad = []
    pat = re.compile(r"rimu\.(fdi|calibration|thresholds|replay)\b(?![/\w])(?! (or|file))")
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            tree = ast.parse(path.read_text(encoding="utf-8"))
            for node in ast.walk(tree):
                if isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef):
                    doc = ast.get_docstring(node) or ""
                    if pat.search(doc):
                        bad.append(f"{path.relative_to(ROOT)}: {pat.search(doc).group(0)}")
    assert not bad, "\n".join(bad)
    import importlib.util

    for pkg in PACKAGES[:-1]:
        assert importlib.util.find_spec(pkg) is not None


@pytest.mark.slow
def test_api_reference_builds(tmp_path):
    """``python docs/build_api.py`` (pdoc, the dev extra) writes one page per public module
    of the five packages, from their docstrings."""
    sys.path.insert(0, str(ROOT / "docs"))
    try:
        import build_api
    finally:
        sys.path.remove(str(ROOT / "docs"))
    out = tmp_path / "api"
    p = subprocess.run([sys.executable, str(ROOT / "docs" / "build_api.py"), "--out",
                        str(out)], cwd=ROOT, capture_output=True, text=True, timeout=900)
    assert p.returncode == 0, p.stderr[-3000:]
    mods = build_api.public_modules()
    assert {m.split(".")[0] for m in mods} == set(PACKAGES) and len(mods) > 100
    missing = [m for m in mods if not (out / (m.replace(".", "/") + ".html")).exists()]
    assert not missing, missing
    page = (out / "fdi" / "monitor.html").read_text(encoding="utf-8")
    assert "bit-identical to" in page and "BlockResult" in page
    assert (out / "index.html").exists()
