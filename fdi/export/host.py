"""The exported C monitor on the host: compile it, load it (ctypes) and run blocks through it.

For checking a module against :class:`fdi.monitor.Monitor` (rimu's tests and benchmark) and
for running it on one's own recordings. :func:`compile_module` builds a shared library
from a folder written by :func:`fdi.export.write_c` with ``harness=True`` (the module and
``rimu_block.c``) under the strict flags :data:`STRICT_FLAGS`; :class:`CMonitor` loads it
and runs blocks of samples (one C call per block), answering with arrays in the layout of
:class:`fdi.answer.BlockResult` and :class:`fdi.answer.Event` objects whose reasons are
spelled as the Python monitor spells them.
"""

from __future__ import annotations

import ctypes
import math
import shutil
import subprocess
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from fdi.answer import CAPABILITIES, STATUSES, Event
from fdi.envelope import reason_names
from fdi.errors import ExportError

__all__ = ["STRICT_FLAGS", "CMonitor", "CResult", "compile_module", "find_compiler"]

STRICT_FLAGS = ("-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-O2")
"""The flags the module must compile under without a warning."""
EVENT_TYPES = ("detected", "isolated", "disagree", "health", "readmitted", "envelope")
C_STATUSES = (*STATUSES, "untabled")
"""``RIMU_STATUS_*`` by code: fdi's statuses, then 8 ``untabled`` (left out of a set the
module carries no table for)."""


def find_compiler(cc: str = "cc") -> str | None:
    """Path of the C compiler ``cc`` (None when there is none)."""
    return shutil.which(cc)


def compile_module(folder: str | Path, out: str | Path | None = None, *, cc: str = "cc",
                   flags: tuple[str, ...] = STRICT_FLAGS, sources: tuple[str, ...] = (
                       "rimu_monitor.c", "rimu_block.c")) -> Path:
    """Compile the module in ``folder`` into a shared library (``out``, default
    ``folder/librimu_monitor.so``).

    Raises
    ------
    ExportError
        No compiler, or the compiler's first error or warning line.
    """
    d = Path(folder)
    exe = find_compiler(cc)
    if exe is None:
        raise ExportError(f"no C compiler {cc!r} on the PATH")
    lib = Path(out) if out is not None else d / "librimu_monitor.so"
    cmd = [exe, *flags, "-fPIC", "-shared", *(str(d / s) for s in sources), "-o", str(lib),
           "-lm"]
    res = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if res.returncode != 0 or res.stderr.strip():
        first = (res.stderr.strip().splitlines() or ["(no message)"])[0]
        raise ExportError(f"{cc} {' '.join(flags)} on {d}: {first}")
    return lib


def _event_type(real: Any) -> type:
    class Ev(ctypes.Structure):
        _fields_ = [("type", ctypes.c_int), ("sensor", ctypes.c_int),
                    ("reason", ctypes.c_int), ("scale", ctypes.c_int),
                    ("t", ctypes.c_double),
                    ("statistic", real), ("threshold", real), ("magnitude", real),
                    ("sensors", ctypes.c_ulong), ("envelope", ctypes.c_ulong)]
    return Ev


@dataclass(frozen=True)
class CResult:
    """The C module's answers to a block (the fields of :class:`fdi.answer.BlockResult`,
    plus ``status`` (N, n) as strings, ``suspects`` (N,) as bitmasks and ``event_rows``)."""

    t: np.ndarray
    omega: np.ndarray
    omega_sd: np.ndarray
    healthy: np.ndarray
    status: np.ndarray
    parity: np.ndarray
    statistics: np.ndarray
    thresholds: np.ndarray
    capability: np.ndarray
    protection_level: np.ndarray
    envelope: np.ndarray
    unverified: np.ndarray
    suspects: np.ndarray
    events: list[Event]
    event_rows: np.ndarray


