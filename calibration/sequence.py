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

then one ``[[step]]`` table per step, numbered from 1 in file order::

    [[step]]
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
from fdi.fileio import read_toml_object
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

_TOP_KEYS = {"schema", "name", "description", "table_rate_dps", "turns",
             "position_duration_s", "mount", "printed_position_vector", "step"}
_STEP_KEYS = {"label", "kind", "mount", "inner_deg", "outer_deg", "inner_rate_w",
              "inner_rate_dps", "outer_rate_w", "outer_rate_dps", "turns", "duration_s",
              "pair", "printed", "printed_agrees", "note"}


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
        Missing file, bad TOML, wrong schema, or a bad field; the message names the file,
        the step and the field, and says what was expected.
    """
    key = str(name_or_path)
    alias = key.replace("_", "-")
    if alias in BUILTIN_SEQUENCES and not Path(key).is_file():
        path = SEQUENCES_DIR / BUILTIN_SEQUENCES[alias]
    else:
        path = Path(name_or_path)
    p = str(path)
    if not path.is_file():
        raise FileFormatError(p, "no such sequence file; built-in sequences are "
                              + ", ".join(sorted(BUILTIN_SEQUENCES)))
    doc = read_toml_object(path)
    overrides = {"table_rate_dps": table_rate_dps, "turns": turns,
                 "position_duration_s": position_duration_s}
    for k, v in overrides.items():
        if v is not None:
            doc[k] = v
    doc.setdefault("name", path.stem.replace("_", "-"))
    return sequence_from_dict(doc, p)


def _num(path: str, v: Any, field: str, step: int | None = None, *,
         positive: bool = False) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise FileFormatError(path, f"expected a finite number, got {v!r}", field=field,
                              step=step)
    if positive and v <= 0:
        raise FileFormatError(path, f"expected a positive number, got {v!r}", field=field,
                              step=step)
    return float(v)


def _rate(path: str, d: dict[str, Any], axis: str, w_dps: float, step: int) -> float:
    kw, kd = f"{axis}_rate_w", f"{axis}_rate_dps"
    if kw in d and kd in d:
        raise FileFormatError(path, f"give either '{kw}' or '{kd}', not both", field=kw,
                              step=step)
    if kw in d:
        return _num(path, d[kw], kw, step) * w_dps * DPS
    if kd in d:
        return _num(path, d[kd], kd, step) * DPS
    return 0.0


def sequence_from_dict(doc: dict[str, Any], path: str = "<sequence>") -> Sequence:
    """Build a :class:`Sequence` from its parsed TOML document (see the module docstring)."""
    schema = doc.get("schema", SEQUENCE_SCHEMA)
    if not isinstance(schema, str) or not schema.startswith("rimu.sequence/"):
        raise FileFormatError(path, f"expected '{SEQUENCE_SCHEMA}', got {schema!r}",
                              field="schema")
    if schema != SEQUENCE_SCHEMA:
        raise FileFormatError(path, f"unsupported version {schema!r}; this rimu reads "
                              f"'{SEQUENCE_SCHEMA}'", field="schema")
    unknown = sorted(set(doc) - _TOP_KEYS)
    if unknown:
        raise FileFormatError(path, f"unknown key; expected one of {sorted(_TOP_KEYS)}",
                              field=unknown[0])
    w_dps = _num(path, doc.get("table_rate_dps", 10.0), "table_rate_dps", positive=True)
    turns_default = _num(path, doc.get("turns", 1), "turns", positive=True)
    pos_default = _num(path, doc.get("position_duration_s", 20.0), "position_duration_s",
                       positive=True)
    mount_default = doc.get("mount", "x_inner_y_up")
    if not isinstance(mount_default, str) or mount_default not in MOUNTS:
        raise FileFormatError(path, f"unknown mounting {mount_default!r}; expected one of "
                              f"{sorted(MOUNTS)}", field="mount")
    ppv = doc.get("printed_position_vector", "specific_force")
    if not isinstance(ppv, str) or ppv not in ("specific_force", "gravity"):
        raise FileFormatError(path, f"expected 'specific_force' or 'gravity', got {ppv!r}",
                              field="printed_position_vector")
    raw_steps = doc.get("step")
    if not isinstance(raw_steps, list) or not raw_steps:
        raise FileFormatError(path, "expected one or more [[step]] tables", field="step")

    steps: list[dict[str, Any]] = []
    any_pair = any(isinstance(d, dict) and "pair" in d for d in raw_steps)
    for i, d in enumerate(raw_steps, start=1):
        if not isinstance(d, dict):
            raise FileFormatError(path, "expected a table", field="step", step=i)
        bad = sorted(set(d) - _STEP_KEYS)
        if bad:
            raise FileFormatError(path, f"unknown key; expected one of {sorted(_STEP_KEYS)}",
                                  field=bad[0], step=i)
        mount = d.get("mount", mount_default)
        if not isinstance(mount, str) or mount not in MOUNTS:
            raise FileFormatError(path, f"unknown mounting {mount!r}; expected one of "
                                  f"{sorted(MOUNTS)}", field="mount", step=i)
        inner = _num(path, d.get("inner_deg", 0.0), "inner_deg", i) * DEG
        outer = _num(path, d.get("outer_deg", 0.0), "outer_deg", i) * DEG
        wi = _rate(path, d, "inner", w_dps, i)
        wo = _rate(path, d, "outer", w_dps, i)
        turning = wi != 0.0 or wo != 0.0
        kind = d.get("kind", "rate" if turning else "position")
        if kind not in ("rate", "position"):
            raise FileFormatError(path, f"expected 'rate' or 'position', got {kind!r}",
                                  field="kind", step=i)
        if kind == "rate" and not turning:
            raise FileFormatError(path, "a rate step needs a non-zero inner or outer rate "
                                  "(inner_rate_w, inner_rate_dps, outer_rate_w or "
                                  "outer_rate_dps)", field="kind", step=i)
        if kind == "position" and turning:
            raise FileFormatError(path, "a position step must have zero rates", field="kind",
                                  step=i)
        if "turns" in d and "duration_s" in d:
            raise FileFormatError(path, "give either 'turns' or 'duration_s', not both",
                                  field="turns", step=i)
        if "duration_s" in d:
            duration = _num(path, d["duration_s"], "duration_s", i, positive=True)
        elif kind == "position":
            if "turns" in d:
                raise FileFormatError(path, "a position step has no turns; give "
                                      "'duration_s'", field="turns", step=i)
            duration = pos_default
        else:
            if wi != 0.0 and wo != 0.0:
                raise FileFormatError(path, "both axes turn: give 'duration_s' (turns are "
                                      "ambiguous)", field="duration_s", step=i)
            n_turns = _num(path, d.get("turns", turns_default), "turns", i, positive=True)
            duration = n_turns * 2.0 * math.pi / abs(wi or wo)
        pair = d.get("pair")
        if pair is not None and (isinstance(pair, bool) or not isinstance(pair, int)):
            raise FileFormatError(path, f"expected a step number, got {pair!r}", field="pair",
                                  step=i)
        printed = d.get("printed")
        if printed is not None:
            if (not isinstance(printed, list) or len(printed) != 3):
                raise FileFormatError(path, f"expected three numbers, got {printed!r}",
                                      field="printed", step=i)
            printed = tuple(_num(path, v, "printed", i) for v in printed)
        agrees = d.get("printed_agrees", True)
        if not isinstance(agrees, bool):
            raise FileFormatError(path, f"expected true or false, got {agrees!r}",
                                  field="printed_agrees", step=i)
        steps.append(dict(index=i, kind=kind, inner=inner, outer=outer, inner_rate=wi,
                          outer_rate=wo, mount=mount, duration_s=duration, pair=pair,
                          label=str(d.get("label", "")), printed=printed,
                          printed_agrees=agrees, note=str(d.get("note", ""))))

    n = len(steps)
    if not any_pair:
        rate_idx = [s["index"] for s in steps if s["kind"] == "rate"]
        for a, b in zip(rate_idx[0::2], rate_idx[1::2], strict=False):
            steps[a - 1]["pair"] = b
            steps[b - 1]["pair"] = a
    for s in steps:
        j = s["pair"]
        if j is None:
            continue
        i = s["index"]
        if not 1 <= j <= n or j == i:
            raise FileFormatError(path, f"expected another step number in 1..{n}, got {j}",
                                  field="pair", step=i)
        if s["kind"] != "rate" or steps[j - 1]["kind"] != "rate":
            raise FileFormatError(path, f"pairs join two rate steps; step {i} is "
                                  f"{s['kind']}, step {j} is {steps[j - 1]['kind']}",
                                  field="pair", step=i)
        if steps[j - 1]["pair"] != i:
            raise FileFormatError(path, f"pair must be mutual: step {i} pairs {j} but step "
                                  f"{j} pairs {steps[j - 1]['pair']}", field="pair", step=i)
    return Sequence(
        name=str(doc.get("name", "sequence")),
        steps=tuple(SequenceStep(**s) for s in steps),
        table_rate=w_dps * DPS,
        description=str(doc.get("description", "")),
        source=path,
        printed_position_vector=ppv,
    )
