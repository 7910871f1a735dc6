"""A detection episode of the streaming monitor: its fault hypotheses and their decisions.

While a detection is active :class:`fdi.monitor.Monitor` holds one :class:`Episode`: the
sensors still suspected, the body axes a fault on them would move (``unverified``) and when
the next isolation decision is due. The episode attributes the detection to a sensor (GLT,
:func:`fdi.isolation.isolate`), tests the single-sensor fault hypotheses on the window of
most evidence (:func:`fdi.isolation.decide`), narrows its suspects and names the sensor to
exclude once a single hypothesis remains; the monitor then excludes it and switches set.

The episode reads the detector state (:class:`fdi.state.DetectorState`) and the model of
the current set (:class:`fdi.reconstruction.SetModel`) it is handed; it changes neither.
The monitor's streaming step and its block path both come here from the same stop of the
compiled kernel, so their answers stay bit-identical.
"""

from __future__ import annotations

import math

import numpy as np

from fdi import state as S
from fdi.answer import Event
from fdi.capability import moved_axes
from fdi.detector import chi2_threshold
from fdi.isolation import IsolationDecision, decide, isolate, magnitude
from fdi.reconstruction import SetModel
from fdi.settings import MonitorSettings, Thresholds

__all__ = ["NO_AXES", "Episode"]

_NAN = float("nan")
_INF = float("inf")
NO_AXES = np.zeros(3, bool)
"""No body axis unverified (read-only)."""
NO_AXES.setflags(write=False)


