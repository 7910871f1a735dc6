"""A plain-numpy reference monitor: the detector's definitions, one sample at a time.

Test oracle for the compiled kernel (:mod:`fdi.kernel`). It shares with the product only
the per-set matrices (V, A, U, G, κ, β, the protection-level constants, built by
:func:`fdi.reconstruction.build_set_model` and checked on their own in ``test_monitor``)
and the threshold functions. Everything the kernel does differently is written here from
the definitions instead:

- windows as direct sums over the last w complete samples (the kernel: differences of
  cumulative sums in a ring);
- ρ as max_i [ω̂ᵀC_iω̂ + τ_i²(h_iᵀω̇̂)²]/Σ_ii from the 3×3 input-error covariances and
  the timing jitters, ω̇̂ = (ω̂_t − ω̂_{t−1})·fs from the ω̂ the oracle answered last (0 when
  not finite) (the kernel: six packed coefficients, one jitter coefficient, ω̂_{t−1} in its
  state);
- the CUSUM as Page's recursion g = max(0, g + x) (the kernel: S − min S);
- the health checks, the state machine and the attribution as numpy/Python;
- the isolation decision from its definition: each single-sensor hypothesis fitted to the
  normalised window sum by least squares (``numpy.linalg.lstsq``), rejected when its
  residual exceeds χ²_{df−1} isf(P_we/(m − 1)); exclusion when one hypothesis remains and
  its own residual passes the subset test (the kernel side: projections,
  :func:`fdi.isolation.decide`).

Re-admission (opt-in) is not modelled.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import stats as sstats

from fdi.detector import chi2_threshold, cusum_threshold
from fdi.health import health_limits
from fdi.reconstruction import SetCache


@dataclass
class OracleSample:
    """The oracle's answer to one sample (the fields of :class:`fdi.answer.Answer`)."""

    omega: np.ndarray
    omega_sd: np.ndarray
    healthy: np.ndarray
    statistics: np.ndarray
    thresholds: np.ndarray
    parity: np.ndarray
    protection_level: float
    capability: str
    events: list = field(default_factory=list)   # (type, sensor, reason, stat, thr, mag)


