"""The grey-box solver: the hand-written bounded Levenberg-Marquardt iteration that ``greybox.fit_problems``
had, against ``scipy.optimize.least_squares`` (method "trf" with bounds), which ``fit_problems`` now runs.

The problems are the ones ``gbo twin diagnose`` builds on three DCMotor-v0 records
(1.5 s each, sensor noise 0.1 rad/s) with a hidden saturation (150 V) and
Coulomb friction (3 N m): the refit of the current (linear) model and the
candidate problems of each catalogued effect with a smooth simulation error
(quantization and cogging left out). Both solvers minimise the same residual
(:func:`agents.twin.least_squares.residual`) over the same free parameters, from the
same start, within the same bounds and scales, with the same forward-difference
Jacobian (the per-record rest levels and biases perturbed all at once), the same
relative cost-decrease tolerance (``tol = 1e-7``, least_squares' ``ftol``) and the
same cap of ``max_iter`` trial points after the start, at ``max_iter`` = 25 (the
workbench's default) and 5.

Prints one JSON object: for each ``max_iter``, the wall times in s of the
hand-written solver on all problems in lock-step (as diagnose ran it) and one
problem at a time, of ``fit_problems`` (least_squares, one problem at a time),
and the final costs (sums of squared residuals, (rad/s)^2) of each problem under
both; ``least_squares_cost_below_hand_lm`` counts the problems where
least_squares ends lower.
"""

from __future__ import annotations

import json
import time

import gymnasium as gym
import numpy as np

import gbo_envs  # noqa: F401  (registers the envs)
from agents.thread_limits import single_thread
from agents.twin.candidates import candidate_problems
from agents.twin.csvio import records_from_loop
from agents.twin.least_squares import Problem, fit_problems, make_problem, residual
from agents.twin.linear_fit import linear_fit
from agents.twin.model import FITTED_PARAMETERS
from agents.twin.records import Batch
from agents.twin.simulation import simulate_sets

EFFECTS = ("saturation", "coulomb_friction", "dead_zone", "viscous_friction", "backlash", "stiction", "offset",
           "time_delay")
MAX_ITER = 25
TOL = 1e-7


def diagnose_problems() -> tuple[Batch, list[Problem]]:
    """The data and the problems diagnose builds on a saturating DC motor with Coulomb friction."""
    env = gym.make("gbo_envs/DCMotor-v0", effects={"saturation": {"limit": 150.0}, "coulomb_friction": {
        "torque": 3.0}}, output_noise_std=0.1)
    loop = env.unwrapped.loop.replace(duration=1.5)
    gains = np.array([[0.3, 1.0], [0.9, 1.2], [1.05, 2.0]])
    data = Batch.from_records(records_from_loop(loop, gains, rng=np.random.default_rng(0)))
    base = linear_fit(data)
    rows = np.arange(data.n_records)
    problems = [make_problem(data, base.spec, base.theta, base.y0, base.bias, rows, tag="current")]
    for name in EFFECTS:
        problems += candidate_problems(data, base, name, tag=name)
    return data, problems


def copy_problem(p: Problem) -> Problem:
    """A fresh copy of ``p`` at its start."""
    return Problem(p.spec, p.rows, p.theta.copy(), p.lower, p.upper, p.scale, p.free, tag=p.tag)


