"""The streaming parity-space monitor: detect, isolate by zeroing rows of H, reconstruct.

One sample of n raw sensor outputs in, one :class:`fdi.answer.Answer` out
(:meth:`Monitor.step`); or a whole block (:meth:`Monitor.run`) with bit-identical answers.

Per sample, with the healthy set's cached :class:`fdi.reconstruction.SetModel`:

1. Health checks (stale, non-finite, range, stuck) isolate at once (:mod:`fdi.health`).
2. Compensation y = SF·u − b, parity p = V·y, whitened parity z = A·p (Cov z = I),
   reconstruction ω̂ = G·y and the calibration-uncertainty ratio ρ = max_i ω̂ᵀC_iω̂/Σ_ii
   (one generated straight-line kernel per set; :mod:`fdi.reconstruction`).
3. Windows: cumulative sums c_t of z and of ρ since the set began, a ring of the last 2^K
   of them; the sum over the last w samples is ``c_t − c_{t−w}`` (O(1) per scale). Per
   scale ``D_w = |Σz|²/(w f_w)`` against ``T_w · (1 + w·β/f_w + κ/f_w · Σρ)``: the
   calibration's own error adds ``V diag(ω̂ᵀC_iω̂) Vᵀ ≼ ρ κ VΣVᵀ`` (input_error_cov) and a
   constant offset ``V diag(bias_sd²) Vᵀ ≼ β·VΣVᵀ`` (in whitened units) to the covariance
   of the window mean; neither averages down, so the threshold grows with the window and
   with the rate (ρ averaged over the window bounds ρ of the window-mean rate, by
   convexity). Clearing (hysteresis) compares with ``clear_ratio`` × the base threshold.
4. Optional CUSUM bank on the unit whitened projections r_i = u_iᵀz/|u_i| (two sides per
   sensor, allowance ν + 3·sqrt(κρ + β)); computed as S_t − min_{s≤t} S_s so that the block path
   can use cumulative sums and running minima with the same arithmetic.
5. Detection state machine: the first alarm emits ``"detected"``; after ``persistence``
   consecutive alarms a set that can isolate isolates the GLT sensor at the scale with the
   largest D/T (``"isolated"``, with the magnitude); a set that cannot stays "detected"
   until every statistic has stayed below ``clear_ratio × threshold`` for ``clear_samples``
   samples (hysteresis: one event per onset, no flapping).

Samples in which a healthy sensor is missing (``valid = False``) give ω̂ from the sensors
present, do not enter the windows (windows count complete samples) and carry an infinite
protection level (no parity test was possible).

Block path: segments of samples that share a healthy set and cause no state change are
computed with numpy — the same generated kernel on columns, ``np.cumsum`` (sequential) for
the cumulative sums — and every sample that changes state (an event, a missing sensor, a
health trigger, a detection clearing) goes through the step code. Elementwise IEEE
operations in the same order give the same bits.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from fdi.answer import CAPABILITIES, Answer, BlockResult, Event
from fdi.calfile import Calibration
from fdi.detector import default_thresholds
from fdi.errors import ConfigError
from fdi.health import first_trigger, health_limits
from fdi.isolation import isolate, magnitude
from fdi.reconstruction import SetCache, SetModel
from fdi.settings import MonitorSettings, Thresholds

__all__ = ["Monitor"]

_NAN = float("nan")
_INF = float("inf")
_CHUNK = 1 << 13


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
        self._sf = s.scale_factors
        self._bias = s.biases
        self._sigma = np.asarray(s.noise_covariance, float)
        bsd = np.array([c.bias_sd for c in s.sensors], float)
        self.cache = SetCache(s.H, self._sf, self._bias, self._sigma, cin, self.thresholds, md,
                              bsd)
        self.cache.precompute(max(self.n - 2, 0))        # bounded step time through two isolations
        self._lim = health_limits(self.settings, kind, self._sf, self._bias)
        th = self.thresholds
        self._scales = tuple(int(w) for w in th.scales)
        self._R = max(self._scales) + 1
        self._cusum = th.detector != "windows"
        self._nu = float(th.cusum_drift)
        self.K = len(self._scales) + (1 if self._cusum else 0)
        self._full_mask = (1 << self.n) - 1
        self._healthy_arr: dict[int, np.ndarray] = {}
        self._alltrue = [True] * self.n
        self.reset()

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Back to the state after construction (all sensors healthy, empty windows)."""
        self._started = False
        self._status = ["ok"] * self.n
        self._last = [_NAN] * self.n
        self._run = [0] * self.n
        self._lvt = [_NAN] * self.n
        self._good_since: list[float | None] = [None] * self.n
        self._length_bad = False
        self._set_model(self._full_mask)

    def _set_model(self, mask: int) -> None:
        self._mask = mask
        mdl = self.cache.get(mask)
        self._model = mdl
        df = mdl.df
        self._c = [0.0] * (df + 1)                          # cumulative z (df) and ρ
        self._ring: list[Any] = [[0.0] * (df + 1) for _ in range(self._R)]
        self._pos = 0
        self._count = 0
        m = mdl.m
        self._sp = [0.0] * m                                # CUSUM sums and running minima
        self._mp = [0.0] * m
        self._sm = [0.0] * m
        self._mm = [0.0] * m
        self._det = False
        self._det_rows = 0
        self._run_alarm = 0
        self._run_clear = 0
        self._cr = [self.settings.clear_ratio * t for t in mdl.thr]
        self._crh = self.settings.clear_ratio * mdl.cusum_h
        self._nanpad = [_NAN] * (max(self.n - 3, 0) - df)

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

    # ------------------------------------------------------------------ input
    def _parse(self, raw: Any, valid: Any, t: float, events: list[Event]
               ) -> tuple[list[float], list[bool]]:
        n = self.n
        vals: list[float] | None = None
        try:
            if type(raw) is np.ndarray and raw.shape == (n,) and raw.dtype.kind == "f":
                vals = raw.tolist()
            else:
                seq = list(raw)
                if len(seq) == n:
                    vals = []
                    for x in seq:
                        try:
                            vals.append(_NAN if isinstance(x, complex) else float(x))
                        except (TypeError, ValueError, OverflowError):
                            vals.append(_NAN)
        except Exception:
            vals = None
        ok: list[bool] | None
        if valid is None:
            ok = self._alltrue
        else:
            try:
                if type(valid) is np.ndarray and valid.shape == (n,):
                    ok = valid.astype(bool, copy=False).tolist()
                else:
                    ok = [bool(v) for v in valid]
                    if len(ok) != n:
                        ok = None
            except Exception:
                ok = None
        if vals is None or ok is None:
            if not self._length_bad:
                events.append(Event(t, None, "health", "length"))
            self._length_bad = True
            return [_NAN] * n, [False] * n
        self._length_bad = False
        return vals, ok

    # ------------------------------------------------------------------ step
    def step(self, t: float, raw: Any, valid: Any = None) -> Answer:
        """Process one sample; never raises.

        Parameters
        ----------
        t : float
            Time (s).
        raw : array_like, shape (n,)
            Raw sensor outputs.
        valid : array_like of bool, shape (n,), optional
            False where a sensor delivered no sample this time.
        """
        try:
            tf = float(t)
        except Exception:
            tf = _NAN
        try:
            return self._step(tf, raw, valid)[0]
        except Exception as exc:
            ev = Event(tf, None, "health", f"internal error: {type(exc).__name__}: {exc}")
            return Answer(tf, np.full(3, _NAN), np.full(3, _NAN),
                          self._healthy_array(self._mask), tuple(self._status),
                          np.full(max(self.n - 3, 0), _NAN), np.full(self.K, _NAN),
                          np.full(self.K, _NAN), (ev,), self._model.capability, _INF)

    def _isolate(self, i: int, reason: str) -> None:
        self._status[i] = reason
        self._good_since[i] = None
        self._set_model(self._mask & ~(1 << i))

    def _step(self, t: float, raw: Any, valid: Any) -> tuple[Answer, list[float], list[float],
                                                             list[float], float]:
        events: list[Event] = []
        vals, ok = self._parse(raw, valid, t, events)
        if not self._started:
            self._started = True
            self._lvt = [t] * self.n
        lim = self._lim
        lo, hi = lim.lo, lim.hi
        last, run, lvt = self._last, self._run, self._lvt
        # 1. health checks
        for i in self._model.idx:
            if ok[i]:
                v = vals[i]
                if not (lo[i] < v < hi[i]):
                    reason = "range" if math.isfinite(v) else "nonfinite"
                    events.append(Event(t, i + 1, "health", reason, v, hi[i]))
                    self._isolate(i, reason)
                    continue
                if v == last[i]:
                    run[i] += 1
                    if run[i] >= lim.stuck_count:
                        events.append(Event(t, i + 1, "health", "stuck", float(run[i]),
                                            float(lim.stuck_count)))
                        self._isolate(i, "stuck")
                        continue
                else:
                    run[i] = 1
                    last[i] = v
                # latest valid time: a timestamp that goes backwards (or is NaN) must not
                # reset the stale clock of every sensor
                if t > lvt[i] or lvt[i] != lvt[i]:
                    lvt[i] = t
            elif t - lvt[i] > lim.stale_timeout_s:
                events.append(Event(t, i + 1, "health", "stale", t - lvt[i],
                                    lim.stale_timeout_s))
                self._isolate(i, "stale")
        if self.settings.readmission:
            self._readmission(t, vals, ok, events)
        mdl = self._model
        complete = True
        for i in mdl.idx:
            if not ok[i]:
                complete = False
                break
        K = self.K
        if not complete:
            amask = 0
            for i in mdl.idx:
                if ok[i]:
                    amask |= 1 << i
            av = self.cache.get(amask)
            if av.capability != "none":
                _, _, w, rho = av.kernel(*vals)
                osd = av.omega_sd
            else:
                w, rho, osd = (_NAN, _NAN, _NAN), _NAN, av.omega_sd
            stats = [_NAN] * K
            thrs = list(mdl.thr) + ([mdl.cusum_h] if self._cusum else [])
            ans = self._answer(t, w, osd, [_NAN] * max(self.n - 3, 0), stats, thrs, events,
                               _INF)
            return ans, stats, thrs, [_NAN] * max(self.n - 3, 0), _INF
        p, z, w, rho = mdl.kernel(*vals)
        if w is None:
            w = (_NAN, _NAN, _NAN)
        df = mdl.df
        if df > 0:
            stats, thrs, alarm, clear, fired = self._windows(mdl, z, rho)
            par = list(p) + self._nanpad
            self._machine(t, mdl, alarm, clear, fired, stats, thrs, events)
            if self._model is not mdl:                      # isolated: ω̂ from the new set
                new = self._model
                if new.capability != "none":
                    _, _, w, rho = new.kernel(*vals)
                else:
                    w, rho = (_NAN, _NAN, _NAN), _NAN
        else:
            stats = [_NAN] * K
            thrs = list(mdl.thr) + ([mdl.cusum_h] if self._cusum else [])
            par = [_NAN] * max(self.n - 3, 0)
        pl = self._model.pl(rho)
        ans = self._answer(t, w, self._model.omega_sd, par, stats, thrs, events, pl)
        return ans, stats, thrs, par, pl

    def _answer(self, t: float, w: Any, osd: np.ndarray, par: list[float], stats: list[float],
                thrs: list[float], events: list[Event], pl: float) -> Answer:
        mdl = self._model
        if self._det:
            status = tuple("detected" if s == "ok" else s for s in self._status)
        else:
            status = tuple(self._status)
        return Answer(t, np.array(w, dtype=float), osd, self._healthy_array(self._mask),
                      status, np.array(par), np.array(stats), np.array(thrs),
                      tuple(events), mdl.capability, pl)

    def _windows(self, mdl: SetModel, z: tuple[float, ...], rho: float
                 ) -> tuple[list[float], list[float], bool, bool, int]:
        """Update cumulative sums and evaluate every scale (and the CUSUM bank)."""
        df = mdl.df
        c = self._c
        for j in range(df):
            c[j] = c[j] + z[j]
        c[df] = c[df] + rho
        self._count += 1
        count = self._count
        R = self._R
        pos = self._pos + 1
        if pos == R:
            pos = 0
        self._pos = pos
        ring = self._ring
        ring[pos] = list(c)
        stats: list[float] = []
        thrs: list[float] = []
        alarm = False
        clear = True
        fired = -1
        best = 0.0
        thr, invwf, kof, obw, cr = mdl.thr, mdl.invwf, mdl.kof, mdl.one_bw, self._cr
        crho = c[df]
        for k, w in enumerate(self._scales):
            if count >= w:
                old = ring[pos - w]                         # negative index wraps the ring
                d = c[0] - old[0]
                acc = d * d
                for j in range(1, df):
                    d = c[j] - old[j]
                    acc = acc + d * d
                D = acc * invwf[k]
                T = thr[k] * (obw[k] + kof[k] * (crho - old[df]))
                if D > T:
                    alarm = True
                    if D / T > best:
                        best = D / T
                        fired = k
                if D >= cr[k]:
                    clear = False
            else:
                D = _NAN
                T = thr[k]
            stats.append(D)
            thrs.append(T)
        if self._cusum:
            r = mdl.proj(*z)
            drift = self._nu + 3.0 * math.sqrt(mdl.kappa * rho + mdl.beta)
            sp, mp, sm, mm = self._sp, self._mp, self._sm, self._mm
            g = 0.0
            for i in range(mdl.m):
                a = sp[i] + (r[i] - drift)
                sp[i] = a
                b = mp[i]
                if a < b:
                    mp[i] = a
                    b = a
                gi = a - b
                a2 = sm[i] + (-r[i] - drift)
                sm[i] = a2
                b2 = mm[i]
                if a2 < b2:
                    mm[i] = a2
                    b2 = a2
                g2 = a2 - b2
                if gi > g:
                    g = gi
                if g2 > g:
                    g = g2
            h = mdl.cusum_h
            stats.append(g)
            thrs.append(h)
            if g > h:
                alarm = True
                if g / h > best:
                    fired = len(self._scales)
            if g >= self._crh:
                clear = False
        return stats, thrs, alarm, clear, fired

    def _machine(self, t: float, mdl: SetModel, alarm: bool, clear: bool, fired: int,
                 stats: list[float], thrs: list[float], events: list[Event]) -> None:
        """Detection state machine for one complete sample (see module docstring)."""
        if not self._det:
            if not alarm:
                return
            self._det = True
            self._det_rows = 1
            self._run_alarm = 1
            self._run_clear = 0
            sensor, mag, reason, scale = self._attribute(mdl, fired)
            events.append(Event(t, sensor if mdl.capability == "isolate" else None, "detected",
                                reason, stats[fired], thrs[fired], scale,
                                mag if mdl.capability == "isolate" else None))
        else:
            self._det_rows += 1
            self._run_alarm = self._run_alarm + 1 if alarm else 0
            self._run_clear = self._run_clear + 1 if clear else 0
        if mdl.capability == "isolate" and self._run_alarm >= self.settings.persistence:
            sensor, mag, reason, scale = self._attribute(mdl, fired)
            events.append(Event(t, sensor, "isolated", reason, stats[fired], thrs[fired],
                                scale, mag))
            if sensor is not None:
                self._isolate(sensor - 1, "isolated")
        elif self._det and self._run_clear >= self.settings.clear_samples:
            self._det = False

    def _window_sum(self, w: int) -> np.ndarray:
        df = self._model.df
        old = self._ring[self._pos - w]
        return np.array([self._c[j] - old[j] for j in range(df)])

    def _attribute(self, mdl: SetModel, fired: int) -> tuple[int | None, float | None, str,
                                                            int | None]:
        """GLT sensor (1-based), magnitude (SI), reason and window of the scale that fired."""
        ns = len(self._scales)
        if fired >= ns:                                     # the CUSUM bank fired
            g = [max(self._sp[i] - self._mp[i], self._sm[i] - self._mm[i])
                 for i in range(mdl.m)]
            k = int(np.argmax(g))
            reason, scale = "cusum", None
        else:
            w = self._scales[fired]
            k, _ = isolate(mdl.U, self._window_sum(w), w)
            reason, scale = f"parity scale {w}", w
        # magnitude from the longest window that lies within the detection episode
        wm = 0
        for w in self._scales:
            if w <= max(self._det_rows, 1) and w <= self._count:
                wm = w
        mag = magnitude(mdl.U, self._window_sum(wm), wm, k) if wm else None
        return mdl.idx[k] + 1, mag, reason, scale

    def _readmission(self, t: float, vals: list[float], ok: list[bool],
                     events: list[Event]) -> None:
        """Re-admit isolated sensors that behaved for ``readmit_dwell_s`` (opt-in)."""
        mdl = self._model
        if mdl.capability == "none" or self._det:
            return
        lim = self._lim
        if not all(ok[i] for i in mdl.idx):
            return
        _, _, w, _ = mdl.kernel(*vals)
        if w is None:
            return
        H = self.cache.H
        for i in range(self.n):
            if (self._mask >> i) & 1:
                continue
            v = vals[i]
            good = bool(ok[i]) and lim.lo[i] < v < lim.hi[i] and v != self._last[i]
            if good:
                y = self._sf[i] * v - self._bias[i]
                hw = H[i] @ np.asarray(w)
                var = self._sigma[i, i] + float(H[i] @ mdl.cov @ H[i])
                good = (y - hw) ** 2 < 9.0 * var
            self._last[i] = v
            if not good:
                self._good_since[i] = None
            elif self._good_since[i] is None:
                self._good_since[i] = t
            elif t - self._good_since[i] >= self.settings.readmit_dwell_s:
                dwell = t - self._good_since[i]
                self._status[i] = "ok"
                self._run[i] = 1
                self._lvt[i] = t
                self._good_since[i] = None
                events.append(Event(t, i + 1, "readmitted", "dwell", dwell,
                                    self.settings.readmit_dwell_s))
                self._set_model(self._mask | (1 << i))
                return

    # ------------------------------------------------------------------ block
    def run(self, t: Any, raw: Any, valid: Any = None, *, parity: bool = False,
            chunk: int = _CHUNK) -> BlockResult:
        """Process a block of samples; answers bit-identical to :meth:`step` on each row.

        Parameters
        ----------
        t : array_like, shape (N,)
        raw : array_like, shape (N, n)
        valid : array_like of bool, shape (N, n), optional
        parity : bool
            Also return the parity vectors (``BlockResult.parity``; costs memory).
        chunk : int
            Rows per vectorised piece (bounds memory and wasted work after an event).

        Returns
        -------
        BlockResult
            Arrays of shape (N, ...) (views of transposed storage), events in time order.
        """
        n, K = self.n, self.K
        try:
            ta = np.asarray(t, dtype=float).reshape(-1)
            ra = np.asarray(raw)
            if ra.dtype.kind not in "fiub":         # complex, object, text: as step() does
                raise TypeError(ra.dtype)
            ra = ra.astype(float, copy=False)
            va = None if valid is None else np.asarray(valid, dtype=bool)
            shaped = (ra.ndim == 2 and ra.shape == (ta.shape[0], n)
                      and (va is None or va.shape == ra.shape))
        except (TypeError, ValueError):
            shaped = False
        if not shaped:
            return self._run_rows(t, raw, valid, parity)
        if va is not None and va.all():
            va = None
        N = ta.shape[0]
        out = _Out(N, n, K, parity)
        chunk = max(1, int(chunk))
        r = 0
        while r < N:
            if not self._started or (self.settings.readmission
                                     and self._mask != self._full_mask):
                self._scalar_row(out, r, ta[r], ra[r], None if va is None else va[r])
                r += 1
                continue
            end = min(N, r + chunk)
            e = self._segment(out, ta, ra, va, r, end)
            if e < end:
                self._scalar_row(out, e, ta[e], ra[e], None if va is None else va[e])
                e += 1
            r = e
        return out.result(ta)

    def _run_rows(self, t: Any, raw: Any, valid: Any, parity: bool) -> BlockResult:
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
        out = _Out(N, self.n, self.K, parity)
        vl = None
        if valid is not None:
            try:
                vl = list(valid)
            except TypeError:
                vl = None
        for r in range(N):
            v = vl[r] if vl is not None and r < len(vl) else None
            self._scalar_row(out, r, ts[r], rows[r], v)
        return out.result(np.asarray(ts[:N], float))

    def _scalar_row(self, out: _Out, r: int, t: float, raw: Any, valid: Any) -> None:
        try:
            tf = float(t)
        except Exception:
            tf = _NAN
        ans, stats, thrs, par, pl = self._step(tf, raw, valid)
        out.omega[:, r] = ans.omega
        out.omega_sd[:, r] = ans.omega_sd
        out.healthy[r] = ans.healthy
        out.statistics[:, r] = stats
        out.thresholds[:, r] = thrs
        if out.parity is not None:
            out.parity[:, r] = par
        out.pl[r] = pl
        out.cap[r] = _CAP_CODE[ans.capability]
        out.events.extend(ans.events)

    def _segment(self, out: _Out, ta: np.ndarray, ra: np.ndarray, va: np.ndarray | None,
                 r0: int, r1: int) -> int:
        """Vectorised rows r0 ... e−1 of one healthy set without state changes; returns e.

        Writes its outputs straight into ``out`` (rows from e on are overwritten by what
        follows) and commits the state of rows < e.
        """
        mdl = self._model
        idx = mdl.idx
        il = list(idx)
        n = self.n
        e = r1 - r0
        Ub = ra[r0:r1]
        if va is not None and idx:
            inc = ~va[r0:r1, il].all(axis=1)
            if inc.any():
                e = int(np.argmax(inc))
        if e == 0:
            return r0
        # health checks (values, stuck) on every healthy sensor at once
        run = None
        if idx:
            lim = self._lim
            row, run = first_trigger(Ub[:e] if len(il) == n else Ub[:e, il],
                                     np.array([lim.lo[i] for i in il]),
                                     np.array([lim.hi[i] for i in il]),
                                     np.array([self._last[i] for i in il]),
                                     np.array([self._run[i] for i in il]), lim.stuck_count)
            if row < e:
                e = row
                if e == 0:
                    return r0
        cols = [Ub[:e, i] for i in range(n)]
        p, z, w, rho = mdl.kernel_vec(*cols)
        df = mdl.df
        ns = len(self._scales)
        sl = slice(r0, r0 + e)
        stats = out.statistics[:, sl]
        thrs = out.thresholds[:, sl]
        if df > 0:
            R = self._R
            M = np.empty((df + 1, e + 1))
            M[:, 0] = self._c
            for j in range(df):
                M[j, 1:] = z[j]
            M[df, 1:] = rho
            C = np.cumsum(M, axis=1)                        # sequential, as c = c + z
            ring = self._ring
            pos = self._pos
            ext = np.empty((df + 1, R + e))
            ext[:, :R] = np.array(ring[pos + 1:] + ring[:pos + 1]).T
            ext[:, R:] = C[:, 1:]
            cur = ext[:, R:]
            count0 = self._count
            alarm = np.zeros(e, bool)
            noclear = np.zeros(e, bool)
            d = np.empty(e)
            acc = np.empty(e)
            bb = np.empty(e, bool)
            for k, wl in enumerate(self._scales):
                old = ext[:, R - wl:R - wl + e]
                np.subtract(cur[0], old[0], out=d)
                np.multiply(d, d, out=acc)
                for j in range(1, df):
                    np.subtract(cur[j], old[j], out=d)
                    np.multiply(d, d, out=d)
                    np.add(acc, d, out=acc)
                D = stats[k]
                T = thrs[k]
                np.multiply(acc, mdl.invwf[k], out=D)
                np.subtract(cur[df], old[df], out=T)
                np.multiply(T, mdl.kof[k], out=T)
                np.add(T, mdl.one_bw[k], out=T)
                np.multiply(T, mdl.thr[k], out=T)
                nf = min(e, max(0, wl - count0 - 1))       # windows not yet full
                if nf:
                    D[:nf] = _NAN
                    T[:nf] = mdl.thr[k]
                np.greater(D, T, out=bb)
                alarm |= bb
                np.greater_equal(D, self._cr[k], out=bb)
                noclear |= bb
            if self._cusum:
                rr = mdl.proj(*z)
                drift = self._nu + 3.0 * np.sqrt(mdl.kappa * rho + mdl.beta)
                m = mdl.m
                X1 = np.empty((m, e + 1))
                X2 = np.empty((m, e + 1))
                X1[:, 0] = self._sp
                X2[:, 0] = self._sm
                for i in range(m):
                    np.subtract(rr[i], drift, out=X1[i, 1:])
                    np.subtract(-rr[i], drift, out=X2[i, 1:])
                np.cumsum(X1, axis=1, out=X1)               # sequential, as s = s + x
                np.cumsum(X2, axis=1, out=X2)
                Y1 = X1.copy()
                Y2 = X2.copy()
                Y1[:, 0] = self._mp
                Y2[:, 0] = self._mm
                np.minimum.accumulate(Y1, axis=1, out=Y1)
                np.minimum.accumulate(Y2, axis=1, out=Y2)
                np.subtract(X1, Y1, out=Y1)
                np.subtract(X2, Y2, out=Y2)
                np.maximum(Y1, Y2, out=Y1)
                g = Y1[:, 1:].max(axis=0)
                np.maximum(g, 0.0, out=g)
                cus_state = (X1, X2)
                stats[ns] = g
                thrs[ns] = mdl.cusum_h
                alarm |= g > mdl.cusum_h
                noclear |= g >= self._crh
            # detection state machine: first row that changes state
            if not self._det:
                tr = int(np.argmax(alarm)) if alarm.any() else e
                ra_arr = rc_arr = None
            else:
                ii1 = np.arange(e)
                lf = np.maximum.accumulate(np.where(alarm, -1, ii1))
                ra_arr = np.where(lf < 0, self._run_alarm + ii1 + 1, ii1 - lf)
                lc = np.maximum.accumulate(np.where(noclear, ii1, -1))
                rc_arr = np.where(lc < 0, self._run_clear + ii1 + 1, ii1 - lc)
                trig2 = rc_arr >= self.settings.clear_samples
                if mdl.capability == "isolate":
                    trig2 |= ra_arr >= self.settings.persistence
                tr = int(np.argmax(trig2)) if trig2.any() else e
            if tr < e:
                e = tr
                if e == 0:
                    return r0
            # commit rows [0, e)
            self._c = C[:, e].tolist()
            self._ring = ext[:, e:e + R].T.tolist()
            self._pos = R - 1
            self._count += e
            if self._cusum:
                X1, X2 = cus_state                          # running minima: exact
                self._sp = X1[:, e].tolist()
                self._mp = np.minimum(X1[:, 1:e + 1].min(axis=1), self._mp).tolist()
                self._sm = X2[:, e].tolist()
                self._mm = np.minimum(X2[:, 1:e + 1].min(axis=1), self._mm).tolist()
            if self._det:
                self._det_rows += e
                self._run_alarm = int(ra_arr[e - 1])
                self._run_clear = int(rc_arr[e - 1])
            if out.parity is not None:
                for j in range(df):
                    out.parity[j, r0:r0 + e] = p[j][:e]
        else:
            stats[:, :e] = _NAN
            thrs[:, :e] = np.array(list(mdl.thr) + ([mdl.cusum_h] if self._cusum else []))[:, None]
        sl = slice(r0, r0 + e)
        # health bookkeeping of the committed rows
        t_latest = float(np.fmax.reduce(ta[r0:r0 + e]))   # same rule as in _step
        for k, i in enumerate(il):
            self._run[i] = int(run[e - 1, k]) if run is not None else 1
            self._last[i] = float(Ub[e - 1, i])
            if t_latest > self._lvt[i] or self._lvt[i] != self._lvt[i]:
                self._lvt[i] = t_latest
        if w is None:
            out.omega[:, sl] = _NAN
        else:
            for a in range(3):
                out.omega[a, sl] = w[a][:e]
        rho_e = rho[:e] if isinstance(rho, np.ndarray) else np.full(e, float(rho))
        pl = mdl.pl
        t1 = out.pl[sl]
        np.multiply(rho_e, pl.b, out=t1)
        np.add(t1, 1.0, out=t1)
        np.sqrt(t1, out=t1)
        np.multiply(t1, pl.a, out=t1)
        t2 = np.multiply(rho_e, pl.e)
        np.add(t2, pl.d, out=t2)
        np.sqrt(t2, out=t2)
        np.multiply(t2, pl.c, out=t2)
        np.add(t1, t2, out=t1)
        out.omega_sd[:, sl] = mdl.omega_sd[:, None]
        out.healthy[sl] = self._healthy_array(self._mask)
        out.cap[sl] = _CAP_CODE[mdl.capability]
        return r0 + e


_CAP_CODE = {c: k for k, c in enumerate(CAPABILITIES)}
_CAP_NAMES = np.array(CAPABILITIES, dtype=object)


class _Out:
    """Preallocated block outputs, stored transposed (rows contiguous per quantity)."""

    def __init__(self, N: int, n: int, K: int, parity: bool = True) -> None:
        self.omega = np.empty((3, N))
        self.omega_sd = np.empty((3, N))
        self.healthy = np.empty((N, n), bool)
        self.statistics = np.empty((K, N))
        self.thresholds = np.empty((K, N))
        self.parity = np.full((max(n - 3, 0), N), _NAN) if parity else None
        self.pl = np.empty(N)
        self.cap = np.empty(N, np.int8)
        self.events: list[Event] = []

    def result(self, t: np.ndarray) -> BlockResult:
        return BlockResult(t=np.asarray(t, float), omega=self.omega.T, omega_sd=self.omega_sd.T,
                           healthy=self.healthy, statistics=self.statistics.T,
                           thresholds=self.thresholds.T, protection_level=self.pl,
                           capability=_CAP_NAMES[self.cap], events=self.events,
                           parity=None if self.parity is None else self.parity.T)
