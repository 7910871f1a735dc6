"""``rimu calibrate PROCEDURE``: each procedure shows only its own options, and the spellings
from before the split are refused in one line with the new spelling (issue 29)."""

from __future__ import annotations

import argparse

import pytest

from rimu.cli import build_parser, main

OWN = {
    "turntable": {"--out", "--compare", "--bias-method", "--noise-model", "--no-denoise",
                  "--plot", "--sensor-class", "--effects", "--alpha"},
    "ferraris": {"--out", "--sections", "--sample-rate-hz", "--rotation-deg", "--gravity",
                 "--position-sd-deg", "--angle-sd-deg", "--latitude-deg", "--raw-unit"},
    "in-flight": {"--out", "--window", "--prior-misalignment-deg", "--prior-scale-pct",
                  "--prior-nonorthogonality-pct", "--reference", "--model",
                  "--no-time-offset", "--drift-model", "--report"},
    "static": {"--out", "--reference"},
}
"""The options of each procedure, read from the single option list before the split
(which refused or ignored the others beside each procedure)."""
POSITIONAL = {"turntable": "SESSION", "ferraris": "CSV", "in-flight": "DIR", "static": "DIR"}


def _procedures() -> dict[str, argparse.ArgumentParser]:
    top = build_parser(["calibrate"])
    cal = next(a for a in top._actions if isinstance(a, argparse._SubParsersAction))
    sub = cal.choices["calibrate"]
    act = next(a for a in sub._actions if isinstance(a, argparse._SubParsersAction))
    return dict(act.choices)


def test_the_procedures_are_the_four():
    assert list(_procedures()) == ["turntable", "ferraris", "in-flight", "static"]


@pytest.mark.parametrize("name", list(OWN))
def test_each_procedure_has_only_its_own_options(name):
    p = _procedures()[name]
    opts = {o for a in p._actions for o in a.option_strings if o.startswith("--")} - {"--help"}
    assert opts == OWN[name]
    assert [a.metavar for a in p._actions if not a.option_strings] == [POSITIONAL[name]]


@pytest.mark.parametrize("name", list(OWN))
def test_each_procedures_help_shows_only_its_own_options(name, capsys):
    assert main(["calibrate", name, "--help"]) == 0
    text = capsys.readouterr().out
    others = set().union(*(v for k, v in OWN.items() if k != name)) - OWN[name]
    for opt in OWN[name]:
        assert opt in text, opt
    for opt in others:
        assert opt not in text.replace(f"{opt}-", ""), (name, opt)
    assert POSITIONAL[name] in text


def test_calibrate_help_lists_the_procedures(capsys):
    assert main(["calibrate", "--help"]) == 0
    text = capsys.readouterr().out
    for name in OWN:
        assert name in text
    assert "--out" not in text and "--ferraris" not in text


@pytest.mark.parametrize("old, new", [
    (["calibrate", "sess", "--out", "c.json"],
     "rimu calibrate turntable sess --out c.json"),
    (["calibrate", "sess", "--out", "c.json", "--compare", "sess/truth.json"],
     "rimu calibrate turntable sess --out c.json --compare sess/truth.json"),
    (["calibrate", "--in-flight", "f1", "f2", "--out", "c.json"],
     "rimu calibrate in-flight f1 f2 --out c.json"),
    (["calibrate", "--out", "c.json", "--in-flight", "f1", "--window", "1:9"],
     "rimu calibrate in-flight f1 --window 1:9 --out c.json"),
    (["calibrate", "--static", "rest", "--out", "c.json"],
     "rimu calibrate static rest --out c.json"),
    (["calibrate", "--static=rest", "--out", "c.json"],
     "rimu calibrate static rest --out c.json"),
    (["calibrate", "--ferraris", "s.csv", "--sample-rate-hz", "100", "--out", "c.json"],
     "rimu calibrate ferraris s.csv --sample-rate-hz 100 --out c.json"),
    (["--debug", "calibrate", "--ferraris", "s.csv", "--out", "c.json"],
     "rimu calibrate ferraris s.csv --out c.json"),
])
def test_old_spellings_are_refused_with_the_new_one(old, new, capsys, tmp_path,
                                                    monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(old) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1, err
    assert err.startswith("rimu: error: rimu calibrate ") and "is now a subcommand" in err
    assert new in err, err
    proc = new.split()[2]
    assert f"rimu calibrate {proc} --help" in err or proc == "turntable"
    assert not any(tmp_path.iterdir())              # refused before anything is read


def test_the_new_spelling_the_hint_gives_parses():
    from rimu.commands.calibrate import old_spelling

    for old in (["sess", "--out", "c.json"], ["--in-flight", "f1", "f2", "--out", "c.json"],
                ["--static", "d", "--out", "c.json"],
                ["--ferraris", "s.csv", "--sample-rate-hz", "100", "--out", "c.json"]):
        new = old_spelling(old).split(": ", 1)[1].split(" (")[0].split()[1:]
        args = build_parser(new).parse_args(new)
        assert args.command == "calibrate" and args.what == new[1]
        assert args.out == "c.json"
