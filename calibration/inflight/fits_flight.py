"""Does a calibration fit another flight? Every parameter tested, not only the time offset.

A calibration carried to a new flight brings what should last across power-ups (mounting,
scale, a firmware lag) and what may not (turn-on bias, jitter, the vibration the noise
model saw). :func:`parameter_checks` fits the new flight in flight as ``rimu calibrate
in-flight`` does (:func:`calibration.inflight.fit_inflight`, its defaults) and compares,
per IMU against the reference and per axis, each parameter of the calibration with the
same parameter of the flight:

- **scale** (``A_jj − 1``), **misalignment** (the small rotation θ) and **bias** of the
  alignment, with the sds both fits state (their HAC standard errors); the bias also with
  the run-to-run spread ``bias_turn_on_sd`` where the calibration carries it (a relative
  bias spreads as ``sqrt(sd_j² + sd_ref²)``);
- the **time offset** τ and the **timing jitter**, with their sds;
- the **noise level** per sensor: the log of the per-sample noise sd, whose sd is
  ``1/sqrt(2·N_eff)`` with ``N_eff`` the fit's samples over its HAC lag count.

Each difference is a z-score ``(flight − calibration)/sqrt(sd_f² + sd_c² + spread²)``,
two-sided, and a parameter does not fit at ``alpha`` family-wise (Bonferroni over every
parameter tested). :func:`mismatch_warnings` turns the failures into one line per IMU and
parameter, naming both values (``imu2 scale x/y/z: calibration +5.6/+4.0/+3.0 %, this
flight -0.5/+0.2/-0.5 %``), for ``rimu diagnose FLIGHT --cal CAL`` and ``rimu
monitor-file``. When the calibration's flights and this one name their firmware and it
differs (:mod:`replay.firmware`), :func:`flight_mismatch` says so first: the time offset,
filtering and driver scale belong to the firmware and may not carry.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from scipy import stats

from fdi.calfile import Calibration
from fdi.errors import RimuError
from fdi.units import DPS
from replay.firmware import calibration_firmwares, firmware_change
from replay.time_offsets import flight_identity
from replay.turn_on import same_power_up

__all__ = ["ParameterCheck", "calibration_firmware", "flight_calibration", "flight_mismatch",
           "mismatch_warnings", "parameter_checks"]

_AXES = "xyz"
_MS = 1e-3


@dataclass(frozen=True)
class ParameterCheck:
    """One parameter of a calibration against the same parameter fitted on a flight.

    Attributes
    ----------
    imu : str
        The IMU (against the reference) or, for the noise level, the sensor's IMU.
    parameter : str
        ``scale``, ``misalignment``, ``bias``, ``time offset``, ``jitter`` or ``noise``.
    axis : str
        ``x``, ``y``, ``z``, or ``""`` (per IMU), or the sensor name (noise).
    calibrated, flight : float
        The value in the calibration and on this flight, in ``unit``.
    sd : float
        sd of the difference (both fits' sds and the spread), in ``unit`` (noise: of the
        log ratio).
    z : float
    fits : bool
        False when the difference is significant at the family-wise level.
    unit : str
    """

    imu: str
    parameter: str
    axis: str
    calibrated: float
    flight: float
    sd: float
    z: float
    fits: bool
    unit: str

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return dict(self.__dict__)


def flight_calibration(flight: Any) -> Calibration:
    """The flight's own in-flight calibration (``rimu calibrate in-flight`` defaults)."""
    from calibration.inflight.calfile import calibration_from_fit
    from calibration.inflight.fit import fit_inflight

    return calibration_from_fit(fit_inflight(flight), flight, tails=False)


def _z(d: float, sd: float) -> float:
    return d / sd if sd > 0 else (0.0 if d == 0 else math.inf)


_Row = tuple[str, str, str, float, float, float, str]


