"""The digital twin as an env: the plant env's closed loop and cost with the identified plant.

The paper's DT "is the same closed-loop system but with a DT plant instead of
the real plant" (subsec. Digital Twin). :class:`TwinEnv` copies from the plant
env it mirrors the controller, the sample time, the step experiment
(``r1 -> r2`` over ``T``), the metric weights, the feasible set and, crucially,
the cost normalisers ``n_i`` of eq. (J_used), so that twin and plant costs are
on the same scale. Its plant is the identified one, with the effects the twin
models (none for a linear twin), so a batch of gains runs through the
vectorised simulator in one call of :meth:`evaluate`.

A plant's cost is measured on a noisy output, and its ground truth is the
expected cost over that noise (:meth:`gbo_envs.ControllerTuningEnv.evaluate`).
Where the settling band is narrow, the noise moves the optimum: on
``DCMotorRig-v0`` (speed noise about 0.09 rad/s against a 1.22 rad/s band) the
optimum of the exact plant simulated without noise has 1.33 times the rig's
optimal expected cost. A twin given the measured noise floor
(``measurement_noise_std``) reproduces that expectation the same way, over
``draws`` fixed draws of white output noise, and its optimum there is within
1.02 of the rig's (``benchmarks/twin_noise.py``).
"""

from __future__ import annotations

import numpy as np

from gbo_envs import ContinuousPlant, ControllerTuningEnv, CostSpec

__all__ = ["TwinEnv", "make_twin_env"]


class TwinEnv(ControllerTuningEnv):
    """A :class:`gbo_envs.ControllerTuningEnv` whose plant is a fitted digital twin.

    Parameters
    ----------
    plant_env : gymnasium.Env
        The env the twin mirrors (wrappers from ``gym.make`` are looked through).
    twin : fitted LinearTwin or GreyBoxTwin, or gbo_envs.ContinuousPlant
        The identified plant (``twin.plant_``), or a plant directly. A twin with
        ``effects_`` (physical effect blocks) adds them to the loop.
    cost_noise_std : float, default 0.0
        Additive cost noise of the twin (the paper's guided BO adds its own).
    measurement_noise_std : float, default 0.0
        Standard deviation of white noise on the twin's measured output, in output
        units (the records' noise floor, :func:`agents.twin.noise_floor.noise_floor`),
        ``>= 0``. With noise, :meth:`evaluate` returns the expected cost over
        ``draws`` fixed noise draws (common random numbers), as the plant env's
        ground truth does.
    draws : int, default 8
        Noise draws ``K`` of the expectation, ``>= 1`` (used only with noise).

    Notes
    -----
    The twin plant takes the plant env's output kind (``"speed"`` or
    ``"position"``), so effect blocks act on the right mechanical speed. Unlike
    the plant env, the twin does not vary between experiments.

    Examples
    --------
    >>> twin_env = TwinEnv(plant_env, LinearTwin().fit(records))  # doctest: +SKIP
    >>> metrics, cost = twin_env.evaluate(gains)  # gains of shape (batch, n_gains)  # doctest: +SKIP
    """

    experiment_source = "twin"  # info["experiment"].source of a step on the twin

    def __init__(self, plant_env, twin, cost_noise_std: float = 0.0, measurement_noise_std: float = 0.0,
                 draws: int = 8) -> None:
        base = getattr(plant_env, "unwrapped", plant_env)
        if not isinstance(base, ControllerTuningEnv):
            raise TypeError(f"plant_env: expected a gbo_envs ControllerTuningEnv, got {type(base).__name__}")
        if not np.isfinite(measurement_noise_std) or measurement_noise_std < 0.0:
            raise ValueError(f"measurement_noise_std: must be a finite number >= 0 (output units), "
                             f"got {measurement_noise_std}")
        loop = base.loop
        if isinstance(twin, ContinuousPlant):
            fitted, effects = twin, ()
        else:
            fitted = getattr(twin, "plant_", None)
            if fitted is None:
                raise ValueError("twin: the estimator is not fitted; call twin.fit(records) first")
            effects = tuple(getattr(twin, "effects_", ()) or ())
        plant = ContinuousPlant(num=fitted.num, den=fitted.den, delay=fitted.delay, output=loop.plant.output)
        self.twin = twin
        self.plant_env = base
        super().__init__(
            loop=loop.replace(plant=plant, effects=effects, output_noise_std=float(measurement_noise_std)),
            gain_low=base.action_space.low,
            gain_high=base.action_space.high,
            cost=CostSpec(weights=base.weights, normalizers=base.normalizers, unstable_cost=base.unstable_cost),
            cost_noise_std=cost_noise_std,
            max_experiments=base.max_experiments,
            out_of_bounds=base.out_of_bounds,
            expectation_draws=draws,
        )
        self._noise_free: TwinEnv | None = None  # made by noise_free() on first use

    def evaluate(self, gains: np.ndarray, experiment_index: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Metrics of shape (batch, 4) and cost of shape (batch,) of the twin for gains of shape (batch, n_gains).

        Same contract as :meth:`gbo_envs.ControllerTuningEnv.evaluate`: the expected
        metrics and cost over the twin's measurement noise (one simulation without
        noise). The twin is time-invariant, so its loop is simulated as it is.
        """
        metrics, cost, _ = self._expected(self.loop, np.atleast_2d(np.asarray(gains, dtype=float)), record=False)
        return metrics, cost

    def noise_free(self) -> TwinEnv:
        """This twin without its random parts (itself if it has none): one simulation per gain.

        No measurement noise, and a cogging ripple that starts at the same angle in every
        experiment (``synchronised``; in a speed loop the twin draws the angle per noise draw,
        as the plant does, see :class:`gbo_envs.physics.actuator.Cogging`).

        Returns
        -------
        TwinEnv
            The same plant, controller, cost and bounds with ``measurement_noise_std=0`` and
            deterministic effects.
        """
        if not self.loop.stochastic:
            return self
        if self._noise_free is None:
            twin = TwinEnv(self.plant_env, self.twin, cost_noise_std=self.cost_noise_std,
                           measurement_noise_std=0.0, draws=self.expectation_draws)
            twin.loop = twin.loop.replace(effects=tuple(block.at_fixed_start() for block in twin.loop.effects))
            self._noise_free = twin
        return self._noise_free

    @property
    def plant(self) -> ContinuousPlant:
        """The twin's plant."""
        return self.loop.plant


def make_twin_env(plant_env, twin, cost_noise_std: float = 0.0, measurement_noise_std: float = 0.0,
                  draws: int = 8) -> TwinEnv:
    """Twin env mirroring ``plant_env`` with the fitted ``twin``; see :class:`TwinEnv`."""
    return TwinEnv(plant_env, twin, cost_noise_std=cost_noise_std, measurement_noise_std=measurement_noise_std,
                   draws=draws)