class CMonitor:
    """A compiled module loaded with ctypes.

    Parameters
    ----------
    lib : path
        The shared library of :func:`compile_module`.
    sensor_names : sequence of str
        Names of the n sensors (for the reasons of ``disagree`` events).
    """

    def __init__(self, lib: str | Path, sensor_names: tuple[str, ...] | list[str]) -> None:
        self._lib = ctypes.CDLL(str(Path(lib).resolve()))
        self.names = tuple(sensor_names)
        self.n = len(self.names)
        self._lib.rimu_monitor_state_bytes.restype = ctypes.c_ulong
        self._lib.rimu_monitor_table_bytes.restype = ctypes.c_ulong
        self.state_bytes = int(self._lib.rimu_monitor_state_bytes())
        self._lib.rimu_monitor_fingerprint.restype = ctypes.c_char_p
        self.fingerprint = self._lib.rimu_monitor_fingerprint().decode("ascii")
        self.table_bytes = int(self._lib.rimu_monitor_table_bytes())
        self._state = ctypes.create_string_buffer(self.state_bytes + 64)
        self._run = self._lib.rimu_run_block
        self._run.restype = ctypes.c_long
        self.K = self.P = 0
        self._real = ctypes.c_double
        self._ev_type: type | None = None
        self.reset()

    def configure(self, K: int, parity_len: int, float32: bool) -> None:
        """The sizes of this module (from its header: RIMU_K, RIMU_PARITY_LEN, RIMU_FLOAT32)."""
        self.K, self.P = int(K), int(parity_len)
        self._real = ctypes.c_float if float32 else ctypes.c_double
        self._ev_type = _event_type(self._real)

    @classmethod
    def load(cls, folder: str | Path, lib: str | Path, sensor_names: Any) -> CMonitor:
        """Load ``lib`` and read its sizes from ``folder/rimu_monitor.h``."""
        mon = cls(lib, sensor_names)
        head = (Path(folder) / "rimu_monitor.h").read_text(encoding="utf-8")
        val = {}
        for line in head.splitlines():
            parts = line.split()
            if len(parts) >= 3 and parts[0] == "#define":
                val[parts[1]] = parts[2]
        nw, cus = int(val["RIMU_NW"]), int(val["RIMU_HAS_CUSUM"])
        mon.configure(nw + cus, int(val["RIMU_PARITY_LEN"]), val["RIMU_FLOAT32"] == "1")
        return mon

    def reset(self) -> None:
        """Back to the state after ``rimu_monitor_init``."""
        self._lib.rimu_monitor_init(self._state)

    def steps(self, t: Any, raw: Any) -> float:
        """N samples through ``rimu_monitor_step`` (aux NULL), nothing copied out: for timing
        the step itself. Returns the sum of the finite ω̂_x."""
        ta = np.ascontiguousarray(t, float).reshape(-1)
        ra = np.ascontiguousarray(raw, float).reshape(ta.shape[0], self.n)
        f = self._lib.rimu_run_steps
        f.restype = ctypes.c_double
        return float(f(self._state, ctypes.c_long(ta.shape[0]),
                       ta.ctypes.data_as(ctypes.c_void_p), ra.ctypes.data_as(ctypes.c_void_p)))

    def run(self, t: Any, raw: Any, valid: Any = None, *, force: Any = None,
            temperature: Any = None, envelope: Any = None) -> CResult:
        """N samples through ``rimu_monitor_step``.

        Parameters
        ----------
        t : array_like, shape (N,)
        raw : array_like, shape (N, n)
        valid : array_like of bool, shape (N, n), optional
        force : array_like, shape (N, 3) or (N, n, 3), optional
            Specific force (m/s²), one vector per sample or one per sensor.
        temperature : array_like, shape (N,) or (N, n), optional
        envelope : array_like of int, shape (N,), optional
        """
        n, K, P = self.n, self.K, self.P
        ta = np.ascontiguousarray(t, float).reshape(-1)
        N = ta.shape[0]
        ra = np.ascontiguousarray(raw, float).reshape(N, n)
        va = None if valid is None else np.ascontiguousarray(valid, bool).reshape(N, n)
        fa = None
        if force is not None:
            f = np.asarray(force, float)
            fa = np.ascontiguousarray(np.broadcast_to(f[:, None, :] if f.ndim == 2 else f,
                                                      (N, n, 3)))
        ta_ = None
        if temperature is not None:
            T = np.asarray(temperature, float)
            ta_ = np.ascontiguousarray(np.broadcast_to(T[:, None] if T.ndim == 1 else T,
                                                       (N, n)))
        ea = None if envelope is None else np.ascontiguousarray(envelope, np.int64)
        out = {"omega": np.empty((N, 3)), "omega_sd": np.empty((N, 3)),
               "healthy": np.empty((N, n), np.uint8), "status": np.empty((N, n), np.uint8),
               "parity": np.empty((N, P)), "statistics": np.empty((N, K)),
               "thresholds": np.empty((N, K)), "cap": np.empty(N, np.intc),
               "pl": np.empty(N), "envelope": np.empty(N, np.int64),
               "unverified": np.empty((N, 3), np.uint8), "suspects": np.empty(N, np.uint64)}
        max_ev = 4 * N + 64
        evs = (self._ev_type * max_ev)()
        rows = np.empty(max_ev, np.int64)

        def ptr(a: np.ndarray | None) -> Any:
            return None if a is None else a.ctypes.data_as(ctypes.c_void_p)

        count = self._run(self._state, ctypes.c_long(N), ptr(ta), ptr(ra),
                          ptr(None if va is None else va.view(np.uint8)), ptr(fa), ptr(ta_),
                          ptr(ea), ptr(out["omega"]), ptr(out["omega_sd"]),
                          ptr(out["healthy"]), ptr(out["status"]), ptr(out["parity"]),
                          ptr(out["statistics"]), ptr(out["thresholds"]), ptr(out["cap"]),
                          ptr(out["pl"]), ptr(out["envelope"]), ptr(out["unverified"]),
                          ptr(out["suspects"]), evs, ctypes.c_long(max_ev), ptr(rows))
        if count > max_ev:
            raise ExportError(f"{count} events in {N} samples: more than the {max_ev} kept")
        events = [self._event(evs[k]) for k in range(count)]
        status = np.array(C_STATUSES, dtype=object)[out["status"]]
        return CResult(t=ta, omega=out["omega"], omega_sd=out["omega_sd"],
                       healthy=out["healthy"].astype(bool), status=status,
                       parity=out["parity"], statistics=out["statistics"],
                       thresholds=out["thresholds"],
                       capability=np.array(CAPABILITIES, dtype=object)[out["cap"]],
                       protection_level=out["pl"], envelope=out["envelope"],
                       unverified=out["unverified"].astype(bool), suspects=out["suspects"],
                       events=events, event_rows=rows[:count].copy())

    def _event(self, e: Any) -> Event:
        """A C event as the Python monitor writes it."""
        typ = EVENT_TYPES[e.type]
        sensors = tuple(i + 1 for i in range(self.n) if (e.sensors >> i) & 1)
        reason = self._reason(e, sensors)

        def num(x: float) -> float:
            return float(x)

        mag = float(e.magnitude)
        return Event(float(e.t), e.sensor or None, typ, reason, num(e.statistic),
                     num(e.threshold), e.scale or None, None if math.isnan(mag) else mag,
                     sensors, int(e.envelope))

    def _reason(self, e: Any, sensors: tuple[int, ...]) -> str:
        names = [self.names[i - 1] for i in sensors]
        r = e.reason
        if r == 0:
            return f"parity scale {e.scale}"
        fixed = {1: "cusum", 2: "range", 3: "nonfinite", 4: "stuck", 5: "stale", 6: "dwell",
                 8: "in"}
        if r in fixed:
            return fixed[r]
        if r == 7:
            return "+".join(reason_names(int(e.envelope)))
        if r == 11:
            return "no single-sensor fault explains the parity: " + _join(names) + \
                " unverified"
        if r == 9:
            return _join(names) + " disagree: cannot tell which"
        return _join(names) + ": suspected (this set cannot isolate)"


def _join(names: list[str]) -> str:
    if not names:
        return ""
    return names[0] if len(names) == 1 else ", ".join(names[:-1]) + " and " + names[-1]
