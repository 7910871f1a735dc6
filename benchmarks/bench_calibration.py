"""Benchmark: calibrate() on a tetrad-paper session (16 steps, 100 Hz, 57 600 × 4 samples).

Baselines measured in the same run on the same array: one ``np.mean(raw, axis=0)`` pass and
one ``np.linalg.lstsq`` of the per-sample model ``u = a·x + c`` (57 600 × 4 design, 4 sensors),
i.e. the least one could do with the data. Also each stage of :func:`calibrate` on its own
(:func:`calibration.calibrate.run_stages`' functions) and a Ferraris calibration of a
simulated session. BLAS single-threaded; min/median/max over the repeats. Prints the
figures and writes ``benchmarks/results/calibration.json``.

Run: ``python benchmarks/bench_calibration.py [--repeats 15]``
"""

from __future__ import annotations

import argparse

import numpy as np
from _common import RESULTS, header, timed, write_results

from calibration.calibrate import calibrate
from calibration.presets import preset
from calibration.simulate import simulate_session


def _median_time(fn, repeats: int) -> float:
    return timed(fn, repeats)["median"]


def _stage_times(s, repeats: int) -> dict[str, dict[str, float]]:
    """Each gyro stage of calibrate() alone, on the results of the stages before it."""
    from calibration.fit_residuals import fit_residuals
    from calibration.linear_fit import fit_offsets, gyro_rate_test
    from calibration.problem import gyro_problem
    from calibration.uncertainty import segment_times, set_uncertainty

    p = gyro_problem(s)
    rt = gyro_rate_test(p)
    fit = fit_offsets(p, rt)
    res = fit_residuals(p, rt, fit)
    st, sl = segment_times(p.t, p.segment, p.seg_count, p.sample_rate_hz)
    H = s.gyro_config.H

    def unc():
        return set_uncertainty(fit.theta, fit.op, fit.inv_count, res.noise_cov_raw, H,
                               res.raw, st, sl, p.sample_rate_hz, "auto", fit.theta_turns,
                               fit.op_turns)

    return {"1 problem": timed(lambda: gyro_problem(s), repeats),
            "2 rate test": timed(lambda: gyro_rate_test(p), repeats),
            "3 offsets": timed(lambda: fit_offsets(p, rt), repeats),
            "4 residuals": timed(lambda: fit_residuals(p, rt, fit), repeats),
            "5 uncertainty (auto)": timed(unc, repeats)}


def _fmt(t: dict[str, float]) -> str:
    return (f"{1e3 * t['min']:8.2f} / {1e3 * t['median']:8.2f} / {1e3 * t['max']:8.2f} ms")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=15)
    ap.add_argument("--out", default=str(RESULTS / "calibration.json"))
    args = ap.parse_args()
    from threadpoolctl import threadpool_limits

    with threadpool_limits(1):
        return _run(args)


def _run(args: argparse.Namespace) -> int:
    from calibration.ferraris import ferraris_calibrate
    from studies.ferraris_sim import imucal_like_truth, simulate_ferraris

    seq, truth, noise = preset("tetrad-paper")
    s = simulate_session(None, seq, truth, seed=0, noise=noise)
    raw = s.raw_gyro
    wt, we, _ = s.inputs()
    design = np.column_stack([wt + we, np.ones(raw.shape[0])])
    r = args.repeats
    full = timed(lambda: calibrate(s), r)
    stages = _stage_times(s, r)
    fs_ = simulate_ferraris(imucal_like_truth(0), seed=0)
    ferraris = timed(lambda: ferraris_calibrate(fs_), r)
    t_full = full["median"]
    t_noallan = _median_time(lambda: calibrate(s, allan=False), r)
    t_nodenoise = _median_time(lambda: calibrate(s, allan=False, denoise=False), r)
    t_mean = _median_time(lambda: np.mean(raw, axis=0), max(r, 50))
    t_lstsq = _median_time(lambda: np.linalg.lstsq(design, raw, rcond=None), r)
    res = header("calibration") | {
        "session": {"preset": "tetrad-paper", "steps": len(s.steps), "samples": raw.shape[0],
                    "sensors": raw.shape[1], "sample_rate_hz": s.sample_rate_hz},
        "repeats": r,
        "calibrate_s": t_full,
        "calibrate_min_median_max_s": full,
        "stages_min_median_max_s": stages,
        "ferraris_min_median_max_s": ferraris,
        "ferraris_samples": int(fs_.gyro.shape[0]),
        "blas_threads": 1,
        "calibrate_no_allan_s": t_noallan,
        "calibrate_no_allan_no_denoise_s": t_nodenoise,
        "baseline_mean_s": t_mean,
        "baseline_lstsq_s": t_lstsq,
        "ratio_to_mean": t_full / t_mean,
        "ratio_to_lstsq": t_full / t_lstsq,
    }
    print(f"calibrate() tetrad-paper ({raw.shape[0]} samples x {raw.shape[1]} gyros, "
          f"{len(s.steps)} steps), median of {r}:")
    print(f"  full (denoise + Earth rate + Allan): {1e3 * t_full:8.1f} ms  "
          f"(min / median / max {_fmt(full)})")
    for k, t in stages.items():
        print(f"    stage {k:<22s} {_fmt(t)}")
    print(f"  without Allan deviation:             {1e3 * t_noallan:8.1f} ms")
    print(f"  without Allan, without denoising:    {1e3 * t_nodenoise:8.1f} ms")
    print(f"baseline np.mean(raw, axis=0):         {1e3 * t_mean:8.3f} ms  "
          f"(calibrate = {t_full / t_mean:.0f} x)")
    print(f"baseline np.linalg.lstsq (N x 4, 4 rhs):{1e3 * t_lstsq:7.2f} ms  "
          f"(calibrate = {t_full / t_lstsq:.1f} x)")
    print(f"ferraris_calibrate ({fs_.gyro.shape[0]} samples x 6 sensors): {_fmt(ferraris)}")
    write_results(res, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