def hand_lm(data: Batch, problems: list[Problem], max_iter: int = MAX_ITER, tol: float = TOL) -> list[Problem]:
    """The hand-written bounded Levenberg-Marquardt that ``fit_problems`` had: all problems in lock-step.

    Each iteration simulates, in one batch, the forward-difference sets of the
    problems whose Jacobian is stale, then the trial points of all active
    problems. The step solves ``(J^T J + lam diag(J^T J)) d = -J^T e`` in the
    scaled parameters and is clipped to the bounds; ``lam`` falls by 3 on
    success and grows by 4 on failure.

    Returns
    -------
    list of Problem
        The same objects, with ``theta``, ``cost``, ``residual`` and ``y_sim`` set.
    """
    sims = simulate_sets(data, [(p.spec, p.theta, p.rows) for p in problems])
    rough = [any(not smooth for name, _ in p.spec.effects for _, smooth in FITTED_PARAMETERS[name])
             for p in problems]
    base_true: dict[int, np.ndarray] = {}
    lam = {id(p): 1e-3 for p in problems}
    done = {id(p): not np.any(p.free) for p in problems}
    for p, y in zip(problems, sims):
        p.y_sim, p.residual = y, residual(data, p.rows, y)
        p.cost = float(np.sum(p.residual**2))
    jac: dict[int, np.ndarray] = {}
    for _ in range(max_iter):
        active = [p for p in problems if not done[id(p)]]
        if not active:
            break
        # 1. Jacobians of the problems whose point moved
        sets, layout = [], []
        for i, p in enumerate(problems):
            if done[id(p)] or i in jac:
                continue
            g = p.n_global
            cols = [j for j in range(g) if p.free[j]]
            steps = {}
            for j in cols:
                h = 1e-6 * max(abs(p.theta[j]), p.scale[j])
                h = h if p.theta[j] + h <= p.upper[j] else -h
                trial = p.theta.copy()
                trial[j] += h
                steps[j] = h
                sets.append((p.spec, trial, p.rows))
                layout.append((i, ("global", j, h)))
            for block, start in (("y0", g), ("bias", g + p.rows.size)):
                if not p.free[start]:
                    continue
                h = 1e-6 * max(float(np.max(np.abs(p.theta[start : start + p.rows.size]))), p.scale[start])
                trial = p.theta.copy()
                trial[start : start + p.rows.size] += h
                sets.append((p.spec, trial, p.rows))
                layout.append((i, (block, start, h)))
        if sets:
            sims = simulate_sets(data, sets)
            need = sorted({i for i, _ in layout if rough[i]})
            if need:  # quantized output: differentiate the plant output before the sensor instead
                smooth = simulate_sets(data, sets, true_output=True)
                sims = [smooth[n] if rough[i] else y for n, ((i, _), y) in enumerate(zip(layout, sims))]
                base = simulate_sets(data, [(problems[i].spec, problems[i].theta, problems[i].rows) for i in need],
                                     true_output=True)
                base_true.update({i: residual(data, problems[i].rows, y) for i, y in zip(need, base)})
            columns: dict[int, np.ndarray] = {}
            for (i, (kind, start, h)), y in zip(layout, sims):
                p = problems[i]
                mat = columns.setdefault(i, np.zeros((p.residual.size, p.theta.size)))
                ref = base_true[i] if rough[i] else p.residual
                diff = (residual(data, p.rows, y) - ref) / h
                if kind == "global":
                    mat[:, start] = diff.ravel()
                else:
                    n = data.u.shape[1]
                    for r in range(p.rows.size):
                        mat[r * n : (r + 1) * n, start + r] = diff[r]
            jac.update(columns)
        # 2. trial steps
        trials = []
        for i, p in enumerate(problems):
            if done[id(p)]:
                continue
            J = jac[i][:, p.free] * p.scale[p.free]
            e = p.residual.ravel()
            jtj = J.T @ J
            grad = J.T @ e
            diag = np.maximum(np.diag(jtj), 1e-12 * max(np.max(np.diag(jtj)), 1e-300))
            try:
                d = -np.linalg.solve(jtj + lam[id(p)] * np.diag(diag), grad)
            except np.linalg.LinAlgError:
                d = -np.linalg.lstsq(jtj + lam[id(p)] * np.diag(diag), grad, rcond=None)[0]
            theta = p.theta.copy()
            theta[p.free] = np.clip(p.theta[p.free] + d * p.scale[p.free], p.lower[p.free], p.upper[p.free])
            trials.append((i, theta))
        sims = simulate_sets(data, [(problems[i].spec, th, problems[i].rows) for i, th in trials])
        for (i, theta), y in zip(trials, sims):
            p = problems[i]
            p.n_iter += 1
            res = residual(data, p.rows, y)
            cost = float(np.sum(res**2))
            if cost < p.cost:
                gain = (p.cost - cost) / max(p.cost, 1e-300)
                p.theta, p.cost, p.residual, p.y_sim = theta, cost, res, y
                lam[id(p)] = max(lam[id(p)] / 3.0, 1e-9)
                jac.pop(i, None)
                if gain < tol:
                    done[id(p)] = True
            else:
                lam[id(p)] *= 4.0
                if lam[id(p)] > 1e8:
                    done[id(p)] = True
            if p.n_iter >= max_iter:
                done[id(p)] = True
    return problems


def _timed(solve, data: Batch, problems: list[Problem], max_iter: int, lockstep: bool) -> tuple[float, list]:
    fits = [copy_problem(p) for p in problems]
    start = time.perf_counter()
    if lockstep:
        solve(data, fits, max_iter=max_iter, tol=TOL)
    else:
        for p in fits:
            solve(data, [p], max_iter=max_iter, tol=TOL)
    return time.perf_counter() - start, fits


@single_thread()
def main() -> dict:
    data, problems = diagnose_problems()
    result = {"n_problems": len(problems), "n_samples": data.n_samples, "tol": TOL}
    for max_iter in (MAX_ITER, 5):
        t_lockstep, hand = _timed(hand_lm, data, problems, max_iter, lockstep=True)
        t_single, _ = _timed(hand_lm, data, problems, max_iter, lockstep=False)
        t_scipy, scipy_fits = _timed(fit_problems, data, problems, max_iter, lockstep=False)
        costs = [{"problem": str(p.tag), "n_free": int(p.free.sum()), "start": float(np.sum(residual(
            data, p.rows, simulate_sets(data, [(p.spec, p.theta, p.rows)])[0]) ** 2)), "hand_lm": float(a.cost),
                  "least_squares": float(b.cost)} for p, a, b in zip(problems, hand, scipy_fits)]
        result[f"max_iter_{max_iter}"] = {
            "hand_lm_lockstep_s": t_lockstep,
            "hand_lm_one_at_a_time_s": t_single,
            "least_squares_s": t_scipy,
            "total_cost_hand_lm": float(sum(c["hand_lm"] for c in costs)),
            "total_cost_least_squares": float(sum(c["least_squares"] for c in costs)),
            "least_squares_cost_below_hand_lm": sum(c["least_squares"] < c["hand_lm"] for c in costs),
            "costs": costs,
        }
    return result


if __name__ == "__main__":
    print(json.dumps(main()))
