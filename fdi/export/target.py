"""The exported C monitor on a Cortex-M4F: cross-compile it and run it under QEMU.

For checking a module on the target ISA (rimu's tests and benchmark). :func:`build_target`
writes ``rimu_target.c`` (a bare-metal program: vector table, reset handler, semihosting
output; template ``templates/rimu_target.c.in``), its linker script for QEMU's
``mps2-an386`` board and the samples as const arrays (``rimu_target_input.h``) beside a
module written by :func:`fdi.export.write_c`, and links them with
``arm-none-eabi-gcc`` (:data:`ARM_FLAGS`; newlib's libm for ``sqrt``); :func:`run_target`
runs the program under ``qemu-system-arm -M mps2-an386 -icount shift=0`` with semihosting
and reads back every answer bit for bit (a :class:`fdi.export.host.CResult`) with the
instructions per step and the stack high-water.

The toolchain is Debian's ``gcc-arm-none-eabi``, ``libnewlib-arm-none-eabi`` and
``qemu-system-arm``; :func:`find_toolchain` says which part is missing.
"""

from __future__ import annotations

import shutil
import subprocess
import types
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from fdi.answer import CAPABILITIES
from fdi.errors import ExportError
from fdi.export.c import _template, _version
from fdi.export.host import C_STATUSES, CMonitor, CResult

__all__ = ["ARM_FLAGS", "QEMU", "TICK_INSTRUCTIONS", "TargetRun", "build_target",
           "find_toolchain", "run_target"]

ARM_FLAGS = ("-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-O2",
             "-mcpu=cortex-m4", "-mthumb", "-mfloat-abi=hard", "-mfpu=fpv4-sp-d16")
"""The flags the module is built with for the Cortex-M4F (warning-free, as on the host)."""
QEMU = ("qemu-system-arm", "-M", "mps2-an386", "-cpu", "cortex-m4", "-nographic",
        "-monitor", "none", "-serial", "none", "-semihosting-config",
        "enable=on,target=native", "-icount", "shift=0")
"""QEMU's command (then ``-kernel ELF``): one instruction per virtual nanosecond."""
TICK_INSTRUCTIONS = 40
"""Instructions per SysTick tick: the mps2-an386 processor clock is 25 MHz (40 ns), and
``-icount shift=0`` advances the virtual clock 1 ns per instruction."""
TOOLS = ("arm-none-eabi-gcc", "qemu-system-arm")


def find_toolchain() -> str | None:
    """None when the cross compiler, newlib and QEMU are all there; else what is missing
    (a reason for a skip)."""
    missing = [t for t in TOOLS if shutil.which(t) is None]
    if missing:
        return (f"{', '.join(missing)} not on the PATH (Debian: apt-get install "
                f"gcc-arm-none-eabi libnewlib-arm-none-eabi qemu-system-arm)")
    gcc = shutil.which("arm-none-eabi-gcc")
    res = subprocess.run([gcc, "-mcpu=cortex-m4", "-mthumb", "-mfloat-abi=hard",
                          "-mfpu=fpv4-sp-d16", "-print-file-name=libm.a"],
                         capture_output=True, text=True, check=False)
    if res.returncode != 0 or not Path(res.stdout.strip()).is_file():
        return "newlib's libm.a for the Cortex-M4F not found (libnewlib-arm-none-eabi)"
    return None


def _c_double(x: float) -> str:
    x = float(x)
    if np.isnan(x):
        return "NAN"
    if np.isinf(x):
        return "INFINITY" if x > 0 else "-INFINITY"
    return repr(x)


