"""Build the API reference (HTML) from the docstrings with pdoc: every module of the five
product packages, private ones (``_name``) left out.

Run from the clone's root (pdoc is in the ``dev`` extra)::

    python docs/build_api.py                 # writes build/api/index.html
    python docs/build_api.py --out DIR

``tests/test_docs.py`` builds it (slow) and checks that every public module has its page.
"""

from __future__ import annotations

import argparse
import pkgutil
import sys
import warnings
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("fdi", "calibration", "thresholds", "replay", "rimu")
"""The product packages (``[tool.setuptools.packages.find]`` of pyproject.toml)."""


def public_modules(root: Path = ROOT) -> list[str]:
    """Dotted names of every module of :data:`PACKAGES` whose path has no ``_name`` part."""
    out = []
    for pkg in PACKAGES:
        out.append(pkg)
        for info in pkgutil.walk_packages([str(root / pkg)], prefix=f"{pkg}."):
            if not any(part.startswith("_") for part in info.name.split(".")):
                out.append(info.name)
    return sorted(out)


def build(out: Path, modules: list[str] | None = None) -> list[str]:
    """Write the HTML reference of ``modules`` (default: :func:`public_modules`) to ``out``;
    return the module names documented."""
    import pdoc
    import pdoc.render

    modules = public_modules() if modules is None else modules
    pdoc.render.configure(docformat="numpy", search=True, show_source=False)
    with warnings.catch_warnings():     # a package's __all__ names a module also listed
        warnings.filterwarnings("ignore", message=".*has already been added")
        pdoc.pdoc(*modules, output_directory=Path(out))
    return modules


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "build" / "api",
                    help="output folder (default: build/api)")
    args = ap.parse_args(argv)
    if str(ROOT) not in sys.path:
        sys.path.insert(0, str(ROOT))
    mods = build(args.out)
    print(f"wrote {len(mods)} modules to {args.out}/index.html")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
