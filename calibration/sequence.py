"""Turntable test sequences: what the table does, step by step, read from TOML files.

A sequence is a list of steps. In a *rate* step one table axis (or both) turns at a
constant rate; in a *position* step the table stands still. The body-frame inputs of every
step are **derived** from the table angles and rates through the one kinematic model of
:mod:`calibration.turntable` (outer axis vertical, inner axis horizontal along North at outer
angle 0, right-handed angles, IMU on the inner plate through a named mounting); they are
never typed in. Two sequences ship with rimu (``calibration/sequences/*.toml``):

- ``tetrad-paper``: seed 000 Table 1 (16 rate steps, tetrad of FOGs, 10 °/s);
- ``cone-paper``: seed 001 Table 1 (10 positions) then Table 2 (14 rate steps), 30 °/s.

File format (``"schema" = "rimu.sequence/1"``, TOML)
---------------------------------------------------
Every key that holds a physical quantity says its unit in its name. Top level::

    schema = "rimu.sequence/1"
    name = "my-sequence"            # optional, defaults to the file stem
    description = "free text"       # optional
    table_rate_dps = 10.0           # the table rate w that *_w keys multiply (default 10)
    turns = 1                       # default length of a rate step, in whole turns (default 1)
    position_duration_s = 20.0      # default length of a position step (default 20 s)
    mount = "x_inner_y_up"          # default mounting, a name in calibration.turntable.MOUNTS
    printed_position_vector = "specific_force"   # or "gravity": how `printed` reads
                                                 # for position steps (see below)

then one ``[[steps]]`` table per step, numbered from 1 in file order (the older spelling
``[[step]]`` is still read, with a deprecation warning)::

    [[steps]]
    label = "Table 1 row 7"          # optional free text
    kind = "rate"                    # optional: "rate" if a rate is non-zero, else "position"
    mount = "x_inner_y_up"           # optional, overrides the default
    inner_deg = 30.0                 # inner angle at the start of the step (default 0)
    outer_deg = 0.0                  # outer angle at the start of the step (default 0)
    outer_rate_w = 1                 # rate in multiples of table_rate_dps, or
    # outer_rate_dps = 10.0          #   the rate in °/s (give one of the two; default 0)
    # inner_rate_w / inner_rate_dps  #   the same for the inner axis
    turns = 1                        # length in whole turns of the turning axis, or
    # duration_s = 36.0              #   in seconds (a step where both axes turn needs this)
    pair = 8                         # the opposite-rate step it is differenced with
    printed = [0, 1, 0]              # optional: the input the source table prints, body
                                     # frame, in multiples of w (rate) or g (position)
    printed_agrees = false           # optional (default true): the printed input
                                     # contradicts the kinematics (documented, tested)
    note = "free text"               # optional

Rate steps last whole turns by default so that the Earth-rate modulation (and, for an
inner-axis turn, gravity) averages out over each step (seed 000 Eq. 20). ``pair`` must be
mutual (step 7 pairs 8 and 8 pairs 7) and name rate steps. When no step in the file gives
``pair``, rate steps are paired in file order: the 1st with the 2nd, the 3rd with the 4th
(seed 000 Eq. 18 G-bar, seed 001 Eq. 15). Unknown keys are errors (they are usually typos).

``printed`` is only documentation and a test oracle. For position steps it is read as the
specific force ``f_b`` (what accelerometers sense, +g Up) when
``printed_position_vector = "specific_force"`` and as the gravity vector ``-f_b`` when it
is ``"gravity"`` (seed 001 Table 1 prints -g on z for the home position, z Up).

Angles: rad inside; rates: rad/s inside; times: s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from calibration.session import Step
from calibration.turntable import MOUNTS, body_inputs
from fdi.errors import FileFormatError
from fdi.fileio import Fields
from fdi.units import DEG, DPS

__all__ = [
    "BUILTIN_SEQUENCES",
    "SEQUENCES_DIR",
    "SEQUENCE_SCHEMA",
    "Sequence",
    "SequenceStep",
    "load_sequence",
    "sequence_from_dict",
]

SEQUENCE_SCHEMA = "rimu.sequence/1"
SEQUENCES_DIR = Path(__file__).resolve().parent / "sequences"
"""Directory of the sequences shipped with rimu."""
BUILTIN_SEQUENCES: dict[str, str] = {
    "cone-paper": "cone_paper.toml",
    "tetrad-paper": "tetrad_paper.toml",
}
"""Built-in sequence names and their files in :data:`SEQUENCES_DIR`."""

@dataclass(frozen=True)
class SequenceStep:
    """One step of a test sequence.

    Attributes
    ----------
    index : int
        1-based step number.
    kind : str
        ``"rate"`` or ``"position"``.
    inner, outer : float
        Table angles at the start of the step (rad, right-handed, see
        :mod:`calibration.turntable`).
    inner_rate, outer_rate : float
        Constant table rates during the step (rad/s).
    mount : str
        Mounting name, a key of :data:`calibration.turntable.MOUNTS`.
    duration_s : float
        Length of the step (s).
    pair : int or None
        1-based index of the opposite-rate step (rate steps), or None.
    label : str
    printed : tuple of float or None
        The body input the source table prints (multiples of the table rate for rate steps,
        of g for position steps; see ``printed_position_vector``), or None.
    printed_agrees : bool
        False when the source table's printed input contradicts the kinematics.
    note : str
    """

    index: int
    kind: str
    inner: float
    outer: float
    inner_rate: float
    outer_rate: float
    mount: str
    duration_s: float
    pair: int | None = None
    label: str = ""
    printed: tuple[float, float, float] | None = None
    printed_agrees: bool = True
    note: str = ""

    @property
    def mat_pb(self) -> np.ndarray:
        """Mounting matrix (3, 3): body axes as columns in plate coordinates."""
        return MOUNTS[self.mount].copy()

    def angles_at(self, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Inner and outer angles (rad) at times ``tau`` (s) since the start of the step."""
        tau = np.asarray(tau, float)
        return self.inner + self.inner_rate * tau, self.outer + self.outer_rate * tau

    def body_rate(self) -> np.ndarray:
        """Table rate in the body frame (rad/s, shape (3,)) at the start of the step.

        Constant over the step when only one axis turns. Earth rate not included.
        """
        w, _, _ = body_inputs(np.array([self.inner]), np.array([self.outer]),
                              np.array([self.inner_rate]), np.array([self.outer_rate]),
                              MOUNTS[self.mount], 0.0, 1.0)
        return w[0]

    def up_body(self) -> np.ndarray:
        """Unit Up vector in the body frame at the start of the step, shape (3,).

        The specific force at rest is ``g·up_body``.
        """
        _, _, f = body_inputs(np.array([self.inner]), np.array([self.outer]),
                              np.zeros(1), np.zeros(1), MOUNTS[self.mount], 0.0, 1.0)
        return f[0]

    def session_step(self) -> Step:
        """The :class:`calibration.session.Step` of this step."""
        return Step(index=self.index, kind=self.kind, mat_pb=self.mat_pb, label=self.label,
                    pair=self.pair)