def build_target(folder: str | Path, t: Any, raw: Any, valid: Any = None,
                 envelope: Any = None) -> Path:
    """Cross-compile the module in ``folder`` with a program that runs the samples
    ``t`` (N,), ``raw`` (N, n), ``valid`` (N, n) and ``envelope`` (N,); returns the ELF.

    Raises
    ------
    ExportError
        The toolchain missing, or the compiler's first error or warning line.
    """
    why = find_toolchain()
    if why:
        raise ExportError(why)
    d = Path(folder)
    ta = np.asarray(t, float).reshape(-1)
    N = ta.shape[0]
    ra = np.asarray(raw, float).reshape(N, -1)
    n = ra.shape[1]
    va = np.ones((N, n), bool) if valid is None else np.asarray(valid, bool).reshape(N, n)
    env = np.zeros(N, np.int64) if envelope is None else np.asarray(envelope, np.int64)
    env = np.where((env > 0) & (env < 1 << 32), env, 0)
    lines = ["/* samples for rimu_target.c (generated) */", "#include <math.h>",
             f"#define RIMU_T_N {N}L",
             f"static const double T_IN[{N}] = {{{', '.join(map(_c_double, ta))}}};",
             f"static const double RAW_IN[{N}][{n}] = {{"]
    lines += ["    {" + ", ".join(map(_c_double, row)) + "}," for row in ra]
    lines += ["};", f"static const unsigned char VALID_IN[{N}][{n}] = {{"]
    lines += ["    {" + ", ".join("1" if v else "0" for v in row) + "}," for row in va]
    lines += ["};", f"static const unsigned long ENV_IN[{N}] = "
              f"{{{', '.join(f'{int(v)}UL' for v in env)}}};", ""]
    (d / "rimu_target_input.h").write_text("\n".join(lines), encoding="utf-8")
    fill = {"VERSION": _version()}
    for name in ("rimu_target.c", "rimu_target.ld"):
        text = _template(name + ".in")
        for k, v in fill.items():
            text = text.replace(f"@@{k}@@", v)
        (d / name).write_text(text, encoding="utf-8")
    gcc = shutil.which("arm-none-eabi-gcc")
    elf = d / "rimu_target.elf"
    steps = [[gcc, *ARM_FLAGS, "-Wdouble-promotion", "-c", str(d / "rimu_monitor.c"), "-o",
              str(d / "rimu_monitor.arm.o")],
             # the program (not the module): GNU asm and a vector table, so no -pedantic
             [gcc, *(f for f in ARM_FLAGS if f != "-pedantic"), "-c", str(d / "rimu_target.c"),
              "-o", str(d / "rimu_target.arm.o")],
             [gcc, *ARM_FLAGS, "-nostartfiles", "--specs=nano.specs", "-T",
              str(d / "rimu_target.ld"), str(d / "rimu_target.arm.o"),
              str(d / "rimu_monitor.arm.o"), "-lm", "-o", str(elf)]]
    for cmd in steps:
        res = subprocess.run(cmd, capture_output=True, text=True, check=False)
        if res.returncode != 0 or res.stderr.strip():
            first = (res.stderr.strip().splitlines() or ["(no message)"])[0]
            raise ExportError(f"arm-none-eabi-gcc on {d}: {first}")
    return elf


@dataclass(frozen=True)
class TargetRun:
    """One run under QEMU: the answers, and what it cost on the target.

    Attributes
    ----------
    result : CResult
        Every answer (float32 modules' numbers widened to float64 exactly).
    steps : int
    instructions_mean, instructions_worst : float
        Instructions per ``rimu_monitor_step`` (SysTick ticks × :data:`TICK_INSTRUCTIONS`:
        a resolution of 40 instructions per step).
    stack_bytes : int
        Stack high-water of the program (its ``main`` holds a ``rimu_answer``).
    answer_bytes, state_bytes : int
        ``sizeof(rimu_answer)``, ``sizeof(rimu_state)`` on the target.
    crc_ok : bool
        ``rimu_monitor_table_crc() == RIMU_TABLE_CRC`` on the target.
    """

    result: CResult
    steps: int
    instructions_mean: float
    instructions_worst: float
    stack_bytes: int
    answer_bytes: int
    state_bytes: int
    crc_ok: bool


def run_target(elf: str | Path, sensor_names: Any, *, float32: bool, parity_len: int,
               K: int, timeout_s: float = 600.0) -> TargetRun:
    """Run ``elf`` under QEMU and read its answers (see ``rimu_target.c``).

    Raises
    ------
    ExportError
        QEMU missing, failing, or an output that is not the program's.
    """
    qemu = shutil.which("qemu-system-arm")
    if qemu is None:
        raise ExportError("qemu-system-arm not on the PATH")
    res = subprocess.run([qemu, *QEMU[1:], "-kernel", str(elf)], capture_output=True,
                         text=True, check=False, timeout=timeout_s,
                         stdin=subprocess.DEVNULL)
    if res.returncode != 0:
        raise ExportError(f"qemu-system-arm on {elf}: exit {res.returncode}: "
                          f"{(res.stderr.strip().splitlines() or [''])[-1]}")
    # QEMU writes the semihosting console to its stderr
    rows, events, event_rows, summary = _console_lines(res.stderr + "\n" + res.stdout)
    if summary is None or int(summary[0]) != len(rows):
        raise ExportError(f"qemu-system-arm on {elf}: {len(rows)} answers and no complete "
                          "summary")
    names = tuple(sensor_names)
    result = _target_answers(rows, names, _target_events(events, names, float32), event_rows,
                             float32=float32, parity_len=parity_len, K=K)
    steps, total, worst, stack, ans, state, crc = (int(v) for v in summary[:7])
    return TargetRun(result, steps, TICK_INSTRUCTIONS * total / max(steps, 1),
                     float(TICK_INSTRUCTIONS * worst), stack, ans, state, bool(crc))


