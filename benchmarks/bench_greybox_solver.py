"""The grey-box solver: the hand-written bounded Levenberg-Marquardt of ``greybox.fit_problems`` against
``scipy.optimize.least_squares`` (method "trf" with bounds) on the same problems.

The problems are the ones ``gbo twin diagnose`` builds on three DCMotor-v0 records
(1.5 s each, sensor noise 0.1 rad/s) with a hidden saturation (150 V) and
Coulomb friction (3 N m): the refit of the current (linear) model and the
candidate problems of each catalogued effect with a smooth simulation error
(quantization and cogging left out). Both solvers minimise the same residual
(:func:`agents.twin.greybox.residual`) over the same free parameters, from the
same start, within the same bounds and scales, with the same forward-difference
Jacobian (the per-record rest levels and biases perturbed all at once), the same
relative cost-decrease tolerance (``ftol = tol = 1e-7``) and the same cap on
evaluated points (``max_iter = 25`` trial points after the start; xtol and gtol of least_squares set to
``1e-12`` so that they do not stop it first).

Prints one JSON object: wall times in s of the hand-written solver on all problems
in lock-step (as diagnose runs it) and one problem at a time, of least_squares one
problem at a time, and the final cost (sum of squared residuals, (rad/s)^2) of each
problem under both.
"""

from __future__ import annotations

import json
import time

import gymnasium as gym
import numpy as np
from scipy.optimize import least_squares

import gbo_envs  # noqa: F401  (registers the envs)
from agents.twin.csvio import records_from_loop
from agents.twin.fitting import candidate_problems, linear_fit, make_problem, single_thread
from agents.twin.greybox import GreyData, Problem, fit_problems, residual, simulate_sets

EFFECTS = ("saturation", "coulomb_friction", "dead_zone", "viscous_friction", "backlash", "stiction", "offset",
           "time_delay")
MAX_ITER = 25
TOL = 1e-7


def diagnose_problems() -> tuple[GreyData, list[Problem]]:
    """The data and the problems diagnose builds on a saturating DC motor with Coulomb friction."""
    env = gym.make("gbo_envs/DCMotor-v0", effects={"saturation": {"limit": 150.0}, "coulomb_friction": {
        "torque": 3.0}}, output_noise_std=0.1)
    loop = env.unwrapped.loop.replace(duration=1.5)
    gains = np.array([[0.3, 1.0], [0.9, 1.2], [1.05, 2.0]])
    data = GreyData.from_records(records_from_loop(loop, gains, rng=np.random.default_rng(0)))
    base = linear_fit(data)
    rows = np.arange(data.n_records)
    problems = [make_problem(data, base.spec, base.theta, base.y0, base.bias, rows, tag="current")]
    for name in EFFECTS:
        problems += candidate_problems(data, base, name, tag=name)
    return data, problems


def _copy(p: Problem) -> Problem:
    return Problem(p.spec, p.rows, p.theta.copy(), p.lower, p.upper, p.scale, p.free, tag=p.tag)


def solve_least_squares(data: GreyData, p: Problem, max_iter: int = MAX_ITER, tol: float = TOL) -> Problem:
    """``p`` solved by ``scipy.optimize.least_squares`` (trf, bounds) with fit_problems' residual and Jacobian."""
    free = np.flatnonzero(p.free)
    g, k = p.n_global, p.rows.size
    start = p.theta.copy()

    def full(x: np.ndarray) -> np.ndarray:
        theta = start.copy()
        theta[free] = x
        return theta

    def fun(x: np.ndarray) -> np.ndarray:
        return residual(data, p.rows, simulate_sets(data, [(p.spec, full(x), p.rows)])[0]).ravel()

    def jac(x: np.ndarray) -> np.ndarray:
        theta = full(x)
        sets, columns = [], []
        for j in free[free < g]:  # one column per global parameter
            h = 1e-6 * max(abs(theta[j]), p.scale[j])
            h = h if theta[j] + h <= p.upper[j] else -h
            trial = theta.copy()
            trial[j] += h
            sets.append((p.spec, trial, p.rows))
            columns.append(([j], h))
        for first in (g, g + k):  # the rest levels (or biases) of all records at once: each moves its own record
            if p.free[first]:
                h = 1e-6 * max(float(np.max(np.abs(theta[first : first + k]))), p.scale[first])
                trial = theta.copy()
                trial[first : first + k] += h
                sets.append((p.spec, trial, p.rows))
                columns.append((list(range(first, first + k)), h))
        base = residual(data, p.rows, simulate_sets(data, [(p.spec, theta, p.rows)])[0])
        n = data.u.shape[1]
        mat = np.zeros((base.size, theta.size))
        for (cols, h), y in zip(columns, simulate_sets(data, sets)):
            diff = (residual(data, p.rows, y) - base) / h
            if len(cols) == 1:
                mat[:, cols[0]] = diff.ravel()
            else:
                for r, c in enumerate(cols):
                    mat[r * n : (r + 1) * n, c] = diff[r]
        return mat[:, free]

    sol = least_squares(fun, start[free], jac=jac, bounds=(p.lower[free], p.upper[free]), x_scale=p.scale[free],
                        method="trf", ftol=tol, xtol=1e-12, gtol=1e-12, max_nfev=max_iter + 1)
    out = _copy(p)
    out.theta = full(sol.x)
    out.residual = sol.fun.reshape(p.rows.size, -1)
    out.cost = float(np.sum(sol.fun**2))
    out.n_iter = int(sol.nfev)
    return out


@single_thread
def main() -> dict:
    data, problems = diagnose_problems()
    lockstep = [_copy(p) for p in problems]
    start = time.perf_counter()
    fit_problems(data, lockstep, max_iter=MAX_ITER, tol=TOL)
    t_lockstep = time.perf_counter() - start
    single = [_copy(p) for p in problems]
    start = time.perf_counter()
    for p in single:
        fit_problems(data, [p], max_iter=MAX_ITER, tol=TOL)
    t_single = time.perf_counter() - start
    start = time.perf_counter()
    scipy_fits = [solve_least_squares(data, p) for p in problems]
    t_scipy = time.perf_counter() - start
    costs = [{"problem": str(p.tag), "n_free": int(p.free.sum()), "hand_lm": float(a.cost),
              "least_squares": float(b.cost)} for p, a, b in zip(problems, lockstep, scipy_fits)]
    return {
        "n_problems": len(problems),
        "n_samples": data.n_samples,
        "hand_lm_lockstep_s": t_lockstep,
        "hand_lm_one_at_a_time_s": t_single,
        "least_squares_one_at_a_time_s": t_scipy,
        "total_cost_hand_lm": float(sum(c["hand_lm"] for c in costs)),
        "total_cost_least_squares": float(sum(c["least_squares"] for c in costs)),
        "costs": costs,
    }


if __name__ == "__main__":
    print(json.dumps(main()))