@dataclass(frozen=True)
class Sequence:
    """A turntable test sequence.

    Attributes
    ----------
    name : str
    steps : tuple of SequenceStep
    table_rate : float
        The table rate w of the file (rad/s).
    description : str
    source : str
        File the sequence was read from.
    printed_position_vector : str
        ``"specific_force"`` or ``"gravity"``.
    """

    name: str
    steps: tuple[SequenceStep, ...]
    table_rate: float
    description: str = ""
    source: str = "<memory>"
    printed_position_vector: str = "specific_force"

    @property
    def duration_s(self) -> float:
        """Total length of the sequence (s)."""
        return float(sum(s.duration_s for s in self.steps))

    @property
    def table_rate_dps(self) -> float:
        """The table rate w in °/s."""
        return self.table_rate / DPS

    def rate_steps(self) -> tuple[SequenceStep, ...]:
        """The rate steps."""
        return tuple(s for s in self.steps if s.kind == "rate")

    def position_steps(self) -> tuple[SequenceStep, ...]:
        """The position steps."""
        return tuple(s for s in self.steps if s.kind == "position")

    def pairs(self) -> tuple[tuple[int, int], ...]:
        """Rate-step pairs (a, b), 1-based, a < b, in order of a."""
        return tuple((s.index, s.pair) for s in self.steps
                     if s.pair is not None and s.index < s.pair)

    def session_steps(self) -> tuple[Step, ...]:
        """The steps as :class:`calibration.session.Step` objects."""
        return tuple(s.session_step() for s in self.steps)

    def step(self, index: int) -> SequenceStep:
        """Step by 1-based index."""
        return self.steps[index - 1]

    def derived_inputs(self) -> np.ndarray:
        """Derived body input of every step, shape (S, 3), in the units of ``printed``.

        Rate steps: table rate in the body frame / table rate w. Position steps: Up in the
        body (specific force / g), negated when ``printed_position_vector`` is gravity.
        """
        out = np.zeros((len(self.steps), 3))
        sign = -1.0 if self.printed_position_vector == "gravity" else 1.0
        for k, s in enumerate(self.steps):
            if s.kind == "rate":
                out[k] = s.body_rate() / self.table_rate
            else:
                out[k] = sign * s.up_body()
        return out


