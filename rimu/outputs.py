"""Output paths of the CLI: checked before any work, written atomically.

Every command checks its output paths right after parsing (:func:`output_file`,
:func:`output_dir`) and its input paths (:func:`input_path`), so that a typo costs no
computation and gives one line naming the option. Before any command runs,
:func:`refuse_outputs_over_inputs` (called by :func:`rimu.cli.main`) refuses an output
option (:data:`OUTPUT_OPTIONS`) whose path is, or lies inside, any path the command was
given as input: no command writes over or into what it reads. Files are then written through
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

__all__ = ["FLIGHT_LOG_SUFFIXES", "OUTPUT_OPTIONS", "atomic_dir", "atomic_file",
           "atomic_write_text", "distinct_inputs", "flight_folder_hint", "input_path",
           "output_dir", "output_file", "refuse_outputs_over_inputs"]

FLIGHT_LOG_SUFFIXES = (".bin", ".ulg", ".mat", ".rda", ".rdata", ".csv")
"""Log files ``rimu ingest`` turns into flight folders (a hint when one is given instead)."""
CAN_LOG_SUFFIXES = (".asc", ".blf", ".log", ".trc")
"""CAN logs (read by ``rimu replay``)."""


def _same(a: Path, b: Path) -> bool:
    try:
        return a.resolve() == b.resolve() or (a.exists() and b.exists() and os.path.samefile(a, b))
    except OSError:
        return False


def _inside(p: Path, q: Path) -> bool:
    """Whether ``p`` is the directory ``q`` or lies somewhere inside it (links resolved)."""
    try:
        pr, qr = p.resolve(), q.resolve()
    except (OSError, RuntimeError):
        return False
    if not qr.is_dir():
        return False
    return qr == pr or qr in pr.parents or any(
        a.exists() and os.path.samefile(a, qr) for a in (pr, *pr.parents))


def _not_an_input(p: Path, option: str, inputs) -> None:
    """Refuse an output that is one of the command's inputs or lies inside one."""
    for q in inputs or ():
        if q is None or str(q) == "":
            continue
        q = Path(q)
        if _same(p, q):
            raise ConfigError(f"{option} {p}: is an input of this command ({q}); writing it "
                              "would replace what is being read: give another path")
        if _inside(p, q):
            raise ConfigError(f"{option} {p}: lies inside the input folder {q}; writing "
                              "there would change what is being read: give a path outside it")


OUTPUT_OPTIONS = ("out", "report", "plot", "rrd")
"""Argument names (``args.<name>``) through which a command writes; every other argument
that names an existing file or folder is an input."""


_OUTPUT_SUFFIXES = ("_plot", "_report", "_rrd", "_out")
"""Argument names ending so are outputs too (``--baseline-plot``)."""


def _paths(value) -> list[Path]:
    if isinstance(value, str | os.PathLike):
        return [Path(value)] if str(value) else []
    if isinstance(value, list | tuple):
        return [p for v in value for p in _paths(v)]
    return []


def refuse_outputs_over_inputs(args, outputs: tuple[str, ...] = OUTPUT_OPTIONS) -> None:
    """Refuse any output of a parsed command line that is, or lies inside, an input.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed arguments. Inputs are the values (strings, paths, lists of them) of every
        argument not in ``outputs`` that name an existing file or directory.
    outputs : tuple of str
        The argument names that are written.

    Raises
    ------
    ConfigError
        One line naming the output option, its path and the input it would change.
    """
    ns = vars(args)
    ins = [q for k, v in ns.items() if k not in outputs and not k.startswith("_")
           and not k.endswith(_OUTPUT_SUFFIXES)
           for q in _paths(v) if _exists(q)]
    for k in [k for k in ns if k in outputs or k.endswith(_OUTPUT_SUFFIXES)]:
        for p in _paths(ns.get(k)):
            _not_an_input(p, "--" + k.replace("_", "-"), ins)