def _console_lines(text: str) -> tuple[list[list[str]], list[list[str]], list[int],
                                       list[str] | None]:
    """The program's console split into answer (``R``), event (``E``) and summary (``S``)
    lines.

    Parameters
    ----------
    text : str
        What QEMU printed.

    Returns
    -------
    rows : list of list of str
        The cells of each answer.
    events : list of list of str
        The cells of each event.
    event_rows : list of int
        The answer each event came with.
    summary : list of str or None
        The summary's cells (None when the program printed none).
    """
    rows: list[list[str]] = []
    events: list[list[str]] = []
    event_rows: list[int] = []
    summary: list[str] | None = None
    for line in text.splitlines():
        tok = line.split()
        if not tok:
            continue
        if tok[0] == "R":
            rows.append(tok[1:])
        elif tok[0] == "E":
            events.append(tok[1:])
            event_rows.append(len(rows) - 1)
        elif tok[0] == "S":
            summary = tok[1:]
    return rows, events, event_rows, summary


def _reals(cells: list[str], float32: bool) -> np.ndarray:
    """Hex bit patterns of the target's reals, as float64.

    Parameters
    ----------
    cells : list of str
    float32 : bool
        The target's reals are float (else double).

    Returns
    -------
    ndarray
    """
    rdt = np.dtype("<u4") if float32 else np.dtype("<u8")
    fdt = np.float32 if float32 else np.float64
    u = np.array([int(c, 16) for c in cells], dtype=rdt)
    return u.view(fdt).astype(np.float64)


def _target_answers(rows: list[list[str]], names: tuple[str, ...], evs: list[Any],
                    event_rows: list[int], *, float32: bool, parity_len: int, K: int
                    ) -> CResult:
    """The answers the target printed, as the host's C monitor returns them.

    Parameters
    ----------
    rows : list of list of str
        The cells of each answer line.
    names : tuple of str
        Sensor names.
    evs : list of Event
        :func:`_target_events`.
    event_rows : list of int
        The answer each event came with.
    float32 : bool
    parity_len, K : int
        Parity length and number of statistics.

    Returns
    -------
    CResult
    """
    n = len(names)
    P = parity_len
    width = 3 + 3 + P + 2 * K + 1
    N = len(rows)
    num = np.array([_reals(r[:width], float32) for r in rows]).reshape(N, width)
    cap = np.array([int(r[width]) for r in rows])
    healthy = np.array([[(int(r[width + 1], 16) >> i) & 1 for i in range(n)] for r in rows],
                       bool).reshape(N, n)
    status = np.array([[C_STATUSES[int(c, 16)] for c in r[width + 2]] for r in rows],
                      dtype=object).reshape(N, n)
    suspects = np.array([int(r[width + 3], 16) for r in rows], np.uint64)
    unverified = np.array([[(int(r[width + 4], 16) >> j) & 1 for j in range(3)]
                           for r in rows], bool).reshape(N, 3)
    env = np.array([int(r[width + 5], 16) for r in rows], np.int64)
    t = np.array([0.0] * N)
    o = 0
    cols = {}
    for name, k in (("omega", 3), ("omega_sd", 3), ("parity", P), ("statistics", K),
                    ("thresholds", K), ("protection_level", 1)):
        cols[name] = num[:, o:o + k]
        o += k
    return CResult(t=t, omega=cols["omega"], omega_sd=cols["omega_sd"], healthy=healthy,
                   status=status, parity=cols["parity"], statistics=cols["statistics"],
                   thresholds=cols["thresholds"],
                   capability=np.array(CAPABILITIES, dtype=object)[cap],
                   protection_level=cols["protection_level"][:, 0], envelope=env,
                   unverified=unverified, suspects=suspects, events=evs,
                   event_rows=np.array(event_rows, np.int64))


def _target_events(events: list[list[str]], names: tuple[str, ...], float32: bool
                   ) -> list[Any]:
    """The events the target printed, as the host's C monitor builds them.

    Parameters
    ----------
    events : list of list of str
        The cells of each event line.
    names : tuple of str
    float32 : bool

    Returns
    -------
    list of Event
    """
    host = types.SimpleNamespace(names=names, n=len(names))
    host._reason = types.MethodType(CMonitor._reason, host)
    evs = []
    for e in events:
        ns = types.SimpleNamespace(
            type=int(e[0]), sensor=int(e[1]), reason=int(e[2]), scale=int(e[3]),
            t=float(np.array([int(e[4], 16)], np.uint64).view(np.float64)[0]),
            statistic=float(_reals([e[5]], float32)[0]),
            threshold=float(_reals([e[6]], float32)[0]),
            magnitude=float(_reals([e[7]], float32)[0]), sensors=int(e[8], 16),
            envelope=int(e[9], 16))
        evs.append(CMonitor._event(host, ns))
    return evs
