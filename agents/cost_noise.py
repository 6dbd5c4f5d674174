"""The cost noise ``sigma_eps`` of ``J = J_hat + epsilon`` from repeated experiments (paper, Secs. II-C, VI-A)."""

from __future__ import annotations

import numpy as np

from agents.space import GainSpace

__all__ = ["estimate_noise"]


def estimate_noise(env, gains=None, repeats: int = 5, seed: int | None = None) -> tuple[float, np.ndarray]:
    """Estimate ``sigma_eps`` of ``J = J_hat + epsilon`` by repeating one experiment.

    The paper (Secs. II-C and VI-A) measures the cost five times at one
    randomly selected ``theta`` and takes the spread as ``sigma_eps``. Each
    repetition is a **real plant experiment**: on hardware it costs as much as
    a tuning experiment, so count them in any experiment budget. The env is
    stepped ``repeats`` times (its experiment counter advances; on a drifting
    plant the repeats see the drift).

    Parameters
    ----------
    env : gymnasium.Env
        A plant env; its measured ``info["cost"]`` is used (never ``true_cost``).
    gains : array_like of shape (n_gains,), optional
        The gains to repeat; default: drawn uniformly from the feasible set.
    repeats : int, default 5
        Number of experiments, ``>= 2``.
    seed : int, optional
        Seeds the draw of ``gains``. The env is not reset: reset it beforehand
        (``env.reset(seed=...)``) to make the measurement noise reproducible.

    Returns
    -------
    sigma : float
        Sample standard deviation (``ddof=1``) of the measured costs, cost units.
    costs : ndarray of shape (repeats,)
        The measured costs.
    """
    if int(repeats) < 2:
        raise ValueError(f"repeats: need >= 2 experiments for a standard deviation, got {repeats}")
    space = GainSpace.from_env(env)
    if gains is None:
        gains = np.random.default_rng(seed).uniform(space.low, space.high)
    gains = space.check(gains, name="estimate_noise(gains)")
    costs = np.array([float(env.step(gains.copy())[4]["cost"]) for _ in range(int(repeats))])
    return float(np.std(costs, ddof=1)), costs