def _turn_on_sd(cal: Calibration, ref: str | None, imu: str, k: int) -> float:
    """Run-to-run sd of IMU ``imu``'s axis k bias relative to the reference (rad/s)."""
    s_c = cal.kind("gyro")
    names = [c.name for c in s_c.sensors]

    def sd_of(g: str | None) -> float:
        if g is None:
            return 0.0
        nm = f"{g}.{_AXES[k]}"
        if nm not in names:
            return 0.0
        v = getattr(s_c.sensors[names.index(nm)], "bias_turn_on_sd", None)
        return float(v) if v is not None and math.isfinite(float(v)) else 0.0

    return math.hypot(sd_of(imu), sd_of(ref))


def _alignment_rows(cal: Calibration, flight_cal: Calibration, ref: str | None) -> list[_Row]:
    """Scale, misalignment and bias of every IMU and axis."""
    a_c, a_f = cal.extras.inflight_alignment, flight_cal.extras.inflight_alignment
    raw: list[_Row] = []
    if a_c is None or a_f is None:
        return raw
    for g, ac in a_c.imus.items():
        af = a_f.imus.get(g)
        if af is None:
            continue
        for k, ax in enumerate(_AXES):
            raw.append((g, "scale", ax, 100 * ac.scale[k], 100 * af.scale[k],
                        100 * math.hypot(ac.scale_sd[k], af.scale_sd[k]), "%"))
            raw.append((g, "misalignment", ax, math.degrees(ac.rotation[k]),
                        math.degrees(af.rotation[k]),
                        math.degrees(math.hypot(ac.rotation_sd[k], af.rotation_sd[k])),
                        "deg"))
            raw.append((g, "bias", ax, ac.bias[k] / DPS, af.bias[k] / DPS,
                        math.sqrt(ac.bias_sd[k] ** 2 + af.bias_sd[k] ** 2
                                  + _turn_on_sd(cal, ref, g, k) ** 2) / DPS, "deg/s"))
    return raw


def _timing_rows(cal: Calibration, flight_cal: Calibration) -> list[_Row]:
    """Time offset and timing jitter of every IMU."""
    t_c, t_f = cal.extras.inflight, flight_cal.extras.inflight
    raw: list[_Row] = []
    if t_c is None or t_f is None:
        return raw
    for g, tc in t_c.imus.items():
        tf = t_f.imus.get(g)
        if tf is None:
            continue
        if tc.time_offset_s is not None and tf.time_offset_s is not None:
            raw.append((g, "time offset", "", tc.time_offset_s / _MS,
                        tf.time_offset_s / _MS,
                        math.hypot(tc.time_offset_sd_s, tf.time_offset_sd_s) / _MS, "ms"))
        if tc.timing_jitter_s is not None and tf.timing_jitter_s is not None:
            raw.append((g, "jitter", "", tc.timing_jitter_s / _MS, tf.timing_jitter_s / _MS,
                        math.hypot(tc.timing_jitter_sd_s, tf.timing_jitter_sd_s) / _MS,
                        "ms"))
    return raw


def _n_eff(c: Calibration) -> float:
    a = c.extras.inflight_alignment
    if a is None or not a.imus:
        return math.nan
    al = next(iter(a.imus.values()))
    return al.samples / max(int(al.hac_lags), 1)


def _noise_rows(cal: Calibration, flight_cal: Calibration) -> list[_Row]:
    """The noise level of every sensor both calibrations have (log ratio)."""
    s_c, s_f = cal.kind("gyro"), flight_cal.kind("gyro")
    names = [c.name for c in s_c.sensors]
    f_names = [c.name for c in s_f.sensors]
    ne = [_n_eff(cal), _n_eff(flight_cal)]
    raw: list[_Row] = []
    if not all(math.isfinite(x) and x > 0 for x in ne):
        return raw
    sd_log = math.sqrt(1.0 / (2 * ne[0]) + 1.0 / (2 * ne[1]))
    for i, nm in enumerate(names):
        if nm not in f_names:
            continue
        vc, vf = float(s_c.noise_sd[i]), float(s_f.noise_sd[f_names.index(nm)])
        if vc > 0 and vf > 0:
            raw.append((nm.split(".")[0], "noise", nm, vc / DPS, vf / DPS, sd_log, "deg/s"))
    return raw


