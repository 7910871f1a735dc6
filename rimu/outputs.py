"""Output paths of the CLI: checked before any work, written atomically.

Every command checks its output paths right after parsing (:func:`output_file`,
:func:`output_dir`) and its input paths (:func:`input_path`), so that a typo costs no
computation and gives one line naming the option. Files are then written through
:func:`atomic_file` (a temporary file beside the target, renamed over it with
``os.replace`` once complete) and directories through :func:`atomic_dir` (a temporary
directory beside the target, whose files are renamed into it once all are written): a
failure part-way leaves neither a half-written file nor a temporary one behind.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

from fdi.errors import ConfigError

__all__ = ["atomic_dir", "atomic_file", "atomic_write_text", "input_path", "output_dir",
           "output_file"]


def _nearest_existing(p: Path) -> Path:
    q = p
    while not q.exists() and q != q.parent:
        q = q.parent
    return q


def output_file(path: str | os.PathLike, option: str) -> Path:
    """Check that ``path`` can be written as a file (it may exist and is then replaced).

    Raises
    ------
    ConfigError
        ``path`` is a directory, its directory does not exist or is not writable.
    """
    p = Path(path)
    if str(path) == "" or p.name in ("", ".", ".."):
        raise ConfigError(f"{option} {str(path)!r}: expected a file name")
    if p.is_dir():
        raise ConfigError(f"{option} {p}: is a directory, expected a file name")
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        what = "is not a directory" if parent.exists() else "does not exist"
        raise ConfigError(f"{option} {p}: directory {parent} {what}")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise ConfigError(f"{option} {p}: directory {parent} is not writable")
    if p.exists() and not os.access(p, os.W_OK):
        raise ConfigError(f"{option} {p}: file exists and is not writable")
    return p


def output_dir(path: str | os.PathLike, option: str) -> Path:
    """Check that ``path`` can be used as an output directory (created when missing).

    Raises
    ------
    ConfigError
        ``path`` is an existing file, or its nearest existing ancestor is not a writable
        directory.
    """
    p = Path(path)
    if str(path) == "":
        raise ConfigError(f"{option}: expected a directory name")
    if p.exists():
        if not p.is_dir():
            raise ConfigError(f"{option} {p}: is a file, expected a directory")
        if not os.access(p, os.W_OK | os.X_OK):
            raise ConfigError(f"{option} {p}: directory is not writable")
        return p
    q = _nearest_existing(p.absolute().parent)
    if not q.is_dir():
        raise ConfigError(f"{option} {p}: {q} is a file, not a directory")
    if not os.access(q, os.W_OK | os.X_OK):
        raise ConfigError(f"{option} {p}: directory {q} is not writable")
    return p


def input_path(path: str | os.PathLike, option: str, *, kind: str = "file") -> Path:
    """Check that an input exists (``kind``: ``"file"``, ``"dir"`` or ``"any"``)."""
    p = Path(path)
    if not p.exists():
        raise ConfigError(f"{option} {p}: no such {'directory' if kind == 'dir' else 'file'}")
    if kind == "file" and not p.is_file():
        raise ConfigError(f"{option} {p}: is a directory, expected a file")
    if kind == "dir" and not p.is_dir():
        raise ConfigError(f"{option} {p}: is a file, expected a directory")
    return p


def _temp_name(p: Path) -> Path:
    # keep the suffix: writers pick their format by it (python-can, rerun)
    fd, name = tempfile.mkstemp(prefix=f".{p.stem}.", suffix=f".part{''.join(p.suffixes)}",
                                dir=p.parent if str(p.parent) else ".")
    os.close(fd)
    return Path(name)


@contextlib.contextmanager
def atomic_file(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it over ``path`` on success.

    On an exception the temporary file is removed and ``path`` is left as it was.
    """
    p = Path(path)
    tmp = _temp_name(p)
    try:
        yield tmp
        if not tmp.exists():
            raise ConfigError(f"{p}: nothing was written")
        os.replace(tmp, p)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


def atomic_write_text(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    p = Path(path)
    with atomic_file(p) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return p


@contextlib.contextmanager
def atomic_dir(path: str | os.PathLike, *, inside: bool = False) -> Iterator[Path]:
    """Yield a temporary directory beside ``path``; move its files into ``path`` on success.

    With ``inside`` the temporary directory is made in ``path`` itself (for a group of
    files written side by side in an existing directory, e.g. a log and its sidecars).

    ``path`` is created when missing (with its parents); files already in it that the
    command also writes are replaced, others are kept. On an exception the temporary
    directory is removed, and a ``path`` this call created is removed again.
    """
    p = Path(path)
    created = []
    q = p
    while not q.exists():
        created.append(q)
        q = q.parent
    p.mkdir(parents=True, exist_ok=True)
    where = p if inside else p.parent
    tmp = Path(tempfile.mkdtemp(prefix=f".{p.name}.", suffix=".part", dir=where))
    try:
        yield tmp
        for src in sorted(tmp.rglob("*")):
            dst = p / src.relative_to(tmp)
            if src.is_dir():
                dst.mkdir(exist_ok=True)
            else:
                os.replace(src, dst)
        shutil.rmtree(tmp)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        for d in created:       # deepest first
            with contextlib.suppress(OSError):
                d.rmdir()
        raise