def load_sequence(name_or_path: str | Path, *, table_rate_dps: float | None = None,
                  turns: float | None = None,
                  position_duration_s: float | None = None) -> Sequence:
    """Read a sequence: a built-in name (``"tetrad-paper"``, ``"cone-paper"``) or a file.

    Parameters
    ----------
    name_or_path : str or Path
    table_rate_dps : float, optional
        Replace the file's table rate w (used by the ``*_rate_w`` keys).
    turns : float, optional
        Replace the file's default rate-step length (whole turns; steps that give their own
        ``turns`` or ``duration_s`` keep it).
    position_duration_s : float, optional
        Replace the file's default position-step length.

    Raises
    ------
    FileFormatError
        Missing file, bad TOML, wrong schema, or a bad or unknown field; the message names
        the file, the line, the step and the field, and says what was expected.
    """
    key = str(name_or_path)
    alias = key.replace("_", "-")
    if alias in BUILTIN_SEQUENCES and not Path(key).is_file():
        path = SEQUENCES_DIR / BUILTIN_SEQUENCES[alias]
    else:
        path = Path(name_or_path)
    if not path.is_file():
        raise FileFormatError(str(path), "no such sequence file; built-in sequences are "
                              + ", ".join(sorted(BUILTIN_SEQUENCES)))
    r = Fields.from_toml(path)
    overrides = {"table_rate_dps": table_rate_dps, "turns": turns,
                 "position_duration_s": position_duration_s}
    return _sequence(r, path.stem.replace("_", "-"),
                     {k: v for k, v in overrides.items() if v is not None})


def sequence_from_dict(doc: dict[str, Any], path: str = "<sequence>") -> Sequence:
    """Build a :class:`Sequence` from its parsed TOML document (see the module docstring)."""
    return _sequence(Fields(doc, path), "sequence", {})


def _sequence(r: Fields, default_name: str, overrides: dict[str, float]) -> Sequence:
    """The whole file: top-level defaults, then the steps, then the pairs."""
    r.schema(SEQUENCE_SCHEMA, default=SEQUENCE_SCHEMA)
    top = {k: r.number(k, d, positive=True) for k, d in
           (("table_rate_dps", 10.0), ("turns", 1.0), ("position_duration_s", 20.0))}
    for k, v in overrides.items():
        top[k] = _positive_override(r, k, v)
    mount = r.choice("mount", sorted(MOUNTS), "x_inner_y_up")
    ppv = r.choice("printed_position_vector", ("specific_force", "gravity"),
                   "specific_force")
    tables = r.tables(r.table_name("steps"))
    any_pair = any("pair" in t for t in tables)
    steps = [_step(t.with_step(i), i, top, mount) for i, t in enumerate(tables, start=1)]
    if not any_pair:
        _pair_in_order(steps)
    for st, t in zip(steps, tables, strict=True):
        _check_pair(t.with_step(st["index"]), st, steps)
    seq = Sequence(
        name=r.string("name", default_name), steps=tuple(SequenceStep(**s) for s in steps),
        table_rate=top["table_rate_dps"] * DPS,
        description=r.string("description", "", nonempty=False),
        source=r.path, printed_position_vector=ppv)
    r.finish()
    return seq


