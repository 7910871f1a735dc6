"""The streaming parity-space monitor: detect, isolate by zeroing rows of H, reconstruct.

One sample of n raw sensor outputs in, one :class:`fdi.answer.Answer` out
(:meth:`Monitor.step`); or a whole block (:meth:`Monitor.run`) with bit-identical answers.

Both run the same compiled per-sample recursion, :func:`fdi.kernel.advance` (health checks,
compensation, parity, whitening, dyadic windows, CUSUM, detection state machine,
reconstruction, protection level; see :mod:`fdi.kernel`). The kernel runs until a sample
needs the monitor: a health verdict, a re-admission, a missing sample, a detection or an
isolation. :class:`Monitor` then names the events, hands a detection to its
:class:`fdi.episode.Episode` (attribution by GLT, :mod:`fdi.isolation`; the suspects and the
sensor to exclude), switches to the model of the new healthy set
(:class:`fdi.reconstruction.SetCache`) and resumes the kernel. Samples are read into the
kernel's rows by :class:`fdi.sample_input.SampleReader`. The state the kernel carries is laid
out in :mod:`fdi.state`; the windows and the CUSUM bank are :mod:`fdi.windows` and
:mod:`fdi.cusum`.

Detection state machine: the first alarm emits ``"detected"``; after ``persistence``
consecutive alarms a set that can isolate isolates the GLT sensor at the scale with the
largest D/T (``"isolated"``, with the magnitude); a set that cannot stays "detected" until
every statistic has stayed below its clearing level for ``clear_samples`` samples
(hysteresis: one event per onset, no flapping; the level is ``clear_ratio × threshold``,
raised where that lies in the bulk of healthy noise, :func:`fdi.detector.clear_thresholds`).

Samples in which a healthy sensor is missing (``valid = False``) give ω̂ from the sensors
present, do not enter the windows (windows count complete samples) and carry an infinite
protection level (no parity test was possible).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from fdi import state as S
from fdi.answer import Answer, BlockResult, Event
from fdi.blocks import BlockRows, block_from_answers, make_answer
from fdi.calfile import Calibration
from fdi.detector import default_thresholds
from fdi.envelope import SATURATION, reason_names
from fdi.episode import Episode
from fdi.errors import ConfigError
from fdi.health import health_limits
from fdi.kernel import advance, reconstruct_row
from fdi.reconstruction import SetCache, SetModel
from fdi.sample_input import SampleReader, env_code, envelope_runs
from fdi.settings import MonitorSettings, Thresholds

__all__ = ["Monitor"]

_NAN = float("nan")
_STOP_MASK = S.STOP_MASK
_RETURN_DETECTED = S.RETURN_DETECTED
_INF = float("inf")
_CHUNK = 1 << 16


class Monitor:
    """Streaming FDI monitor for one sensor set of a calibration.

    Parameters
    ----------
    cal : Calibration
    thresholds : Thresholds, optional
        Defaults to :func:`fdi.detector.default_thresholds` (1e-3 false alarms per hour,
        windows of 1 ... 128 samples).
    kind : str
        ``"gyro"`` or ``"accel"``.
    settings : MonitorSettings, optional

    Raises
    ------
    ConfigError
        Thresholds made for another kind or number of sensors.

    Notes
    -----
    :meth:`step` never raises: bad numbers, wrong lengths and odd types mark sensors (or the
    sample) and the monitor carries on. The models of every healthy set down to n − 2
    sensors are built here (no SVD in the step path); smaller sets are built the first time
    they occur and cached (``self.cache``, keyed by the bitmask of healthy sensors).
    """

    def __init__(self, cal: Calibration, thresholds: Thresholds | None = None, *,
                 kind: str = "gyro", settings: MonitorSettings | None = None) -> None:
        s = cal.kind(kind)
        self.kind = kind
        self.cal = cal
        self.settings = settings or MonitorSettings()
        self.thresholds = thresholds or default_thresholds(cal, kind=kind)
        if self.thresholds.kind != kind:
            raise ConfigError(f"thresholds are for {self.thresholds.kind} sensors, the monitor "
                              f"watches {kind} sensors")
        if self.thresholds.n != s.n:
            raise ConfigError(f"thresholds are for {self.thresholds.n} sensors, the "
                              f"calibration has {s.n} {kind} sensors")
        self.n = s.n
        self.sensor_names = tuple(c.name for c in s.sensors)
        md = self.settings.missed_detection or self.thresholds.missed_detection
        cin = np.array([np.asarray(c.input_error_cov, float) for c in s.sensors])
        self._sigma = np.asarray(s.noise_covariance, float)
        bsd = np.array([c.bias_sd for c in s.sensors], float)
        jit = np.array([c.timing_jitter for c in s.sensors], float)
        self.cache = SetCache(s.H, s.scale_factors, s.biases, self._sigma, cin,
                              self.thresholds, md, bsd,
                              wrong_exclusion=self.settings.wrong_exclusion,
                              isolation_ratio=self.settings.isolation_ratio,
                              timing_jitter=jit)
        self.cache.precompute(max(self.n - 2, 0))        # bounded step time through two isolations
        self._limits = health_limits(self.settings, kind, s.scale_factors, s.biases)
        self._packed: dict[int, S.KernelSet] = {}
        self._scales = tuple(int(w) for w in self.thresholds.scales)
        self._cusum = self.thresholds.detector != "windows"
        self.K = len(self._scales) + (1 if self._cusum else 0)
        self._layout = S.OutLayout(self.K, max(self.n - 3, 0))
        self._full_mask = (1 << self.n) - 1
        self._healthy_arr: dict[int, np.ndarray] = {}
        self._input = SampleReader(self.n)
        self._episode = Episode(self.thresholds, self.settings, self.sensor_names,
                                self._layout.thresholds0)
        self._row = np.empty((1, self._layout.width(True)))
        self._row0 = self._row[0]
        self._t1 = np.empty(1)
        self._columns = (S.OMEGA0, S.STATS0, self._layout.thresholds0, self._layout.parity0)
        self.reset()

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Back to the state after construction (all sensors healthy, empty windows)."""
        self._state = S.DetectorState(self.n, max(self._scales) + 1)
        self._state.counters[S.HAS_PARITY] = 1
        self._status = ["ok"] * self.n
        self._input.length_bad = False
        self._env = 0
        self._time_code = S.TIME_OK                  # the verdict of the last time stamp seen
        self._set_model(self._full_mask)

    def _kernel_set(self, mask: int) -> S.KernelSet:
        ks = self._packed.get(mask)
        if ks is None:
            ks = S.pack_set(self.cache.get(mask), self.cache.H, np.diag(self._sigma),
                            self._limits.lo, self._limits.hi, self.settings, self.thresholds)
            self._packed[mask] = ks
        return ks

    def _set_model(self, mask: int) -> None:
        self._mask = mask
        self._model = self.cache.get(mask)
        self._kset = self._kernel_set(mask)
        self._state.new_set(self._model.df)
        # what every answer of this set repeats (the status changes only with the set)
        self._healthy_now = self._healthy_array(mask)
        self._status_now = tuple(self._status)
        self._status_detected = tuple("detected" if s == "ok" else s for s in self._status)
        self._omega_sd = self._model.omega_sd
        self._capability = self._model.capability
        self._episode.clear()

    def _healthy_array(self, mask: int) -> np.ndarray:
        a = self._healthy_arr.get(mask)
        if a is None:
            a = np.array([(mask >> i) & 1 == 1 for i in range(self.n)])
            a.setflags(write=False)
            self._healthy_arr[mask] = a
        return a

    @property
    def healthy(self) -> np.ndarray:
        """Current health per sensor, shape (n,)."""
        return self._healthy_array(self._mask).copy()

    @property
    def model(self) -> SetModel:
        """The cached model of the current healthy set."""
        return self._model

    @property
    def detected(self) -> bool:
        """A detection is active (not yet isolated or cleared)."""
        return bool(self._state.counters[S.DETECTED])

    # ------------------------------------------------------------------ step
    def step(self, t: float, raw: Any, valid: Any = None, correction: Any = None,
             envelope: Any = 0) -> Answer:
        """Process one sample; never raises.

        Parameters
        ----------
        t : float
            Time (s).
        raw : array_like, shape (n,)
            Raw sensor outputs.
        valid : array_like of bool, shape (n,), optional
            False where a sensor delivered no sample this time.
        correction : array_like, shape (n,), optional
            Run-time correction of the calibration's effect terms (rad/s), subtracted from
            the compensated outputs: y = SF·u − b − c. A non-finite entry counts as 0; a
            correction of the wrong shape is ignored (no correction).
        envelope : int
            Operating-envelope code of the sample (0: inside; bits of :mod:`fdi.envelope`;
            anything that is not a non-negative integer counts as 0). Out of the envelope the
            monitor detects and reports as usual but excludes nothing on the parity; when
            the envelope is re-entered its windows start afresh (what the excursion put in
            them is not a sensor fault).

        Notes
        -----
        While a detection is active the answer names the suspected sensors (the fault
        hypotheses the data do not reject, :func:`fdi.isolation.decide`), marks the body
        axes a fault on any of them would move as ``unverified`` and gives an infinite
        protection level; a sensor is excluded only when a single hypothesis remains and the
        subset without it passes its own test.
        """
        try:
            tf = float(t)
        except Exception:
            tf = _NAN
        try:
            events = None
            env = env_code(envelope)
            if env != self._env:
                events = []
                self._env_change(tf, env, events)
            u, ok, corr, ev = self._input.read(raw, valid, correction, tf)
            if ev is not None:
                events = ev if events is None else events + ev
            # one sample through the kernel (the same entry point as run's)
            self._t1[0] = tf
            st = self._state
            has_valid = ok is not self._input.all_valid
            if has_valid:                                    # (HAS_VALID only picks the row
                st.counters[S.HAS_VALID] = 1                 # of ``valid``: 0 here either way)
            code = advance(self._t1, u, corr, ok, 0, 1, self._kset.packed, st.values,
                           st.counters, self._row)
            if self._row0[S.TIME_CODE] != self._time_code:  # rare: a time-stamp verdict
                events = [] if events is None else events
                self._time_events(self._t1, self._row[:, S.TIME_CODE], 0, events)
            osd = None
            if code & _STOP_MASK:                            # rare: the monitor's turn
                events = [] if events is None else events
                osd, detected = self._step_stop(code & _STOP_MASK, u, corr, ok, has_valid,
                                                events)
            else:
                detected = code >= _RETURN_DETECTED
            return self._answer(tf, osd, detected, events)
        except Exception as exc:
            return self._internal_error(tf, exc)

    def _answer(self, t: float, osd: np.ndarray | None, detected: bool,
                events: list[Event] | None) -> Answer:
        """The answer to the sample in the kernel's output row (``osd``: its ω̂ sd when it
        is not the model's)."""
        r = self._row0.copy()
        ep = self._episode
        if ep.suspects or self._env:
            r[S.PROTECTION] = _INF                          # not verified: no bound
        o, s0, t0, p0 = self._columns
        return make_answer({
            "t": t, "omega": r[o:o + 3],
            "omega_sd": self._omega_sd if osd is None else osd,
            "healthy": self._healthy_now,
            "status": self._status_detected if detected else self._status_now,
            "parity": r[p0:], "statistics": r[s0:t0], "thresholds": r[t0:p0],
            "events": tuple(events) if events else (), "capability": self._capability,
            "protection_level": float(r[S.PROTECTION]), "envelope": self._env,
            "unverified": ep.unverified, "suspects": ep.suspects,
            "time_status": S.TIME_STATUSES[self._time_code]})

    def _internal_error(self, t: float, exc: Exception) -> Answer:
        """The answer to a sample whose processing failed: NaN rate, an event naming it."""
        self._state.counters[S.PHASE] = S.PHASE_HEALTH
        ev = Event(t, None, "health", f"internal error: {type(exc).__name__}: {exc}")
        return make_answer({
            "t": t, "omega": np.full(3, _NAN), "omega_sd": np.full(3, _NAN),
            "healthy": self._healthy_array(self._mask), "status": tuple(self._status),
            "parity": np.full(max(self.n - 3, 0), _NAN), "statistics": np.full(self.K, _NAN),
            "thresholds": np.full(self.K, _NAN), "events": (ev,),
            "capability": self._model.capability, "protection_level": _INF,
            "envelope": self._env, "unverified": np.ones(3, bool),
            "suspects": self._episode.suspects,
            "time_status": S.TIME_STATUSES[self._time_code]})

    def _step_stop(self, code: int, u: np.ndarray, corr: np.ndarray, ok: np.ndarray,
                   has_valid: bool, events: list[Event]) -> tuple[np.ndarray | None, bool]:
        """The monitor's turn in a step (the kernel stopped at the sample): handle it, run
        the rest of the sample; returns the sample's ω̂ sd when it is not the model's, and
        whether a detection is active."""
        c = self._state.counters
        r, osd = self._handle(int(c[S.STOP_ROW]), code, self._t1, u, corr, ok, has_valid,
                              self._row, events, None)
        if r == 0:
            osd = self._advance(self._t1, u, corr, ok, has_valid, self._row, events, None)
        return osd, c[S.DETECTED] != 0

    # ------------------------------------------------------------------ the loop
    def _advance(self, t: np.ndarray, raw: np.ndarray, corr: np.ndarray, valid: np.ndarray,
                 has_valid: bool, out: np.ndarray, events: list[Event], rows: BlockRows | None,
                 chunk: int = _CHUNK, r0: int = 0, r1: int | None = None
                 ) -> np.ndarray | None:
        """Run the kernel over rows r0 … r1−1 (all by default), handling the samples it hands
        back.

        The counters HAS_VALID, HAS_PARITY and PHASE must be set by the caller.

        Returns the ω̂ standard deviation of the last row when it differs from the model's
        (an incomplete sample), else None.
        """
        N = t.shape[0] if r1 is None else r1
        r = r0
        osd = None
        while r < N:
            r1 = min(N, r + chunk)
            stop, code = self._kernel(t, raw, corr, valid, r, r1, out)
            e = stop + 1 if code != S.STOP_NONE else stop    # rows whose time stamps it read
            tc = out[r:e, S.TIME_CODE]
            if tc.shape[0] and (tc != self._time_code).any():
                self._time_events(t, out[:, S.TIME_CODE], r, events, e)
            if rows is not None:
                self._fill(rows, r, stop)
            r, osd = self._handle(stop, code, t, raw, corr, valid, has_valid, out, events, rows)
        return osd

    def _kernel(self, t: np.ndarray, raw: np.ndarray, corr: np.ndarray, valid: np.ndarray,
                r0: int, r1: int, out: np.ndarray) -> tuple[int, int]:
        """One call of the compiled kernel; returns where and why it stopped."""
        st = self._state
        code = advance(t, raw, corr, valid, r0, r1, self._kset.packed, st.values, st.counters,
                       out)
        return int(st.counters[S.STOP_ROW]), code & S.STOP_MASK

    def _handle(self, stop: int, code: int, t: np.ndarray, raw: np.ndarray, corr: np.ndarray,
                valid: np.ndarray, has_valid: bool, out: np.ndarray, events: list[Event],
                rows: BlockRows | None) -> tuple[int, np.ndarray | None]:
        """Handle the sample the kernel stopped at; returns the next row and the sample's
        ω̂ sd when it is not the model's (incomplete sample)."""
        if code == S.STOP_NONE:
            return stop, None
        c = self._state.counters
        tr = float(t[stop])
        if code == S.STOP_HEALTH:
            self._on_health(tr, raw[stop], events)
            c[S.PHASE] = S.PHASE_READMIT
            return stop, None
        if code == S.STOP_READMIT:
            self._on_readmit(tr, int(c[S.READMIT_SENSOR]), events)
            c[S.PHASE] = S.PHASE_PARITY
            return stop, None
        osd = None
        if code == S.STOP_INCOMPLETE:
            osd = self._on_incomplete(raw, corr, stop, valid[stop if has_valid else 0], out[stop])
        else:                                     # bits: cleared, detected/isolate, vibration
            if code & S.STOP_CLEARED:
                self._episode.clear()
            if code & (S.STOP_DETECTED | S.STOP_ISOLATE):
                self._on_detection(tr, code, raw, corr, stop, out[stop], events)
            if code & S.STOP_VIBRATION:
                self._on_vibration(tr, raw, corr, stop, out[stop], events)
        if rows is not None:
            self._fill(rows, stop, stop + 1, osd)
        return stop + 1, osd

    # ------------------------------------------------------------------ stops
    def _time_events(self, t: np.ndarray, codes: np.ndarray, r0: int, events: list[Event],
                     r1: int | None = None) -> None:
        """Follow the time-stamp verdicts of rows r0 … r1−1 (``codes``, the kernel's output
        column): one ``health`` event where a run of bad time stamps starts or changes its
        kind, and where a new time base is taken (:func:`fdi.kernel.time_check`)."""
        r1 = codes.shape[0] if r1 is None else r1
        last = self._time_code
        for r in range(r0, r1):
            c = int(codes[r])
            if c != last and c != S.TIME_OK:
                events.append(Event(float(t[r]), None, "health",
                                    "time " + S.TIME_STATUSES[c]))
            last = c
        self._time_code = last

    def _isolate(self, i: int, reason: str) -> None:
        self._status[i] = reason
        self._state.sensor[i, S.GOOD_SINCE_T] = _NAN
        self._set_model(self._mask & ~(1 << i))

    def _on_health(self, t: float, u: np.ndarray, events: list[Event]) -> None:
        """Health verdicts of one sample: one event per sensor, isolated in order."""
        st, lim = self._state, self._limits
        for i in range(self.n):
            code = int(st.counters[S.HEALTH0 + i])
            if code == S.HEALTH_OK:
                continue
            if code == S.HEALTH_RANGE and self._env & SATURATION:
                # at a saturation every IMU confirms, a sensor at its range is the envelope,
                # not a fault: kept (the sample is tested, nothing is excluded out of the
                # envelope, and the windows start afresh at re-entry)
                continue
            reason = S.HEALTH_REASON[code]
            if code == S.HEALTH_STUCK:
                value, limit = float(st.sensor[i, S.SAME_RUN]), float(lim.stuck_count)
            elif code == S.HEALTH_STALE:
                value, limit = self._stale_for(t, i), lim.stale_timeout_s
            else:
                value, limit = float(u[i]), lim.hi[i]
            events.append(Event(t, i + 1, "health", reason, value, limit))
            self._isolate(i, reason)

    def _on_vibration(self, t: float, raw: np.ndarray, corr: np.ndarray, r: int,
                      row: np.ndarray, events: list[Event]) -> None:
        """A sensor whose noise along its own parity direction is far above every other's
        (the kernel's vibration test, :func:`fdi.kernel.noise_update`): excluded as a fault
        of its own kind, ``vibration``; ω̂ and PL of the sample from the set left."""
        k = int(self._state.counters[S.VIB_SENSOR])
        if self._env or not (self._mask >> k) & 1:
            return
        vib = self._state.vibration
        others = [float(vib[i]) for i in self._model.idx if i != k]
        events.append(Event(t, k + 1, "isolated", "vibration", float(vib[k]),
                            self.settings.vibration_ratio * max(others) if others else _NAN,
                            envelope=self._env))
        self._isolate(k, "vibration")
        reconstruct_row(raw, corr, r, self._kset.packed, self._state.values, row)

    def _stale_for(self, t: float, i: int) -> float:
        """How long sensor i has been silent (s): since its latest valid sample at a good
        time stamp, or, where that is not known or the time stamps stopped, its missed
        samples times the sample period (the stale clock's two counts)."""
        st = self._state
        fc = self._kset.fconst
        since = t - float(st.sensor[i, S.LAST_VALID_T])
        good = int(st.counters[S.TIME_STATUS]) in (S.TIME_OK, S.TIME_REBASED)
        if good and since > float(fc[S.STALE_TIMEOUT_S]):
            return since
        return float(st.sensor[i, S.MISSED_RUN]) * (float(fc[S.STALE_TIMEOUT_S])
                                                     / float(fc[S.STALE_SAMPLES]))

    def _on_readmit(self, t: float, i: int, events: list[Event]) -> None:
        sen = self._state.sensor
        dwell = t - float(sen[i, S.GOOD_SINCE_T])
        self._status[i] = "ok"
        sen[i, S.SAME_RUN] = 1.0
        sen[i, S.LAST_VALID_T] = t
        sen[i, S.GOOD_SINCE_T] = _NAN
        events.append(Event(t, i + 1, "readmitted", "dwell", dwell,
                            self.settings.readmit_dwell_s))
        self._set_model(self._mask | (1 << i))

    def _on_incomplete(self, raw: np.ndarray, corr: np.ndarray, r: int, ok: np.ndarray,
                       row: np.ndarray) -> np.ndarray:
        """ω̂ from the sensors present; the kernel wrote the untested statistics."""
        present = 0
        for i in self._model.idx:
            if ok[i]:
                present |= 1 << i
        ks = self._kernel_set(present)
        reconstruct_row(raw, corr, r, ks.packed, self._state.values, row)
        row[S.PROTECTION] = _INF
        return self.cache.get(present).omega_sd

    def _on_detection(self, t: float, code: int, raw: np.ndarray, corr: np.ndarray, r: int,
                      row: np.ndarray, events: list[Event]) -> None:
        """Name a detection, test the fault hypotheses (:class:`fdi.episode.Episode`),
        exclude only a verified single sensor; ω̂ and PL of the sample from the new set after
        an exclusion."""
        mdl, st, ep = self._model, self._state, self._episode
        fired = int(st.counters[S.FIRED])
        if code & S.STOP_DETECTED:
            ep.detected(t, st, mdl, row, fired, self._env, events)
        if not code & S.STOP_ISOLATE:
            return
        k = ep.isolation_due(t, st, mdl, row, fired, self._env, events)
        if k is None:
            return
        self._isolate(mdl.idx[k], "isolated")
        reconstruct_row(raw, corr, r, self._kset.packed, st.values, row)

    def _env_change(self, t: float, env: int, events: list[Event]) -> None:
        """Leaving, changing or re-entering the operating envelope."""
        old, self._env = self._env, env
        self._state.counters[S.ENV_OUT] = 1 if env else 0   # the noise levels wait outside
        if env:
            events.append(Event(t, None, "envelope", _env_reason(env), envelope=env))
            return
        events.append(Event(t, None, "envelope", "in", envelope=0))
        if old:                       # back inside: what the excursion put in the windows goes
            c = self._state.counters
            open_ = bool(c[S.DETECTED])
            self._state.new_set(self._model.df)
            if not open_:
                self._episode.clear()
                return
            # a detection open at re-entry stays open on the fresh windows, with its suspects
            # and unverified axes, until every window has filled again and cleared it: an
            # excursion must not make a persisting fault look verified
            c[S.DETECTED] = 1
            c[S.HOLD_OPEN] = max(self._scales)      # the kernel's clear rule waits for it
            self._episode.reopen()                  # the same episode, on fresh windows

    # ------------------------------------------------------------------ block
    def run(self, t: Any, raw: Any, valid: Any = None, *, parity: bool = False,
            chunk: int = _CHUNK, correction: Any = None, envelope: Any = None) -> BlockResult:
        """Process a block of samples; answers bit-identical to :meth:`step` on each row.

        Parameters
        ----------
        t : array_like, shape (N,)
        raw : array_like, shape (N, n)
        valid : array_like of bool, shape (N, n), optional
        parity : bool
            Also return the parity vectors (``BlockResult.parity``; costs memory).
        chunk : int
            Most rows per kernel call.
        correction : array_like, shape (N, n) or (n,), optional
            Run-time correction of the effect terms (rad/s), as in :meth:`step`.
        envelope : array_like of int, shape (N,), optional
            Operating-envelope code per sample, as in :meth:`step` (another shape: ignored,
            every sample inside).

        Returns
        -------
        BlockResult
            Arrays of shape (N, ...) (column views of one row-major output), events in time
            order.
        """
        n = self.n
        try:
            ta = np.ascontiguousarray(np.asarray(t, dtype=float).reshape(-1))
            ra = np.asarray(raw)
            if ra.dtype.kind not in "fiub":         # complex, object, text: as step() does
                raise TypeError(ra.dtype)
            ra = np.ascontiguousarray(ra, dtype=np.float64)
            va = None if valid is None else np.ascontiguousarray(valid, dtype=bool)
            shaped = (ra.ndim == 2 and ra.shape == (ta.shape[0], n)
                      and (va is None or va.shape == ra.shape))
        except (TypeError, ValueError):
            shaped = False
        if not shaped:
            return self._run_rows(t, raw, valid, parity, correction, envelope)
        N = ta.shape[0]
        out = np.empty((N, self._layout.width(parity)))
        rows = BlockRows(N, n)
        events: list[Event] = []
        if N:
            self._input.length_bad = False
            c = self._state.counters
            c[S.HAS_VALID] = va is not None
            c[S.HAS_PARITY] = parity
            c[S.PHASE] = S.PHASE_HEALTH
            corr = self._input.correction(correction, N)
            vv = self._input.all_valid if va is None else va
            try:
                for r0, r1, env in envelope_runs(envelope, N, self._env):
                    if env != self._env:
                        self._env_change(float(ta[r0]), env, events)
                    self._advance(ta, ra, corr, vv, va is not None, out, events, rows,
                                  max(1, int(chunk)), r0, r1)
            finally:
                c[S.HAS_PARITY] = 1                          # step() always fills the parity
                c[S.PHASE] = S.PHASE_HEALTH                  # and starts a sample afresh
        lay = self._layout
        return rows.result(ta, out[:, S.OMEGA0:S.OMEGA0 + 3], out[:, S.STATS0:lay.thresholds0],
                           out[:, lay.thresholds0:lay.parity0], out[:, S.PROTECTION],
                           out[:, lay.parity0:] if parity else None, out[:, S.TIME_CODE],
                           events)

    def _fill(self, rows: BlockRows, r0: int, r1: int, omega_sd: np.ndarray | None = None
              ) -> None:
        """Rows r0 … r1−1 of a block answered by the current set and episode."""
        ep = self._episode
        rows.fill(r0, r1, self._healthy_array(self._mask), self._model.capability,
                  self._model.omega_sd if omega_sd is None else omega_sd, self._env,
                  ep.unverified, not (ep.suspects or self._env))

    def _run_rows(self, t: Any, raw: Any, valid: Any, parity: bool, correction: Any,
                  envelope: Any = None) -> BlockResult:
        """Fallback for blocks of odd shape: step row by row."""
        try:
            rows = list(raw)
        except TypeError:
            rows = []
        try:
            ts = list(np.asarray(t, float).reshape(-1))
        except (TypeError, ValueError):
            ts = [_NAN] * len(rows)
        N = min(len(rows), len(ts))
        vl = None
        if valid is not None:
            try:
                vl = list(valid)
            except TypeError:
                vl = None
        cl = self._input.correction(correction, N) if N else self._input.no_correction
        codes = np.zeros(N, np.int64)
        for r0, r1, e in envelope_runs(envelope, N, 0):
            codes[r0:r1] = e
        answers = [self.step(ts[r], rows[r], vl[r] if vl is not None and r < len(vl) else None,
                             cl[r if cl.shape[0] > 1 else 0], int(codes[r]))
                   for r in range(N)]
        return block_from_answers(answers, self.n, self.K, parity)


def _env_reason(code: int) -> str:
    """Why a sample is out of the envelope: the names of its bits, "shock+tumble"."""
    return "+".join(reason_names(code))
