"""``gbo twin diagnose`` on records made as real rigs make them, each with a known answer (issue 35).

The sets are the test suite's generator (:func:`tests.support.real_like_records`): a 0.1 s servo driven open
loop from rest (u = 0, y = 0 for 0.1 s), two input levels per record, six records alternating in sign (both
directions), speed from a 1024-line encoder differenced over 4 samples (a 1.53 rad/s quantum), 1 ms
samples, 2 s per record, and one hidden effect each:

* ``asymmetric_friction``: Coulomb friction 0.08 forward, 0.12 backward (``torque`` 0.1, ``asymmetry`` -0.2);
* ``saturation``: a drive limit of 0.45 input units;
* ``dead_zone``: a dead band 0.16 wide (the second level, 0.05, inside it: the motor coasts);
* ``time_delay``: 30 ms of dead time.

Each set is written as a workbench CSV and diagnosed by the command a user runs, ``gbo twin diagnose FILE
--json --quiet``; one JSON line per set: the best candidate, the RMSE before and after it, the noise floor and
the ratio of the two, and the command's wall time. Run from the repository root::

    python benchmarks/real_like_sets.py --out out/real_like
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:  # the generator lives in the test suite
    sys.path.insert(0, str(REPO))

from agents.twin.csvio import write_csv  # noqa: E402
from tests.support import real_like_records  # noqa: E402

SETS = {
    "asymmetric_friction": ({"coulomb_friction": {"torque": 0.1, "asymmetry": -0.2}}, (0.3, 0.6)),
    "saturation": ({"saturation": {"limit": 0.45}}, (0.3, 0.6)),
    "dead_zone": ({"dead_zone": {"width": 0.16}}, (0.5, 0.05)),
    "time_delay": ({"time_delay": {"delay": 0.03}}, (0.3, 0.6)),
}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", default="out/real_like", help="folder for the CSVs (default out/real_like)")
    parser.add_argument("--sets", nargs="*", choices=list(SETS), default=list(SETS))
    args = parser.parse_args(argv)
    out = Path(args.out)
    for name in args.sets:
        effects, levels = SETS[name]
        path = write_csv(real_like_records(effects, levels=levels), out / f"{name}.csv")
        start = time.perf_counter()
        done = subprocess.run([sys.executable, "-m", "evaluation.cli", "twin", "diagnose", str(path), "--json",
                               "--quiet"], capture_output=True, text=True, cwd=REPO, check=True)
        wall = time.perf_counter() - start
        payload = json.loads(done.stdout)
        best = payload["best_step"]
        after = best["rmse"] if best else payload["rmse"]
        noise = payload["noise_rmse"]
        print(json.dumps({"set": name, "hidden": effects, "best": payload["best"],
                          "params": best["params"].get(payload["best"]) if best else None,
                          "rmse_before": payload["rmse"], "rmse_after": after,
                          "rmse_fall_percent": best["rmse_fall_percent"] if best else 0.0, "noise_floor": noise,
                          "after_over_floor": after / noise if noise else None, "wall_s": round(wall, 2),
                          "command": f"gbo twin diagnose {path} --json --quiet"}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
