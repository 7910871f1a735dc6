"""rimu evaluate: statistics, determinism serial vs Dask, CLI outputs and bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest

from replay.threshold_choice import select
from studies.synthetic import synthetic_calibration
from thresholds.evaluate import (
    design,
    execute,
    map_on_client,
    poisson_interval,
    simulation_task,
    summarise,
    wilson_interval,
)
from thresholds.tune import detectable_sizes

CAL = synthetic_calibration("cone6")
THR = select(CAL, false_alarms_per_hour=10.0).thresholds


def test_intervals_against_textbook_values():
    # Wilson 95 % for 8/10: (0.490, 0.943) (Newcombe 1998, Table I style check)
    lo, hi = wilson_interval(8, 10)
    assert lo == pytest.approx(0.4902, abs=1e-3) and hi == pytest.approx(0.9433, abs=1e-3)
    # Garwood exact Poisson 95 % for k = 0 and k = 10 (Ulm 1990): (0, 3.689), (4.795, 18.39)
    assert poisson_interval(0, 1.0) == pytest.approx((0.0, 3.6889), abs=1e-3)
    assert poisson_interval(10, 2.0) == pytest.approx((4.7954 / 2, 18.390 / 2), abs=1e-3)


def test_design_covers_every_kind_and_is_seeded():
    specs = design(CAL, THR, runs=32, seed=5)
    kinds = {s.fault for s in specs}
    assert kinds == {"healthy", "step", "ramp", "stuck", "noise", "scale", "spike", "dropout"}
    assert len({s.seed for s in specs}) == 32
    assert [s.seed for s in design(CAL, THR, runs=32, seed=5)] == [s.seed for s in specs]
    with pytest.raises(Exception, match="unknown fault kind 'wobble'"):
        design(CAL, THR, runs=4, faults=("step", "wobble"))


def _small():
    return design(CAL, THR, runs=18, seed=3, duration_s=8.0, onset_s=4.0, sweep_runs=6)


def test_serial_and_dask_localcluster_give_identical_evaluation():
    from dask.distributed import Client, LocalCluster

    specs = _small()
    task = simulation_task(CAL, THR)
    a = summarise(execute(task, specs), THR, n_sensors=6)
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=False,
                      dashboard_address=None) as cl, Client(cl) as c:
        b = summarise(map_on_client(c, task, specs, batch=3), THR, n_sensors=6)
    assert json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)


def test_faults_are_detected_and_isolated_where_they_should_be():
    """Large faults on cone6 are detected and isolated on the right sensor; healthy runs
    carry exposure. (Sizes well above the detectable sizes: a deterministic check of the
    bookkeeping, the statistics are in the slow tests.)"""
    specs = [s for s in design(CAL, THR, runs=64, seed=1, duration_s=10.0, onset_s=5.0)
             if (s.fault == "step" and s.size_label == 8.0) or s.fault in ("stuck", "healthy")]
    ev = summarise(execute(simulation_task(CAL, THR), specs), THR, n_sensors=6)
    for f in ev["faults"]:
        assert f["pd"] == 1.0 and f["p_isolation"] == 1.0, f
    assert ev["false_alarms"]["exposure_h"] > 0
    conf = np.array(ev["isolation_confusion"]["counts"])
    assert conf[:, 0].sum() == 0 and np.trace(conf[:, 1:]) == conf.sum()


def test_evaluate_cli_writes_json_summary_and_plots(tmp_path, capsys):
    from rimu.cli import main

    cal = tmp_path / "cal.json"
    CAL.save(cal)
    out = tmp_path / "ev"
    assert main(["evaluate", "--cal", str(cal), "--false-alarms-per-hour", "10", "--runs", "16",
                 "--sweep-runs", "11", "--duration", "4", "--faults", "step",
                 "--no-progress", "--out", str(out)]) == 0
    ev = json.loads((out / "evaluation.json").read_text())
    assert ev["schema"] == "rimu.evaluation/1" and ev["runs"] == 27
    for name in ("roc.png", "delay_vs_size.png", "isolation_confusion.png",
                 "detectable_sizes.png", "summary.md"):
        assert (out / name).stat().st_size > 1000 or name == "summary.md"
    assert "P(detect)" in (out / "summary.md").read_text()


def test_evaluate_corpus_of_flight_folders(tmp_path):
    from replay.faults import parse_fault
    from replay.flight import save_flight_dir, simulate_flight
    from rimu.cli import main

    cal = tmp_path / "cal.json"
    CAL.save(cal)
    corpus = tmp_path / "corpus"
    for k in range(2):
        f = simulate_flight(CAL, 6.0, seed=k,
                            faults=[parse_fault("step:2:10sigma:3", CAL)] if k else [])
        save_flight_dir(f, corpus / f"f{k}")
    assert main(["evaluate", "--cal", str(cal), "--corpus", str(corpus), "--no-progress",
                 "--false-alarms-per-hour", "1", "--out", str(tmp_path / "ev")]) == 0
    ev = json.loads((tmp_path / "ev" / "evaluation.json").read_text())
    assert ev["source"] == "corpus" and ev["runs"] == 2
    assert ev["faults"][0]["fault"] == "step" and ev["faults"][0]["pd"] == 1.0


@pytest.mark.parametrize("argv, msg", [
    (["--faults", "step,wobble"], "unknown fault kind 'wobble'"),
    (["--scheduler", "nowhere"], "unknown scheduler"),
    (["--scheduler", "tcp://127.0.0.1:9"], "cannot reach the Dask scheduler"),
    (["--false-alarms-per-hour", "0"], "positive"),
])
def test_evaluate_cli_bad_input_one_line_exit_2(tmp_path, capsys, argv, msg):
    from rimu.cli import main

    cal = tmp_path / "cal.json"
    CAL.save(cal)
    assert main(["evaluate", "--cal", str(cal), "--runs", "2", "--no-progress", "--out",
                 str(tmp_path / "ev"), *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and msg in err[0]


@pytest.mark.slow
def test_tune_detectable_sizes_agree_with_the_evaluate_sweep_within_20_percent():
    """Single-window detection of steps at rest, 40 runs per size (11 sizes), probit fit:
    the measured 99 % size per scale agrees with rimu tune's within 20 % (with 60 runs per
    size: within 8 %, 95 % intervals about ±8 %)."""
    specs = design(CAL, THR, runs=0, sweep_runs=440, seed=0)
    ev = summarise(execute(simulation_task(CAL, THR), specs), THR, n_sensors=6,
                   predicted=detectable_sizes(CAL, THR))
    for r in ev["detectable_sizes"]["per_scale"]:
        assert abs(r["ratio"] - 1.0) < 0.2, r


@pytest.mark.slow
def test_cli_serial_and_local_cluster_processes_write_the_same_evaluation(tmp_path):
    """End to end through worker processes (pickling the calibration and the task): the
    two evaluation.json files differ only in their timing entry."""
    from rimu.cli import main

    cal = tmp_path / "cal.json"
    CAL.save(cal)
    docs = []
    for sched in ("serial", "local"):
        out = tmp_path / sched
        assert main(["evaluate", "--cal", str(cal), "--false-alarms-per-hour", "10",
                     "--runs", "24", "--sweep-runs", "22", "--duration", "6", "--seed", "9",
                     "--scheduler", sched, "--no-progress", "--out", str(out)]) == 0
        doc = json.loads((out / "evaluation.json").read_text())
        assert doc.pop("timing")["scheduler"] == sched
        docs.append(doc)
    assert docs[0] == docs[1]