class OracleMonitor:
    """Reference of :class:`fdi.monitor.Monitor` (same constructor inputs)."""

    def __init__(self, cal, thresholds, settings, kind: str = "gyro") -> None:
        s = cal.kind(kind)
        self.n = s.n
        self.sf = np.asarray(s.scale_factors, float)
        self.bias = np.asarray(s.biases, float)
        self.sigma = np.asarray(s.noise_covariance, float)
        self.cin = np.array([np.asarray(c.input_error_cov, float) for c in s.sensors])
        self.tau = np.array([c.timing_jitter for c in s.sensors], float)
        self.H = np.asarray(s.H, float)
        self.fs = float(thresholds.sample_rate_hz)
        self.w_prev = np.full(3, np.nan)
        self.th = thresholds
        self.settings = settings
        md = settings.missed_detection or thresholds.missed_detection
        self.cache = SetCache(s.H, self.sf, self.bias, self.sigma, self.cin, thresholds, md,
                              np.array([c.bias_sd for c in s.sensors], float),
                              wrong_exclusion=settings.wrong_exclusion,
                              isolation_ratio=settings.isolation_ratio,
                              timing_jitter=self.tau)
        self.names = [c.name for c in s.sensors]
        self.lim = health_limits(settings, kind, self.sf, self.bias)
        self.scales = [int(w) for w in thresholds.scales]
        self.cusum = thresholds.detector != "windows"
        self.K = len(self.scales) + int(self.cusum)
        self.healthy = np.ones(self.n, bool)
        self.last = np.full(self.n, np.nan)
        self.run = np.zeros(self.n)
        self.lvt = None
        self._new_set()

    # ------------------------------------------------------------ set and state
    def _mask(self, healthy: np.ndarray) -> int:
        return int(sum(1 << i for i in range(self.n) if healthy[i]))

    def _new_set(self) -> None:
        self.model = self.cache.get(self._mask(self.healthy))
        self.hist_z: list[np.ndarray] = []
        self.hist_rho: list[float] = []
        m = self.model.m
        self.g_up = np.zeros(m)
        self.g_down = np.zeros(m)
        self.detected = False
        self.det_rows = self.alarm_run = self.clear_run = 0
        self.suspects: tuple[int, ...] = ()
        self.no_fit = False
        self.due = 0
        self.rows_seen = 0
        self.fresh = False

    def _base_thresholds(self) -> np.ndarray:
        df = self.model.df
        thr = [chi2_threshold(a, df) if df > 0 else np.inf for a in self.th.alpha]
        return np.array(thr + ([self._h()] if self.cusum else []))

    def _h(self) -> float:
        if self.model.df < 1 or not self.cusum:
            return np.nan
        return cusum_threshold(self.th.alpha[0], self.th.cusum_drift, 2 * self.model.m)

    def _reconstruct(self, model, u: np.ndarray) -> tuple[np.ndarray, float]:
        """ω̂ = G·y over the set's sensors and
        ρ = max_i [ω̂ᵀC_iω̂ + τ_i²(h_iᵀω̇̂)²]/Σ_ii (≥ 0), ω̇̂ = (ω̂ − ω̂_{t−1})·fs."""
        if model.capability == "none":
            return np.full(3, np.nan), 0.0
        idx = list(model.idx)
        y = self.sf[idx] * u[idx] - self.bias[idx]
        w = model.G[:, idx] @ y
        wdot = (w - self.w_prev) * self.fs
        if not np.all(np.isfinite(wdot)):
            wdot = np.zeros(3)
        rho = max([0.0] + [(float(w @ self.cin[i] @ w)
                            + self.tau[i] ** 2 * float(self.H[i] @ wdot) ** 2)
                           / self.sigma[i, i] for i in idx])
        return w, rho

    # ------------------------------------------------------------ one sample
    def step(self, t: float, u: np.ndarray, ok: np.ndarray) -> OracleSample:
        out = self._step(t, u, ok)
        self.w_prev = np.asarray(out.omega, float).copy()
        return out

    def _step(self, t: float, u: np.ndarray, ok: np.ndarray) -> OracleSample:
        u = np.asarray(u, float)
        ok = np.asarray(ok, bool)
        if self.lvt is None:
            self.lvt = np.full(self.n, t)
        events = self._health(t, u, ok)
        mdl = self.model
        idx = list(mdl.idx)
        nan_par = np.full(max(self.n - 3, 0), np.nan)
        if not ok[idx].all():                               # incomplete: no parity test
            present = self.healthy & ok
            sub = self.cache.get(self._mask(present))
            w, _ = self._reconstruct(sub, u)
            return OracleSample(w, sub.omega_sd, self.healthy.copy(),
                                np.full(self.K, np.nan), self._base_thresholds(), nan_par,
                                np.inf, mdl.capability, events)
        y = self.sf[idx] * u[idx] - self.bias[idx]
        p = mdl.V[:, idx] @ y
        z = mdl.A @ p
        w, rho = self._reconstruct(mdl, u)
        if mdl.df == 0:
            stats, thrs, par = np.full(self.K, np.nan), self._base_thresholds(), nan_par
        else:
            stats, thrs, alarm, clear, fired = self._tests(z, rho)
            par = nan_par.copy()
            par[:mdl.df] = p
            events += self._machine(t, stats, thrs, alarm, clear, fired)
            if self.model is not mdl:
                w, rho = self._reconstruct(self.model, u)
        pl = self.model.pl
        level = pl.a * math.sqrt(1.0 + pl.b * rho) + pl.c * math.sqrt(pl.d + pl.e * rho)
        if self.suspects:
            level = np.inf
        return OracleSample(w, self.model.omega_sd, self.healthy.copy(), stats, thrs, par,
                            level, self.model.capability, events)

    def _health(self, t: float, u: np.ndarray, ok: np.ndarray) -> list:
        events = []
        for i in np.flatnonzero(self.healthy):
            reason = None
            if ok[i]:
                v = u[i]
                if not (self.lim.lo[i] < v < self.lim.hi[i]):
                    reason = "range" if np.isfinite(v) else "nonfinite"
                else:
                    self.run[i] = self.run[i] + 1 if v == self.last[i] else 1
                    self.last[i] = v
                    if self.run[i] >= self.lim.stuck_count:
                        reason = "stuck"
                    elif t > self.lvt[i] or np.isnan(self.lvt[i]):
                        self.lvt[i] = t
            elif t - self.lvt[i] > self.lim.stale_timeout_s:
                reason = "stale"
            if reason is not None:
                events.append(("health", int(i) + 1, reason, None, None, None))
                self.healthy[i] = False
        if events:
            self._new_set()
        return events

    def _tests(self, z: np.ndarray, rho: float):
        """Window statistics by direct sums, the CUSUM bank by Page's recursion."""
        mdl = self.model
        self.hist_z.append(z)
        self.hist_rho.append(rho)
        count = len(self.hist_z)
        stats, thrs, ratios = [], [], []
        clear = True
        for w, a, f in zip(self.scales, self.th.alpha, self.th.variance_factor, strict=True):
            thr = chi2_threshold(a, mdl.df)
            if count < w:
                stats.append(np.nan)
                thrs.append(thr)
                ratios.append(-np.inf)
                continue
            s = np.sum(self.hist_z[-w:], axis=0)
            D = float(s @ s) / (w * f)
            gain = 1.0 + w * mdl.beta / f + mdl.kappa / f * float(np.sum(self.hist_rho[-w:]))
            T = thr * gain
            stats.append(D)
            thrs.append(T)
            self.last_T = getattr(self, "last_T", {})
            self.last_T[w] = T
            ratios.append(D / T if D > T else -np.inf)
            # clearing level: half the threshold, never below the χ² level healthy noise
            # stays under for clear_samples samples on every scale but with clear_miss
            # (union bound), never above the threshold; inflated as the threshold is
            st = self.settings
            floor = chi2_threshold(st.clear_miss / (st.clear_samples * len(self.scales)),
                                   mdl.df)
            clear &= D < min(thr, max(st.clear_ratio * thr, floor)) * gain
        if self.cusum:
            U = mdl.U / np.linalg.norm(mdl.U, axis=0)
            r = U.T @ z
            allowance = self.th.cusum_drift + 3.0 * math.sqrt(mdl.kappa * rho + mdl.beta)
            self.g_up = np.maximum(0.0, self.g_up + r - allowance)
            self.g_down = np.maximum(0.0, self.g_down - r - allowance)
            g = float(max(self.g_up.max(), self.g_down.max(), 0.0))
            h = self._h()
            stats.append(g)
            thrs.append(h)
            ratios.append(g / h if g > h else -np.inf)
            clear &= g < self.settings.clear_ratio * h
        ratios = np.array(ratios)
        alarm = bool(np.isfinite(ratios).any())
        fired = int(np.argmax(ratios)) if alarm else -1
        return np.array(stats), np.array(thrs), alarm, clear, fired

    def _machine(self, t, stats, thrs, alarm, clear, fired) -> list:
        mdl = self.model
        events = []
        if not self.detected:
            if not alarm:
                return events
            self.detected, self.det_rows, self.alarm_run, self.clear_run = True, 1, 1, 0
            sensor, mag, reason = self._attribute(fired)
            cons, _, _ = self._hypotheses(fired)
            single = mdl.capability == "isolate" and cons is not None and len(cons) == 1
            events.append(("detected", sensor if single else None, reason, stats[fired],
                           thrs[fired], mag if single else None))
            self.due = self.settings.persistence
            self.rows_seen = 1
            events += self._suspect(cons)
        else:
            self.det_rows += 1
            if alarm and self.clear_run > 0:        # fell back below clearing, rises again:
                self.det_rows = 1                   # a new onset
            self.alarm_run = self.alarm_run + 1 if alarm else 0
            self.clear_run = self.clear_run + 1 if clear else 0
        ask = mdl.df >= 2 and mdl.capability in ("isolate", "detect")
        if ask and self.alarm_run >= self.settings.persistence:
            if self.det_rows < self.rows_seen:     # a new onset: decided afresh
                self.due = self.settings.persistence
                self.fresh = True
                self.no_fit = False
            self.rows_seen = self.det_rows
            if self.det_rows >= self.due:
                nxt = [w for w in self.scales if w > self.det_rows]
                self.due = nxt[0] if nxt else self.det_rows + max(self.scales)
                cons, res, wd = self._hypotheses(fired)
                sub = chi2_threshold(self.th.alpha[self.scales.index(wd)], mdl.df - 1)
                if (mdl.capability == "isolate" and cons is not None and len(cons) == 1
                        and res[cons[0]] <= sub):
                    k = cons[0]
                    wm = max([w for w in self.scales if w <= self.det_rows
                              and w <= len(self.hist_z)], default=0)
                    s = np.sum(self.hist_z[-wm:], axis=0)
                    mag = (float(mdl.U[:, k] @ s) / (wm * float(mdl.U[:, k] @ mdl.U[:, k]))
                           if wm else None)
                    sensor = mdl.idx[k] + 1
                    c = sstats.chi2.isf(self.settings.wrong_exclusion / (mdl.m - 1), mdl.df - 1)
                    weakest = min(float(res[j]) for j in range(mdl.m) if j != k)
                    events.append(("isolated", sensor, f"parity scale {wd}", weakest, c, mag))
                    self.healthy[sensor - 1] = False
                    self._new_set()
                else:
                    events += self._suspect(cons)
        elif self.detected and self.clear_run >= self.settings.clear_samples:
            self.detected = False
            self.suspects = ()
            self.no_fit = False
            self.rows_seen = 0
            self.fresh = False
        return events

    def _hypotheses(self, fired: int):
        """Consistent hypotheses (columns, best first), residuals and the window used."""
        mdl = self.model
        if mdl.df < 1:
            return None, None, 0
        cand = [w for w in self.scales if w <= max(self.det_rows, 1) and w <= len(self.hist_z)]
        if 0 <= fired < len(self.scales):
            cand.append(self.scales[fired])
        if not cand:
            return None, None, 0
        w = max(cand)
        k = self.scales.index(w)
        base = chi2_threshold(self.th.alpha[k], mdl.df)
        infl = self.last_T[w] / base
        s = np.sum(self.hist_z[-w:], axis=0) / math.sqrt(w * self.th.variance_factor[k] * infl)
        res = []
        for j in range(mdl.m):
            a, *_ = np.linalg.lstsq(mdl.U[:, [j]], s, rcond=None)
            r = s - mdl.U[:, j] * a[0]
            res.append(float(r @ r))
        res = np.array(res)
        c = (sstats.chi2.isf(self.settings.wrong_exclusion / (mdl.m - 1), mdl.df - 1)
             if mdl.df > 1 else np.inf)
        best = int(np.argmin(res))
        cons = [best] + [j for j in np.argsort(res) if j != best and res[j] <= c]
        if res[best] > c:
            cons = cons[1:]
        return cons, res, w

    def _suspect(self, cons) -> list:
        """Suspects narrow within a detection: the intersection of the consistent sets."""
        mdl = self.model
        if self.no_fit:
            return []
        cand = set(range(mdl.m)) if cons is None else set(cons)
        if self.fresh:
            self.fresh = False
        elif self.suspects and cand:
            cand &= {mdl.idx.index(i - 1) for i in self.suspects}
        none_fits = cons is not None and not cand
        self.no_fit = none_fits
        cols = sorted(cand) if cand else list(range(mdl.m))
        sus = tuple(sorted(mdl.idx[j] + 1 for j in cols))
        changed = sus != self.suspects
        self.suspects = sus
        if changed and (len(sus) > 1 or mdl.capability != "isolate"):
            names = [self.names[i - 1] for i in sus]
            joined = names[0] if len(names) == 1 else ", ".join(names[:-1]) + " and " + names[-1]
            if none_fits:
                why = "no single-sensor fault explains the parity: " + joined + " unverified"
            else:
                why = joined + (" disagree: cannot tell which" if len(sus) > 1 else
                                ": suspected (this set cannot isolate)")
            return [("disagree", None, why, None, None, None)]
        return []

    def _attribute(self, fired: int) -> tuple[int, float | None, str]:
        mdl = self.model
        U = mdl.U
        u2 = np.sum(U * U, axis=0)
        if fired >= len(self.scales):
            k = int(np.argmax(np.maximum(self.g_up, self.g_down)))
            reason = "cusum"
        else:
            w = self.scales[fired]
            s = np.sum(self.hist_z[-w:], axis=0)
            k = int(np.argmax((U.T @ s) ** 2 / (w * u2)))
            reason = f"parity scale {w}"
        wm = max([w for w in self.scales if w <= max(self.det_rows, 1)
                  and w <= len(self.hist_z)], default=0)
        mag = None
        if wm:
            s = np.sum(self.hist_z[-wm:], axis=0)
            mag = float(U[:, k] @ s) / (wm * u2[k])
        return mdl.idx[k] + 1, mag, reason