def parameter_checks(cal: Calibration, flight_cal: Calibration, *, alpha: float = 0.01
                     ) -> list[ParameterCheck]:
    """Every parameter of ``cal`` against ``flight_cal`` (module docstring).

    Both must be in-flight calibrations of the same IMU set (the same IMU names); the
    parameters one of them lacks are not tested.
    """
    t_c = cal.extras.inflight
    ref = t_c.reference if t_c is not None else None
    raw = (_alignment_rows(cal, flight_cal, ref) + _timing_rows(cal, flight_cal)
           + _noise_rows(cal, flight_cal))
    M = max(len(raw), 1)
    zc = float(stats.norm.isf(alpha / (2 * M)))
    out = []
    for g, p, ax, vc, vf, sd, unit in raw:
        d = math.log(vf / vc) if p == "noise" else vf - vc
        z = _z(d, sd)
        out.append(ParameterCheck(g, p, ax, vc, vf, sd, z, bool(abs(z) <= zc), unit))
    return out


def _fmt(v: float, unit: str) -> str:
    if unit == "%":
        return f"{v:+.2g}"
    return f"{v:.3g}" if unit != "deg/s" else f"{v:+.3g}"


def mismatch_warnings(checks: list[ParameterCheck]) -> list[str]:
    """One line per IMU and parameter with a parameter that does not fit (module docstring)."""
    groups: dict[tuple[str, str], list[ParameterCheck]] = {}
    for c in checks:
        groups.setdefault((c.imu, c.parameter), []).append(c)
    out = []
    for (g, p), cs in groups.items():
        if all(c.fits for c in cs):
            continue
        unit = cs[0].unit
        zmax = max(abs(c.z) for c in cs)
        if p == "noise":
            bad = [c for c in cs if not c.fits]
            out.append(f"{g} noise: " + ", ".join(
                f"{c.axis} {c.calibrated:.3g} deg/s in the calibration, {c.flight:.3g} on this "
                f"flight" for c in bad) + f" (|z| up to {zmax:.3g}): the calibration's noise "
                f"model does not fit this flight's vibration; thresholds made from it do "
                f"not hold here")
            continue
        axes = "/".join(c.axis for c in cs) if cs[0].axis else ""
        label = f"{g} {p}" + (f" {axes}" if axes else "")
        cv = "/".join(_fmt(c.calibrated, unit) for c in cs)
        fv = "/".join(_fmt(c.flight, unit) for c in cs)
        out.append(f"{label}: calibration {cv} {unit}, this flight {fv} {unit} (|z| up to "
                   f"{zmax:.3g}, family-wise test of every parameter): the calibration's "
                   f"{p} does not fit this flight")
    return out


def flight_mismatch(cal: Calibration, flight: Any, *, alpha: float = 0.01
                    ) -> tuple[list[ParameterCheck], list[str]]:
    """Fit ``flight`` and compare (checks, warning lines); nothing on the calibration's own
    power-up (:func:`replay.turn_on.same_power_up`) or for a calibration that is not
    in-flight; a flight the in-flight fit refuses gives one warning saying so and no
    checks."""
    if cal.extras.inflight_alignment is None or same_power_up(cal, flight):
        return [], []
    builds = calibration_firmwares(cal)
    here = str(flight_identity(flight)["firmware"])
    fw = None if here in builds else firmware_change(" | ".join(builds), here)
    first = [fw] if fw else []
    try:
        fc = flight_calibration(flight)
    except RimuError as e:
        return [], [*first, f"the calibration's parameters could not be checked against this "
                            f"flight: its in-flight fit refuses it ({e})"]
    checks = parameter_checks(cal, fc, alpha=alpha)
    return checks, [*first, *mismatch_warnings(checks)]


def calibration_firmware(cal: Calibration) -> str:
    """The firmware the calibration's flights name (``extra.inflight``): that of its flight,
    or of each flight calibrated together (different ones joined by ``" | "``); ``""``
    when none names one (:func:`replay.firmware.calibration_firmwares`)."""
    return " | ".join(calibration_firmwares(cal))