def _exists(q: Path) -> bool:
    try:
        return q.exists()
    except OSError:
        return False


def _nearest_existing(p: Path) -> Path:
    q = p
    while not q.exists() and q != q.parent:
        q = q.parent
    return q


def output_file(path: str | os.PathLike, option: str, *, inputs=()) -> Path:
    """Check that ``path`` can be written as a file (it may exist and is then replaced).

    ``inputs`` are the command's input paths (None entries skipped): the output may be
    none of them.

    Raises
    ------
    ConfigError
        ``path`` is a directory, its directory does not exist or is not writable, or it is
        one of ``inputs``.
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
    _not_an_input(p, option, inputs)
    return p


def output_dir(path: str | os.PathLike, option: str, *, inputs=(),
               schema: str | None = None) -> Path:
    """Check that ``path`` can be used as an output directory (created when missing).

    ``inputs``: the command's input paths; the folder may be none of them. ``schema``: the
    ``rimu.xxx/`` family the command writes into ``manifest.json``; an existing folder
    whose manifest is of another kind (a session where a flight is written) is refused
    instead of mixed.

    Raises
    ------
    ConfigError
        ``path`` is an existing file, its nearest existing ancestor is not a writable
        directory, it is an input, or it holds another kind of folder.
    """
    p = Path(path)
    if str(path) == "":
        raise ConfigError(f"{option}: expected a directory name")
    _not_an_input(p, option, inputs)
    if p.exists():
        if not p.is_dir():
            raise ConfigError(f"{option} {p}: is a file, expected a directory")
        if not os.access(p, os.W_OK | os.X_OK):
            raise ConfigError(f"{option} {p}: directory is not writable")
        if schema is not None and (p / "manifest.json").is_file():
            from fdi.errors import FileFormatError
            from fdi.fileio import read_json_object

            try:
                got = str(read_json_object(p / "manifest.json").get("schema", ""))
            except FileFormatError:
                got = "?"
            if not got.startswith(schema.split("/")[0] + "/"):
                raise ConfigError(f"{option} {p}: holds a {got} folder, not a "
                                  f"{schema.split('/')[0]} one: give a new or empty folder")
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


def distinct_inputs(paths, option: str) -> None:
    """Refuse the same input given twice (``rimu repeat S S``), one line naming it."""
    seen: list[Path] = []
    for x in paths:
        q = Path(x)
        for r in seen:
            if _same(q, r):
                raise ConfigError(f"{option} {q}: given twice ({r}); give different inputs")
        seen.append(q)


def _umask() -> int:
    m = os.umask(0)
    os.umask(m)
    return m


def flight_folder_hint(path: str | os.PathLike, option: str, command: str) -> None:
    """A log file given where a flight folder is read: name the command that reads it."""
    p = Path(path)
    if p.is_dir():
        return
    sfx = p.suffix.lower()
    if sfx in CAN_LOG_SUFFIXES:
        raise ConfigError(f"{option} {p}: is a CAN log, not a flight folder; {command} reads "
                          f"folders: use rimu replay {p} --cal CAL")
    if sfx in FLIGHT_LOG_SUFFIXES:
        raise ConfigError(f"{option} {p}: is a log file, not a flight folder; make one "
                          f"first: rimu ingest {p} --out FOLDER")


def _temp_name(p: Path) -> Path:
    # keep the suffix: writers pick their format by it (python-can, rerun)
    fd, name = tempfile.mkstemp(prefix=f".{p.stem}.", suffix=f".part{''.join(p.suffixes)}",
                                dir=p.parent if str(p.parent) else ".")
    os.close(fd)
    # mkstemp makes 0600 files; a written file gets the mode open() would give it
    os.chmod(name, 0o666 & ~_umask())
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
        if p.exists():          # replacing a file keeps its mode
            with contextlib.suppress(OSError):
                os.chmod(tmp, p.stat().st_mode & 0o7777)
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
