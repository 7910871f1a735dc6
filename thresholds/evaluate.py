"""Evaluation campaigns: Monte Carlo of simulated flights (or a corpus of recorded ones).

:func:`design` lays out the runs of a campaign: every fault kind of :mod:`replay.faults`
at a sweep of sizes (:data:`SIZE_SWEEP`), one healthy cell, and the *sweep* of step sizes
at rest that measures the detectable size of each scale. Run ``j`` has its own seed
``SeedSequence([seed, j])``, so the runs can go anywhere: :func:`execute` maps
:func:`thresholds.campaign.run_one` over them serially, on a Dask ``LocalCluster`` or on an
existing cluster (``tcp://HOST:PORT``), and the results are put back in run order before
:func:`summarise` turns them into the numbers of ``evaluation.json``: identical whatever
ran them.

Statistics: detection and isolation probabilities with Wilson 95 % intervals
(``statsmodels.stats.proportion.proportion_confint``); false alarms per hour with the exact
Poisson (Garwood) 95 % interval (``scipy.stats.chi2``) on the full-set exposure; the
detectable size of each scale from a probit fit of the sweep's window detections against
size (maximum likelihood), with a delta-method interval.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from functools import partial
from typing import Any

import numpy as np
from scipy import optimize, stats

from fdi.calfile import Calibration
from fdi.errors import ConfigError
from fdi.settings import Thresholds
from replay.faults import FAULT_KINDS
from thresholds.campaign import ROC_MULTIPLIERS, RunResult, RunSpec, corpus_one, run_one

__all__ = ["EVALUATION_SCHEMA", "SIZE_SWEEP", "SIZE_UNITS", "corpus_task", "design",
           "execute", "map_on_client", "poisson_interval", "simulation_task", "summarise",
           "wilson_interval"]

EVALUATION_SCHEMA = "rimu.evaluation/1"
SIZE_SWEEP: dict[str, tuple[float, ...]] = {
    "step": (1.0, 2.0, 4.0, 8.0),
    "ramp": (0.02, 0.1, 0.5),
    "stuck": (0.0,),
    "noise": (2.0, 4.0),
    "scale": (1e-3, 1e-2),
    "spike": (10.0, 30.0),
    "dropout": (0.0,),
}
"""Sizes per fault kind, in :data:`SIZE_UNITS`."""
SIZE_UNITS = {"step": "sigma", "ramp": "sigma/s", "stuck": "-", "noise": "x",
              "scale": "fraction", "spike": "sigma", "dropout": "-", "sweep": "sigma"}
SWEEP_SIGMA = tuple(float(x) for x in np.geomspace(0.5, 16.0, 11))
"""Step sizes (σ) of the detectable-size sweep."""


def _seed(seed: int, j: int) -> int:
    return int(np.random.SeedSequence([int(seed), int(j)]).generate_state(1)[0])


def _si_size(kind: str, label: float, sigma: float) -> float:
    return label * sigma if SIZE_UNITS[kind] in ("sigma", "sigma/s") else label


def design(cal: Calibration, thresholds: Thresholds, *, runs: int, seed: int = 0,
           faults: Sequence[str] = FAULT_KINDS, sweep_runs: int = 0, kind: str = "gyro",
           duration_s: float = 60.0, onset_s: float = 30.0, max_rate_dps: float = 300.0
           ) -> list[RunSpec]:
    """The runs of a campaign, in order.

    Parameters
    ----------
    runs : int
        Flights cycling over the cells (healthy, then each fault kind × size); the faulty
        sensor cycles over the set.
    faults : sequence of str
        Fault kinds (default all).
    sweep_runs : int
        Extra runs of steps at rest on the worst sensor for the detectable sizes.

    Raises
    ------
    ConfigError
        An unknown fault kind, a non-positive run count.
    """
    for f in faults:
        if f not in FAULT_KINDS:
            raise ConfigError(f"unknown fault kind {f!r}; expected one of "
                              f"{', '.join(FAULT_KINDS)}")
    if runs < 0 or sweep_runs < 0 or runs + sweep_runs < 1:
        raise ConfigError(f"need at least one run, got --runs {runs}")
    s = cal.kind(kind)
    cells = [("healthy", 0.0)] + [(f, x) for f in faults for x in SIZE_SWEEP[f]]
    out = []
    for j in range(runs):
        f, lab = cells[j % len(cells)]
        sensor = 0 if f == "healthy" else (j // len(cells)) % s.n + 1
        size = _si_size(f, lab, float(s.noise_sd[sensor - 1])) if sensor else 0.0
        out.append(RunSpec(j, _seed(seed, j), f, size, lab, sensor, onset_s, duration_s,
                           max_rate_dps))
    if sweep_runs:
        from thresholds.tune import detectable_sizes

        worst = detectable_sizes(cal, thresholds, kind=kind)[0].sensor
        sd = float(s.noise_sd[worst - 1])
        onset = 1.0
        dur = onset + (max(thresholds.scales) + 2) / thresholds.sample_rate_hz
        for k in range(sweep_runs):
            j = runs + k
            lab = SWEEP_SIGMA[k % len(SWEEP_SIGMA)]
            out.append(RunSpec(j, _seed(seed, j), "sweep", lab * sd, lab, worst, onset, dur,
                               0.0))
    return out


def _run_batch(task: Callable[[Any], RunResult], items: list[Any]) -> list[RunResult]:
    return [task(x) for x in items]


def simulation_task(cal: Calibration, thresholds: Thresholds, kind: str = "gyro",
                    baselines: Sequence[str] = ()) -> Callable[[RunSpec], RunResult]:
    """The picklable function that runs one simulated :class:`RunSpec` (``baselines``:
    autopilot rules run on the same samples, :mod:`replay.baselines`)."""
    return partial(_sim, cal, thresholds, kind, tuple(baselines))


def corpus_task(cal: Calibration, thresholds: Thresholds, kind: str = "gyro",
                baselines: Sequence[str] = ()) -> Callable[[tuple[int, str]], RunResult]:
    """The picklable function that runs one ``(index, flight folder)`` of a corpus."""
    return partial(_corpus, cal, thresholds, kind, tuple(baselines))


def _sim(cal: Calibration, thresholds: Thresholds, kind: str, baselines: tuple[str, ...],
         spec: RunSpec) -> RunResult:
    return run_one(cal, thresholds, spec, kind=kind, baselines=baselines)


def _corpus(cal: Calibration, thresholds: Thresholds, kind: str, baselines: tuple[str, ...],
            item: tuple[int, str]) -> RunResult:
    return corpus_one(cal, thresholds, item[0], item[1], kind=kind, baselines=baselines)


def execute(task: Callable[[Any], RunResult], items: Sequence[Any], *,
            scheduler: str = "serial", progress: bool = False, batch: int = 8,
            workers: int = 2) -> list[RunResult]:
    """Run ``task`` on every item; results in item order.

    Parameters
    ----------
    task : callable
        :func:`simulation_task` or :func:`corpus_task` (picklable).
    items : sequence
        RunSpecs, or (index, folder) pairs.
    scheduler : str
        ``"serial"`` (this process), ``"local"`` (a Dask LocalCluster of ``workers``
        single-threaded worker processes) or a scheduler address ``tcp://HOST:PORT``.
    progress : bool
        A progress bar on stderr (:mod:`fdi.progress`).
    batch : int
        Runs per Dask task.

    Raises
    ------
    ConfigError
        An unknown scheduler spelling or a scheduler that cannot be reached.
    """
    items = list(items)
    if not (scheduler in ("serial", "local") or "://" in scheduler):
        raise ConfigError(f"unknown scheduler {scheduler!r}; expected serial, local or "
                          f"tcp://HOST:PORT")
    if scheduler != "serial":
        return _execute_dask(task, items, scheduler, batch, workers, progress)
    bar = _bar(len(items), progress)
    try:
        out = []
        for x in items:
            out.append(task(x))
            bar.update(1)
        return out
    finally:
        bar.close()


def _bar(total: int, progress: bool) -> Any:
    from fdi.progress import Progress, current

    # the command's progress (fdi.progress); a silent one when not asked for
    return (current() if progress else Progress("evaluate", enabled=False)).bar(
        total, "simulated runs", unit="runs")


def _execute_dask(task: Callable[[Any], RunResult], items: list[Any], scheduler: str,
                  batch: int, workers: int, progress: bool) -> list[RunResult]:
    from dask.distributed import Client, LocalCluster

    cluster = None
    if scheduler == "local":
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                               dashboard_address=None)
        client = Client(cluster)
    else:
        try:
            client = Client(scheduler, timeout="3s")
        except (OSError, TimeoutError, ValueError) as exc:
            raise ConfigError(f"cannot reach the Dask scheduler {scheduler}: "
                              f"{type(exc).__name__}: {exc}") from None
    bar = _bar(len(items), progress)
    try:
        return map_on_client(client, task, items, batch=batch, bar=bar)
    finally:
        bar.close()
        client.close()
        if cluster is not None:
            cluster.close()


def map_on_client(client: Any, task: Callable[[Any], RunResult], items: Sequence[Any], *,
                  batch: int = 8, bar: Any = None) -> list[RunResult]:
    """Run the items on a Dask ``Client`` in batches; results in item order."""
    from dask.distributed import as_completed

    items = list(items)
    chunks = [items[i:i + max(1, batch)] for i in range(0, len(items), max(1, batch))]
    futs = [client.submit(_run_batch, task, c, pure=False) for c in chunks]
    done: dict[int, RunResult] = {}
    for fut in as_completed(futs):
        rs = fut.result()
        for r in rs:
            done[r.spec.index] = r
        if bar is not None:
            bar.update(len(rs))
    return [done[k] for k in sorted(done)]


def wilson_interval(k: int, n: int, level: float = 0.95) -> tuple[float, float]:
    """Wilson score interval of a proportion (statsmodels)."""
    if n == 0:
        return (math.nan, math.nan)
    from statsmodels.stats.proportion import proportion_confint

    lo, hi = proportion_confint(k, n, alpha=1.0 - level, method="wilson")
    return float(lo), float(hi)


def poisson_interval(k: int, exposure: float, level: float = 0.95) -> tuple[float, float]:
    """Exact (Garwood) interval of a Poisson rate ``k / exposure``."""
    if exposure <= 0:
        return (math.nan, math.nan)
    a = 1.0 - level
    lo = 0.0 if k == 0 else stats.chi2.ppf(a / 2, 2 * k) / 2
    hi = stats.chi2.ppf(1 - a / 2, 2 * k + 2) / 2
    return float(lo / exposure), float(hi / exposure)


def _probit_b99(sizes: np.ndarray, hits: np.ndarray, p: float = 0.99
                ) -> tuple[float, float, float]:
    """Size detected with probability p, and a 95 % interval, from a probit fit.

    ``P(hit) = Φ((b − μ)/s)``: for a non-central χ² well above its threshold
    ``sqrt(D) ≈ N(sqrt(λ), 1)`` with ``sqrt(λ) ∝ b``, so the probit is linear in b.
    Maximum likelihood; the interval by the delta method on the numerical Hessian. When
    every miss lies below every hit the fit has no maximum: ``(nan, largest miss, smallest
    hit)``, the bracket the runs give.
    """
    ok = np.isfinite(hits)
    x, y = sizes[ok], hits[ok]
    if y.size < 4 or y.all() or not y.any():
        return (math.nan, math.nan, math.nan)
    lo_hit, hi_miss = float(x[y > 0].min()), float(x[y == 0].max())
    if hi_miss < lo_hit:
        # complete separation: every miss below every hit; the probit has no maximum (its
        # slope runs to infinity and the interval collapses to a point), so report only
        # the bracket the runs give: no size estimate
        return (math.nan, hi_miss, lo_hit)

    def nll(th: np.ndarray) -> float:
        q = stats.norm.cdf((x - th[0]) / math.exp(th[1]))
        q = np.clip(q, 1e-300, 1.0)
        r = np.clip(stats.norm.sf((x - th[0]) / math.exp(th[1])), 1e-300, 1.0)
        return -float(np.sum(y * np.log(q) + (1 - y) * np.log(r)))

    x50 = float(np.median(x[y > 0]))
    r = optimize.minimize(nll, [x50, math.log(0.3 * x50)], method="Nelder-Mead",
                          options={"xatol": 1e-8, "fatol": 1e-10, "maxiter": 4000})
    mu, ls = r.x
    z = stats.norm.ppf(p)
    b = mu + z * math.exp(ls)
    h = 1e-4 * max(abs(mu), 1e-3)
    steps = np.array([h, 1e-4])
    H = np.zeros((2, 2))
    for i in range(2):
        for k in range(2):
            e_i, e_k = np.eye(2)[i] * steps[i], np.eye(2)[k] * steps[k]
            H[i, k] = (nll(r.x + e_i + e_k) - nll(r.x + e_i - e_k) - nll(r.x - e_i + e_k)
                       + nll(r.x - e_i - e_k)) / (4 * steps[i] * steps[k])
    try:
        cov = np.linalg.inv(H)
        g = np.array([1.0, z * math.exp(ls)])
        sd = math.sqrt(max(float(g @ cov @ g), 0.0))
    except np.linalg.LinAlgError:
        sd = math.nan
    return float(b), float(b - 1.96 * sd), float(b + 1.96 * sd)


def _false_alarms(main: list[RunResult]) -> dict[str, Any]:
    """Full-set false alarms per hour of exposure, exact Poisson interval."""
    nfa = sum(r.false_alarm for r in main)
    expo_h = sum(r.exposure_s for r in main) / 3600.0
    lo, hi = poisson_interval(nfa, expo_h)
    return {"count": nfa, "exposure_h": expo_h,
            "per_hour": nfa / expo_h if expo_h > 0 else math.nan, "ci95_per_hour": [lo, hi],
            "definition": "first alarm of the full healthy set before the fault onset, per "
                          "hour of exposure until it"}


def _fault_cells(main: list[RunResult]) -> list[dict[str, Any]]:
    """Per fault kind and size: detection, correct isolation (Wilson intervals), delay."""
    cells: dict[tuple[str, float], list[RunResult]] = {}
    for r in main:
        if r.spec.fault != "healthy":
            cells.setdefault((r.spec.fault, r.spec.size_label), []).append(r)
    out = []
    for (f, lab), rs in sorted(cells.items()):
        n = len(rs)
        kd = sum(r.detected for r in rs)
        ki = sum(r.isolated == r.spec.sensor for r in rs)
        d = np.array([r.delay_s for r in rs if r.detected])
        out.append({"fault": f, "size": lab, "unit": SIZE_UNITS.get(f, "SI"), "runs": n,
                    "detected": kd, "pd": kd / n, "pd_ci95": list(wilson_interval(kd, n)),
                    "isolated_correctly": ki, "p_isolation": ki / n,
                    "p_isolation_ci95": list(wilson_interval(ki, n)),
                    "delay_s_median": float(np.median(d)) if d.size else None,
                    "delay_s_p90": float(np.quantile(d, 0.9)) if d.size else None})
    return out


def _confusion(main: list[RunResult], n_sensors: int) -> dict[str, Any]:
    """Faulty sensor (rows) against the first sensor isolated after the onset (columns)."""
    conf = np.zeros((n_sensors, n_sensors + 1), int)
    for r in main:
        if r.spec.fault != "healthy" and r.detected:
            conf[r.spec.sensor - 1, r.isolated] += 1
    return {"rows": "true sensor 1..n", "columns": "isolated: none, 1..n",
            "counts": conf.tolist()}


def _roc_point(main: list[RunResult], k: int) -> dict[str, Any]:
    """False alarms per hour and detection of step/ramp faults at ROC multiplier k.

    False alarms: a passage before the onset, per hour of healthy exposure up to the first
    passage. Detection: a passage at or after the onset, whatever passed before it (so
    that lower thresholds never detect less: the curve rises as they fall)."""
    fa, ex = 0, 0.0
    for r in main:
        first = r.roc_first[k]
        end = min(r.spec.onset_s if r.spec.fault != "healthy" else math.inf,
                  r.spec.duration_s)
        fa += first < end
        ex += min(first, end)
    det = [r for r in main if r.spec.fault in ("step", "ramp")]
    # runs made before roc_detect existed: only a first passage after the onset counts
    kd = sum((r.roc_detect[k] if r.roc_detect else
              (r.roc_first[k] if r.roc_first[k] >= r.spec.onset_s else math.inf)) < math.inf
             for r in det)
    return {"multiplier": ROC_MULTIPLIERS[k],
            "false_alarms_per_hour": fa / (ex / 3600.0) if ex else math.nan,
            "false_alarms": fa, "pd_step_ramp": kd / len(det) if det else math.nan}


def _detectable(sweep: list[RunResult], thresholds: Thresholds, predicted: Sequence[Any]
                ) -> dict[str, Any]:
    """Measured 99 % detectable size per scale (probit fit) beside the prediction."""
    sizes = np.array([r.spec.size_label for r in sweep])
    hits = np.array([r.window_hit for r in sweep], float)
    rows = []
    for k, w in enumerate(thresholds.scales):
        b, blo, bhi = _probit_b99(sizes, hits[:, k])
        row = {"scale": int(w), "measured_sigma": b, "ci95_sigma": [blo, bhi]}
        if k < len(predicted):
            pr = predicted[k].size_sigma
            row["predicted_sigma"] = pr
            row["ratio"] = b / pr if math.isfinite(b) else None
        rows.append(row)
    return {"probability": 0.99, "runs": len(sweep), "sensor": sweep[0].spec.sensor,
            "conditions": "step at rest, one full window, isolation off", "per_scale": rows}


def _baseline_cells(main: list[RunResult]) -> dict[str, Any]:
    """Per autopilot rule: false alarms counted as rimu's (first flag before the onset, per
    hour of exposure until it) and, per fault cell, detection, right blame and delay;
    rimu's isolation read per IMU beside them."""
    names = [b.name for b in main[0].baselines] if main and main[0].baselines else []
    out: dict[str, Any] = {"definitions": {
        "false_alarm": "first flag of the rule before the fault onset, per hour of "
                       "exposure until it (as rimu's false_alarms)",
        "detected": "a flag at or after the onset", "blame_correct": "the first IMU blamed at "
        "or after the onset is the faulted sensor's", "rimu_p_isolation_imu": "rimu's first "
        "exclusion after the onset names a sensor of the faulted IMU"}, "rules": {}}
    for k, nm in enumerate(names):
        runs = [(r, r.baselines[k]) for r in main if len(r.baselines) > k]
        nfa = sum(b.false_alarm for _, b in runs)
        expo_h = sum(b.exposure_s for _, b in runs) / 3600.0
        lo, hi = poisson_interval(nfa, expo_h)
        cells: dict[tuple[str, float], list[Any]] = {}
        for r, b in runs:
            if r.spec.fault != "healthy":
                cells.setdefault((r.spec.fault, r.spec.size_label), []).append((r, b))
        rows = []
        for (f, lab), rs in sorted(cells.items()):
            n = len(rs)
            kd = sum(b.detected for _, b in rs)
            kb = sum(bool(b.blame_correct) for _, b in rs)
            ki = sum(0 <= r.isolated_imu == r.faulted_imu for r, _ in rs)
            d = np.array([b.delay_s for _, b in rs if b.detected])
            rows.append({"fault": f, "size": lab, "unit": SIZE_UNITS.get(f, "SI"), "runs": n,
                         "pd": kd / n, "pd_ci95": list(wilson_interval(kd, n)),
                         "p_blame_correct": kb / n,
                         "p_blame_correct_ci95": list(wilson_interval(kb, n)),
                         "rimu_p_isolation_imu": ki / n,
                         "delay_s_median": float(np.median(d)) if d.size else None})
        out["rules"][nm] = {"false_alarms": {"count": nfa, "exposure_h": expo_h,
                                             "per_hour": nfa / expo_h if expo_h else math.nan,
                                             "ci95_per_hour": [lo, hi]},
                            "faults": rows}
    return out


