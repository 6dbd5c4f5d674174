"""Cross-validation folds put back an effect parameter their experiments cannot tell, even when the biases absorb it.

Data as in ``test_workbench``: DCMotor-v0 with a hidden 20-unit dead zone, reference step -30 -> +30 rad/s
(2 s, 1001 samples), five experiments; the fold of experiments 2 to 4 only crosses the dead band.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from agents.twin import ranking as diagnose_module
from agents.twin.candidates import refit_problem
from agents.twin.fits import fit_model
from agents.twin.least_squares import fit_problems
from agents.twin.records import Batch
from tests.support import loop_records

GAINS = np.array([[0.3, 1.0], [0.6, 1.5], [0.9, 1.2], [1.05, 2.0], [0.5, 1.9]])


def test_a_width_the_biases_absorb_is_put_back():
    data = Batch.from_records(loop_records({"dead_zone": {"width": 20.0}}, gains=GAINS, step=(-30.0, 30.0),
                                              noise=0.1, seed=0))
    fit = fit_model(data, ["dead_zone"])
    width = fit.theta[-1]
    assert abs(width - 20.0) < 0.5
    fold = refit_problem(data, fit, np.array([1, 2, 3]), True, tag=(0, 0))
    # the width moved to 11 along the fold's flat valley: the input biases take up the difference
    moved = replace(fold, theta=fold.theta.copy(), free=fold.free.copy())
    moved.theta[-7] = 11.0  # the width: the last global parameter (then 3 rest levels and 3 biases)
    moved.free[: moved.n_global] = False
    fit_problems(data, [moved], max_iter=6)
    alone = replace(moved, theta=moved.theta.copy())
    alone.theta[-7] = width  # the width alone put back: far worse, the biases no longer fit it
    fit_problems(data, [alone], max_iter=0)
    assert alone.cost > 100.0 * moved.cost
    moved.free[:] = fold.free
    cost = moved.cost
    diagnose_module._keep_undetermined(data, [moved], [fit])
    assert moved.theta[-7] == width
    assert moved.cost <= cost * (1.0 + 1e-9)  # with the biases refitted: the fold's cost