class Episode:
    """The fault hypotheses of the monitor's active detection (none when it is cleared).

    Parameters
    ----------
    thresholds : Thresholds
        The monitor's thresholds (scales, risks, variance factors).
    settings : MonitorSettings
        Persistence and wrong-exclusion risk.
    sensor_names : tuple of str
        Names of the n sensors (for the events' reasons).
    thresholds0 : int
        Column of the first per-scale threshold in the kernel's output row.

    Attributes
    ----------
    suspects : tuple of int
        1-based sensors under suspicion (empty: no detection active).
    unverified : ndarray of bool, shape (3,)
        Body axes a fault on a suspect would move.
    """

    def __init__(self, thresholds: Thresholds, settings: MonitorSettings,
                 sensor_names: tuple[str, ...], thresholds0: int) -> None:
        self.thresholds = thresholds
        self.settings = settings
        self.sensor_names = sensor_names
        self.scales = tuple(int(w) for w in thresholds.scales)
        self.thresholds0 = thresholds0
        self.clear()

    def clear(self) -> None:
        """No detection active: nothing suspected, every axis verified."""
        self.suspects: tuple[int, ...] = ()
        self.unverified = NO_AXES
        self.iso_due = 0
        self.rows_seen = 0                  # detection age at the last stop (a new onset
        self.fresh = False                  # makes it smaller: decide afresh)
        self.no_fit = False                 # no single-sensor fault explains this detection

    def reopen(self) -> None:
        """The same episode goes on, on fresh windows (the envelope was re-entered)."""
        self.iso_due = self.settings.persistence
        self.rows_seen = 0

    # ------------------------------------------------------------------ the stops
    def detected(self, t: float, st: S.DetectorState, mdl: SetModel, row: np.ndarray,
                 fired: int, env: int, events: list[Event]) -> None:
        """A new detection: the ``"detected"`` event (naming the sensor only where a single
        hypothesis remains in a set that can isolate) and the first suspects."""
        stat = float(row[S.STATS0 + fired])
        thr = float(row[self.thresholds0 + fired])
        sensor, mag, reason, scale = self.attribute(st, mdl, fired)
        dec, w = self.decide(st, mdl, row, fired)
        single = mdl.capability == "isolate" and dec is not None \
            and dec.consistent == (dec.best,)
        events.append(Event(t, sensor if single else None, "detected", reason, stat, thr,
                            scale, mag if single else None, envelope=env))
        self.iso_due = self.settings.persistence
        self.rows_seen = 1
        self.suspect(t, st, mdl, dec, w, env, events)

    def isolation_due(self, t: float, st: S.DetectorState, mdl: SetModel, row: np.ndarray,
                      fired: int, env: int, events: list[Event]) -> int | None:
        """The detection persisted: decide when due; the column (of the set) of the sensor
        to exclude, with its ``"isolated"`` event, or None (suspects narrowed)."""
        rows = int(st.counters[S.DETECTED_ROWS])
        if rows < self.rows_seen:
            # a new onset within the open detection (the kernel restarted its age when the
            # evidence rose again from below the clearing levels): its hypotheses are
            # decided afresh, not narrowed by the episode before (a false alarm)
            self.iso_due = self.settings.persistence
            self.fresh = True
            self.no_fit = False
        self.rows_seen = rows
        if env or rows < self.iso_due:                      # out of the envelope: no exclusion
            return None
        self.iso_due = self.next_attempt(rows)
        dec, w = self.decide(st, mdl, row, fired)
        if dec is None or dec.exclude is None or mdl.capability != "isolate":
            self.suspect(t, st, mdl, dec, w, env, events)   # a set that only detects narrows
            return None                                     # its suspects, never excludes
        k = dec.exclude
        wm = self.episode_window(st)
        mag = magnitude(mdl.U, st.window_sum(wm), wm, k) if wm else None
        others = [float(dec.residuals[j]) for j in range(mdl.m) if j != k]
        events.append(Event(t, mdl.idx[k] + 1, "isolated", f"parity scale {w}",
                            min(others) if others else _NAN, dec.rejection_level, w, mag,
                            envelope=env))   # the weakest rejected alternative > c
        return k

    # ------------------------------------------------------------------ the tests
    def next_attempt(self, rows: int) -> int:
        """Detection age (samples) of the next isolation decision: when the next longer
        window lies wholly within the detection, then once per longest window."""
        for w in self.scales:
            if w > rows:
                return w
        return rows + max(self.scales)

    def decide(self, st: S.DetectorState, mdl: SetModel, row: np.ndarray, fired: int
               ) -> tuple[IsolationDecision | None, int]:
        """The isolation test (:func:`fdi.isolation.decide`) on the window of most evidence:
        the longer of the scale that fired and the longest window within the detection.
        Under the hypothesis of the truly faulty sensor its residual is χ²(df − 1) for any
        window, whatever the fault's size or time profile, so the choice costs no risk."""
        c = st.counters
        if mdl.df < 1:
            return None, 0
        rows = max(int(c[S.DETECTED_ROWS]), 1)
        count = int(c[S.WINDOW_COUNT])
        k = fired if 0 <= fired < len(self.scales) else -1
        for j, w in enumerate(self.scales):
            if w <= rows and w <= count and (k < 0 or w > self.scales[k]):
                k = j
        if k < 0:
            return None, 0
        w = self.scales[k]
        base = mdl.thr[k]
        infl = float(row[self.thresholds0 + k]) / base if base > 0 else _NAN
        if not (infl >= 1.0 and math.isfinite(infl)):
            infl = 1.0
        var = w * self.thresholds.variance_factor[k] * infl
        sub = chi2_threshold(self.thresholds.alpha[k], mdl.df - 1) if mdl.df > 1 else _INF
        return decide(mdl.U, st.window_sum(w), var, self.settings.wrong_exclusion, sub), w

    def suspect(self, t: float, st: S.DetectorState, mdl: SetModel,
                dec: IsolationDecision | None, w: int, env: int, events: list[Event]) -> None:
        """Record the suspected sensors of an active detection and the body axes a fault on
        them would move; a ``"disagree"`` event when they are not a single sensor or change.

        Within one detection the suspects only narrow: a hypothesis rejected once stays
        rejected (each rejection is a decision at the stated risk), so the set is the
        intersection of the consistent hypotheses of every decision; when that is empty no
        single-sensor fault explains the episode and every healthy sensor is suspected.
        """
        if self.no_fit:
            return
        cols = self._consistent(mdl, dec)
        none_fits = dec is not None and not cols
        self.no_fit = none_fits
        cols = cols or tuple(range(mdl.m))
        sus = tuple(sorted(mdl.idx[j] + 1 for j in cols))
        axes = _moved_axes(mdl, cols, st.window_sum(w) if w else None, w)
        changed = sus != self.suspects
        self.suspects = sus
        self.unverified = axes
        if changed and (len(sus) > 1 or mdl.capability != "isolate"):
            events.append(self._disagree(t, mdl, dec, w, sus, none_fits, env))

    def _consistent(self, mdl: SetModel, dec: IsolationDecision | None) -> tuple[int, ...]:
        """The set's columns still consistent: the decision's, narrowed by the suspects
        before (unless the onset is fresh)."""
        cols = tuple(range(mdl.m)) if dec is None else dec.consistent
        if self.fresh:
            self.fresh = False
        elif self.suspects and cols:
            before = {i - 1 for i in self.suspects}
            cols = tuple(j for j in cols if mdl.idx[j] in before)
        return cols

    def _disagree(self, t: float, mdl: SetModel, dec: IsolationDecision | None, w: int,
                  sus: tuple[int, ...], none_fits: bool, env: int) -> Event:
        """The ``"disagree"`` event of a changed set of suspects."""
        names = [self.sensor_names[i - 1] for i in sus]
        if none_fits:
            why = "no single-sensor fault explains the parity: " + _join(names) + " unverified"
        else:
            why = (_join(names) + (" disagree: cannot tell which" if len(sus) > 1 else
                                   ": suspected (this set cannot isolate)"))
        stat = _NAN
        if dec is not None and len(dec.consistent) < mdl.m:
            rej = [float(dec.residuals[j]) for j in range(mdl.m) if j not in dec.consistent]
            stat = min(rej)
        return Event(t, None, "disagree", why, stat,
                     dec.rejection_level if dec is not None else _NAN,
                     w or None, None, sus, env)

    def attribute(self, st: S.DetectorState, mdl: SetModel, fired: int
                  ) -> tuple[int, float | None, str, int | None]:
        """GLT sensor (1-based), magnitude (SI), reason and window of the scale that fired."""
        if fired >= len(self.scales):                        # the CUSUM bank fired
            k = int(np.argmax(st.cusum_scores(mdl.idx)))
            reason, scale = "cusum", None
        else:
            w = self.scales[fired]
            k, _ = isolate(mdl.U, st.window_sum(w), w)
            reason, scale = f"parity scale {w}", w
        wm = self.episode_window(st)
        mag = magnitude(mdl.U, st.window_sum(wm), wm, k) if wm else None
        return mdl.idx[k] + 1, mag, reason, scale

    def episode_window(self, st: S.DetectorState) -> int:
        """The longest window that lies within the detection episode (0: none); the fault
        magnitude is estimated from it (no sample from before the onset of a step)."""
        c = st.counters
        rows = max(int(c[S.DETECTED_ROWS]), 1)
        count = int(c[S.WINDOW_COUNT])
        wm = 0
        for w in self.scales:
            if w <= rows and w <= count:
                wm = w
        return wm


def _moved_axes(mdl: SetModel, cols: tuple[int, ...], s_w: np.ndarray | None,
                w: int) -> np.ndarray:
    """Body axes (read-only, shape (3,)) a fault on any of the set's columns ``cols`` would
    move: where its reconstruction column reaches, and where the fault estimated from the
    window sum ``s_w`` (of ``w`` samples) moves the rate by one sd."""
    G = mdl.G
    axes = np.zeros(3, bool)
    for j in cols:
        g = np.abs(G[:, mdl.idx[j]])
        axes |= moved_axes(g)
        if s_w is not None:
            f = abs(magnitude(mdl.U, s_w, w, j))
            with np.errstate(invalid="ignore", over="ignore"):
                axes |= ~(g * f < mdl.omega_sd)
    axes.setflags(write=False)
    return axes


def _join(names: list[str]) -> str:
    """'a', 'a and b', 'a, b and c'."""
    return names[0] if len(names) == 1 else ", ".join(names[:-1]) + " and " + names[-1]