def summarise(results: Iterable[RunResult], thresholds: Thresholds, *, n_sensors: int,
              predicted: Sequence[Any] = ()) -> dict[str, Any]:
    """The numbers of ``evaluation.json`` (no timing; deterministic in the results).

    Parameters
    ----------
    results : iterable of RunResult
        In run order.
    thresholds : Thresholds
    n_sensors : int
    predicted : sequence of DetectableSize
        ``rimu tune``'s detectable sizes, shown beside the measured ones.
    """
    res = list(results)
    errors = [r.spec.fault for r in res if r.spec.fault.startswith("error")]
    main = [r for r in res if r.spec.fault != "sweep" and not r.spec.fault.startswith("error")]
    sweep = [r for r in res if r.spec.fault == "sweep"]
    out: dict[str, Any] = {
        "schema": EVALUATION_SCHEMA, "runs": len(res),
        "thresholds": {"false_alarms_per_hour": thresholds.false_alarms_per_hour,
                       "sample_rate_hz": thresholds.sample_rate_hz,
                       "scales": list(thresholds.scales), "notes": thresholds.notes},
        "false_alarms": _false_alarms(main), "faults": _fault_cells(main)}
    if errors:
        out["errors"] = errors
    out["isolation_confusion"] = _confusion(main, n_sensors)
    out["roc"] = [_roc_point(main, k) for k in range(len(ROC_MULTIPLIERS))]
    if sweep:
        out["detectable_sizes"] = _detectable(sweep, thresholds, predicted)
    if any(r.baselines for r in main):
        out["baselines"] = _baseline_cells(main)
    return out
