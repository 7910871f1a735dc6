"""The monitoring chain's cost of the time offsets: replay of a two-IMU CAN log with and
without the in-flight calibration's offsets.

The script simulates a two-IMU flight at 100 Hz with a 10 ms lag on IMU 2 (``--minutes``),
fits the in-flight calibration on it, writes it as a candump log (six gyro frames and six
accelerometer frames per sample), then times, interleaved and repeated (best of
``--repeat``; process CPU time, the machine is shared), what ``rimu replay`` does apart from
printing: the log streamed in pieces through :func:`replay.chain.report_log` with the
offsets (the causal aligner) and without (``--no-time-offsets``). It also records the
largest number of samples the aligner held at once (its memory: constant).

Usage: ``python benchmarks/bench_chain.py [--minutes 5] [--repeat 2]``.
Writes ``benchmarks/results/chain.json``.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from _common import header, print_results, write_results

from calibration.inflight.calfile import calibration_from_fit
from calibration.inflight.fit import fit_inflight
from replay.can_write import write_flight_log
from replay.chain import ChainOptions, chain_for_map, report_log
from replay.imu_set import ImuSetSpec, simulate_imu_set
from replay.logio import LogStream, resolve_map


def _replay(log: Path, cal, offsets: bool) -> tuple[float, int, int]:
    """CPU seconds, samples and the most samples the aligner held."""
    db, cmap = resolve_map(cal)
    t0 = time.process_time()
    st = LogStream(log, cal, db, cmap, progress=False)
    ch = chain_for_map(cal, cmap, ChainOptions(time_offsets=offsets))
    held = [0]
    if ch.aligner is not None:
        push = ch.aligner.push

        def watch(piece):
            out = push(piece)
            buf = ch.aligner._buf
            held[0] = max(held[0], 0 if buf is None else int(buf.t.shape[0]))
            return out

        ch.aligner.push = watch
    rep = report_log(ch, st, st.header)
    return time.process_time() - t0, int(rep["samples"]), held[0]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=5.0)
    ap.add_argument("--repeat", type=int, default=2)
    args = ap.parse_args()
    f = simulate_imu_set(ImuSetSpec(imus=2, duration_s=60 * args.minutes, sample_rate_hz=100.0,
                                    seed=1, time_offset_s=(0.0, -0.010)))
    cal = calibration_from_fit(fit_inflight(f), f)
    res = header("chain", minutes=args.minutes, sample_rate_hz=100.0, lag_ms=-10.0)
    with tempfile.TemporaryDirectory() as d:
        log = Path(d) / "two_imus.log"
        write_flight_log(f, log)
        on, off = [], []
        for _ in range(args.repeat):
            c, n, held = _replay(log, cal, True)
            on.append(c)
            c0, n0, _ = _replay(log, cal, False)
            off.append(c0)
        res.update(samples=n, samples_without_offsets=n0, cpu_s_with_offsets=min(on),
                   cpu_s_without_offsets=min(off), ratio=min(on) / min(off),
                   aligner_samples_held_max=held,
                   time_offsets_applied_ms=chain_for_map(cal, resolve_map(cal)[1])
                   .time_offsets_ms)
    print_results(res)
    write_results(res)


if __name__ == "__main__":
    main()