def _positive_override(r: Fields, key: str, v: float) -> float:
    if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
        raise r.error(key, f"expected a positive number, got {v!r} (given as an override)")
    return float(v)


def _rate(d: Fields, axis: str, w_dps: float) -> float:
    """The rate of one table axis (rad/s) from ``<axis>_rate_w`` or ``<axis>_rate_dps``."""
    kw, kd = f"{axis}_rate_w", f"{axis}_rate_dps"
    w, dps = d.number(kw, None), d.number(kd, None)
    if w is not None and dps is not None:
        raise d.error(kw, f"give either '{kw}' or '{kd}', not both")
    if w is not None:
        return w * w_dps * DPS
    return 0.0 if dps is None else dps * DPS


def _step(d: Fields, i: int, top: dict[str, float], mount_default: str) -> dict[str, Any]:
    """One ``[[steps]]`` table (fields named by bare key and step number)."""
    wi = _rate(d, "inner", top["table_rate_dps"])
    wo = _rate(d, "outer", top["table_rate_dps"])
    turning = wi != 0.0 or wo != 0.0
    kind = d.choice("kind", ("rate", "position"), "rate" if turning else "position")
    if kind == "rate" and not turning:
        raise d.error("kind", "a rate step needs a non-zero inner or outer rate "
                      "(inner_rate_w, inner_rate_dps, outer_rate_w or outer_rate_dps)")
    if kind == "position" and turning:
        raise d.error("kind", "a position step must have zero rates")
    printed = d.array("printed", (3,), None)
    step = dict(
        index=i, kind=kind, inner=d.number("inner_deg", 0.0) * DEG,
        outer=d.number("outer_deg", 0.0) * DEG, inner_rate=wi, outer_rate=wo,
        mount=d.choice("mount", sorted(MOUNTS), mount_default),
        duration_s=_duration(d, kind, wi, wo, top), pair=d.integer("pair", None),
        label=d.string("label", "", nonempty=False),
        printed=None if printed is None else tuple(float(v) for v in printed),
        printed_agrees=d.boolean("printed_agrees", True),
        note=d.string("note", "", nonempty=False))
    d.finish()
    return step


def _duration(d: Fields, kind: str, wi: float, wo: float, top: dict[str, float]) -> float:
    """Step length (s): ``duration_s``, or whole turns of the turning axis, or the default."""
    turns = d.number("turns", None, positive=True)
    dur = d.number("duration_s", None, positive=True)
    if turns is not None and dur is not None:
        raise d.error("turns", "give either 'turns' or 'duration_s', not both")
    if dur is not None:
        return dur
    if kind == "position":
        if turns is not None:
            raise d.error("turns", "a position step has no turns; give 'duration_s'")
        return top["position_duration_s"]
    if wi != 0.0 and wo != 0.0:
        raise d.error("duration_s", "both axes turn: give 'duration_s' (turns are ambiguous)")
    return (turns or top["turns"]) * 2.0 * math.pi / abs(wi or wo)


def _pair_in_order(steps: list[dict[str, Any]]) -> None:
    """No step names a pair: rate steps pair in file order (1st with 2nd, 3rd with 4th)."""
    rate_idx = [s["index"] for s in steps if s["kind"] == "rate"]
    for a, b in zip(rate_idx[0::2], rate_idx[1::2], strict=False):
        steps[a - 1]["pair"] = b
        steps[b - 1]["pair"] = a


def _check_pair(d: Fields, s: dict[str, Any], steps: list[dict[str, Any]]) -> None:
    """Pairs join two different rate steps, mutually."""
    j, i, n = s["pair"], s["index"], len(steps)
    if j is None:
        return
    if not 1 <= j <= n or j == i:
        raise d.error("pair", f"expected another step number in 1..{n}, got {j}")
    other = steps[j - 1]
    if s["kind"] != "rate" or other["kind"] != "rate":
        raise d.error("pair", f"pairs join two rate steps; step {i} is {s['kind']}, step "
                      f"{j} is {other['kind']}")
    if other["pair"] != i:
        raise d.error("pair", f"pair must be mutual: step {i} pairs {j} but step {j} pairs "
                      f"{other['pair']}")
