"""The shape of an effect specification: :class:`EffectSpec` and its forms.

An effect beyond the linear sensor model ``y = SF·u − b`` (the calibration model of the
seed papers) exists in four places: the simulator adds it to a session, the diagnosis tests
its regressor on a session or a flight, and the monitor subtracts its run-time form from
the compensated output. One :class:`EffectSpec` holds all four, as pure numpy functions of
the inputs they read; :mod:`calibration.effects`, :mod:`calibration.simulate`,
:mod:`calibration.diagnose.library`, :mod:`calibration.inflight.diagnose` and
:mod:`fdi.effects` derive their forms from it. The built-in specs are in
:mod:`fdi.effect_specs.builtin`.

The session inputs a regressor reads are the attributes of
:class:`calibration.diagnose.context.KindData` (:class:`SessionInputs` lists them: ``fdi``
does not import ``calibration``); the flight inputs are :class:`FlightInputs`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

from fdi.units import DPH, MG

if TYPE_CHECKING:
    import numpy as np

__all__ = ["BIAS_UNITS", "EffectSpec", "FlightForm", "FlightInputs", "RuntimeForm",
           "SessionInputs", "SimulatorForm", "no_need"]

BIAS_UNITS = {"gyro": ("deg/h", DPH), "accel": ("mg", MG)}
"""Display unit and its SI factor of bias-like effects, per sensor kind."""


class SessionInputs(Protocol):
    """What a session regressor reads (the attributes of ``KindData``).

    ``kind`` (``"gyro"``/``"accel"``), ``N`` samples, ``n`` sensors; ``H`` (n, 3) the
    calibrated axes; ``x``, ``x_dot``, ``earth``, ``force`` (N, 3) the body input (rad/s or
    m/s²), its rate of change, the Earth rate (rad/s) and the specific force (m/s²); ``s``
    (N, n) the input along each axis; ``t`` (N,) time from the session start (s);
    ``duration_s``; ``table_rate`` (rad/s; 0 without rate steps); ``temperature`` (N, n) °C
    or None; ``mount`` (N,) the mounting index; ``step`` (N,) the step index;
    ``sample_rate_hz``.
    """

    kind: str
    N: int
    H: np.ndarray
    x: np.ndarray
    x_dot: np.ndarray
    earth: np.ndarray
    force: np.ndarray
    s: np.ndarray
    t: np.ndarray
    duration_s: float
    table_rate: float
    temperature: np.ndarray | None
    mount: np.ndarray


@dataclass(frozen=True)
class FlightInputs:
    """What a flight regressor reads, for one IMU of three gyro channels.

    Attributes
    ----------
    t : ndarray, shape (N,)
        Time (s).
    keep : ndarray of bool, shape (N,)
        Samples the diagnosis uses.
    rate_dot : ndarray, shape (N, 3)
        ``H_j·dω̂/dt`` on the IMU's three channels (rad/s²).
    force : ndarray, shape (N, k) or None
        The IMU's logged accelerometers (m/s²), None when none.
    temperature : ndarray, shape (N, k) or None
        The IMU's logged temperature (°C), None when none.
    """

    t: np.ndarray
    keep: np.ndarray
    rate_dot: np.ndarray
    force: np.ndarray | None = None
    temperature: np.ndarray | None = None


def no_need(data: Any) -> str | None:
    """The effect can be tested on any session (the default ``needs``)."""
    return None


@dataclass(frozen=True)
class SimulatorForm:
    """How ``rimu simulate calibration`` adds the effect (a knob, off by default).

    Attributes
    ----------
    unit : str
        Unit of the knob's value on the CLI and in the truth file.
    kinds : tuple of str
        Sensor kinds the knob acts on.
    doc : str
        One-line definition (the CLI help).
    apply : callable ``(s, value, ctx) -> s`` or None
        On the gyro input along the true axes ``s`` (N, m) of the touched sensors; ``ctx``
        has ``t`` (N,), ``duration_s``, ``table_rate`` (rad/s) and ``f_along`` (N, m). None:
        the effect acts on the inputs (``stage``).
    stage : str
        ``"output"`` (``apply``), ``"delay"`` (the input is sampled late) or
        ``"earth_rate"`` (the Earth rate is left out).
    flag : bool
        The value is on/off only.
    all_sensors : bool
        Ignores ``--effect-sensors``.
    details : callable ``(meta) -> dict`` or None
        The constants the knob used, for the truth sidecar (``meta``: the session's
        ``table_rate_dps`` and ``duration_s``).
    order : int
        Position in the order the output effects are applied (gains before biases).
    column : bool
        Whenever the knob is given (also 0) the session carries the temperature column
        and the truth records the knob's details.
    """

    unit: str
    kinds: tuple[str, ...]
    doc: str
    apply: Callable[[np.ndarray, float, Any], np.ndarray] | None = None
    stage: str = "output"
    flag: bool = False
    all_sensors: bool = False
    details: Callable[[Mapping[str, Any]], dict[str, Any]] | None = None
    order: int = 0
    column: bool = False


@dataclass(frozen=True)
class RuntimeForm:
    """How the monitor compensates a term of the effect, elementwise.

    The correction of one term is ``apply(k, x, e)`` with ``k = coefficient(estimate,
    params, kind)`` folded once, ``x`` the run-time input of the sample (the sensor's own
    compensated output for ``"rate"``, the components ``(fx, fy, fz)`` for
    ``"specific_force"``, the temperature for ``"temperature"``) and ``e = extra(params,
    axis, variance)``. ``apply`` uses ``+ − ×`` and ``abs`` only, so numpy arrays and
    Python floats give the same bits.

    Attributes
    ----------
    input : str
        ``"rate"``, ``"specific_force"`` or ``"temperature"``.
    reads : str
        What it reads, for people (``"rate sign"``).
    code : int
        The branch of the scalar path and of the C template (``EFFECT_*``).
    kinds : tuple of str
        Sensor kinds it has a run-time form for (a term carries the session regressor's
        unit, :meth:`EffectSpec.unit_for`).
    coefficient : callable ``(estimate, params, kind) -> float``
    extra : callable ``(params, axis, variance) -> float or tuple``
    apply : callable ``(k, x, e) -> value``
    check : callable ``(params) -> str or None``
        Why a term's parameters do not suit (None: they do).
    """

    input: str
    reads: str
    code: int
    kinds: tuple[str, ...]
    coefficient: Callable[[float, Mapping[str, Any], str], float]
    extra: Callable[[Mapping[str, Any], np.ndarray, float], Any]
    apply: Callable[[Any, Any, Any], Any]
    check: Callable[[Mapping[str, Any]], str | None] = field(default=lambda p: None)


@dataclass(frozen=True)
class FlightForm:
    """The in-flight candidate of the effect (:mod:`calibration.inflight.diagnose`).

    Attributes
    ----------
    label : str
        Name of the record (a searched line adds ``_<f>Hz``).
    unit : str
        Unit of the reported estimate.
    scale : float
        SI parameter → reported unit.
    columns : callable ``(FlightInputs, params) -> ndarray (N, 3, p) or str``
        The regressor on the IMU's three channels, or why it cannot be tested.
    order : int
        Position among the in-flight candidates (ties in the selection go to the first).
    time_only : bool
        A function of time only: enters after the measured regressors.
    role : str
        ``"skew"`` (the timing record), ``"drift"`` (the drift attribution) or ``""``.
    matrix : tuple of (tuple of str, bool) or None
        Column labels of the reported matrix and whether the parameters are term-major
        (``P1x P1y P1z P2x …``) rather than channel-major.
    searched : bool
        One candidate per spectral line (``params["frequency_hz"]``).
    """

    label: str
    unit: str
    scale: float
    columns: Callable[[FlightInputs, Mapping[str, Any]], np.ndarray | str]
    order: int
    time_only: bool = False
    role: str = ""
    matrix: tuple[tuple[str, ...], bool] | None = None
    searched: bool = False


@dataclass(frozen=True)
class EffectSpec:
    """One sensor effect: name, units, inputs, and its four forms.

    Attributes
    ----------
    name : str
    kinds : tuple of str
        Sensor kinds the diagnosis tests it on.
    meaning : str
        Physical meaning, one line.
    unit : str
        Unit of its value (``"{bias}"`` is the kind's bias unit, :data:`BIAS_UNITS`).
    inputs : tuple of str
        Session inputs its regressor needs (``"time"``, ``"temperature"``, ...).
    regressor : callable ``(data, sensor, params) -> ndarray (N,) or (N, p)``
        SI output per unit of the value on a session (:class:`SessionInputs`).
    needs : callable ``(data) -> str or None``
        Why it cannot be tested on a session (None: testable).
    fixed_params : callable ``(data, sensor) -> dict`` or None
        Parameters the session fixes and a term records (table rate, reference °C).
    search : str or None
        The unknown parameter the diagnosis searches (``"time_s"``, ``"frequency_hz"``,
        ``"mount"``), None when there is none.
    could_absorb : str
        What else the fitted term can absorb (printed with each finding).
    bounds : mapping of sensor class to mapping of kind to float
        Largest plausible ``|estimate|`` per class (``"*"`` for every class).
    fraction_range : tuple of float or None
        The plausible interval of a fraction-valued effect (replaces ``bounds``).
    monitor_input : str or None
        What the monitor would need (None: nothing can compensate it live).
    simulator : SimulatorForm or None
    runtime : RuntimeForm or None
    no_runtime : str
        Why there is no run-time form (empty when there is one).
    flight : FlightForm or None
    """

    name: str
    kinds: tuple[str, ...]
    meaning: str
    unit: str
    regressor: Callable[[Any, int, Mapping[str, Any]], np.ndarray]
    inputs: tuple[str, ...] = ()
    needs: Callable[[Any], str | None] = no_need
    fixed_params: Callable[[Any, int], dict[str, Any]] | None = None
    search: str | None = None
    could_absorb: str = ""
    bounds: Mapping[str, Mapping[str, float]] = field(default_factory=dict)
    fraction_range: tuple[float, float] | None = None
    monitor_input: str | None = None
    simulator: SimulatorForm | None = None
    runtime: RuntimeForm | None = None
    no_runtime: str = ""
    flight: FlightForm | None = None

    def unit_for(self, kind: str) -> str:
        """The unit of the value for sensors of ``kind``."""
        return self.unit.replace("{bias}", BIAS_UNITS[kind][0])

    def bound(self, sensor_class: str, kind: str) -> float | None:
        """The largest plausible ``|estimate|`` (None: no bound)."""
        per = self.bounds.get(sensor_class, self.bounds.get("*", {}))
        return per.get(kind)
