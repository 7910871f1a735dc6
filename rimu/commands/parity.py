"""``rimu parity CONFIG``: measurement matrix, parity matrix and isolability."""

from __future__ import annotations

import argparse
import json
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import numpy as np

HELP = "print H, the parity matrix V and the isolability of each sensor pair"


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", help="tetrad, cone6, triad or a TOML configuration file")
    p.add_argument("--misalignment", metavar="FILE",
                   help="a rimu calibration file: also print the calibrated axes and V_c")
    p.add_argument("--json", action="store_true", help="print JSON instead of text")


def _clean(a: np.ndarray, decimals: int = 12) -> np.ndarray:
    """``a`` rounded, with negative zeros made positive (no ``-0.`` in the output)."""
    import numpy as np

    return np.round(np.asarray(a, float), decimals) + 0.0


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from fdi.calfile import load_calibration
    from fdi.geometry import load_configuration
    from fdi.parity import isolability, parity_matrix
    from rimu.outputs import input_path

    if args.misalignment:
        input_path(args.misalignment, "--misalignment")
    cfg = load_configuration(args.config)
    V = _clean(parity_matrix(cfg.H))
    iso = isolability(V)
    out: dict[str, object] = {
        "configuration": cfg.name,
        "sensors": list(cfg.sensor_names),
        "H": _clean(cfg.H).tolist(),
        "V": V.tolist(),
        "detectable": iso["detectable"],
        "isolable_pairs": [
            {"pair": [i + 1, j + 1], "isolable": ok, "cos": float(iso["pair_cos"][i, j])}
            for (i, j), ok in zip(((i, j) for i in range(cfg.n) for j in range(i + 1, cfg.n)),
                                  iso["isolable_pairs"], strict=True)],
        "can_isolate": iso["can_isolate"],
    }
    if args.misalignment:
        cal = load_calibration(args.misalignment)
        Ht = cal.gyro.H
        if Ht.shape != cfg.H.shape:
            from fdi.errors import ConfigError
            raise ConfigError(f"{args.misalignment}: {Ht.shape[0]} gyros, configuration "
                              f"{cfg.name} has {cfg.n}")
        out["H_calibrated"] = Ht.tolist()
        out["V_calibrated"] = _clean(parity_matrix(Ht)).tolist()
    if args.json:
        print(json.dumps(out, indent=1))
        return 0
    np.set_printoptions(precision=5, suppress=True, linewidth=100)
    print(f"configuration {cfg.name}: {cfg.n} sensors, {V.shape[0]} parity equation(s)")
    print("H =\n" + str(_clean(cfg.H, 5)))
    print("V =\n" + str(_clean(V, 5)))
    if "V_calibrated" in out:
        print("H_c (calibrated axes) =\n" + str(_clean(np.array(out["H_calibrated"]), 5)))
        print("V_c =\n" + str(_clean(np.array(out["V_calibrated"]), 5)))
    bad = [p["pair"] for p in out["isolable_pairs"] if not p["isolable"]]
    print("isolation: " + ("every pair isolable" if not bad else
                           f"{len(bad)} pair(s) cannot be told apart: {bad}"))
    return 0
