"""Tuners that only the benchmark studies use: guided BO with a wrong or an exact twin, mf-bo with a noise twin.

The studies import this module (``[study] imports = ["evaluation.study_tuners"]``) and name the tuners
it registers, as a researcher's module registers a tuner for ``gbo bench suite --import``:

* ``guided-bo-wrong-twin``: the default guided BO given a deliberately wrong fitted twin
  (:func:`wrong_twin`), which must not make it worse than BO (issue 15; the ablation's
  ``wrong user twin``);
* ``guided-bo-oracle-twin``: the default guided BO given the plant's own model as its twin
  (:class:`OracleTwin`: the env's linear plant and effect blocks with their true parameters),
  which tells a loss in identifying the twin from one in using it (the oracle study);
* ``mf-bo-noise-twin``: multi-fidelity BO whose twin cost is pure noise, log-normal around the
  plant's median measured cost: the fidelity estimate must drop and the tuner behave as ``bo``.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from sklearn.base import BaseEstimator

import agents
import gbo_envs  # noqa: F401  (registers the envs)
from agents.guided_bo import GuidedBO
from agents.mf_bo import MultiFidelityBO
from agents.twin import IdentifyOptions, LinearTwin, SrivcOptions

__all__ = ["NoiseTwinMFBO", "OracleTwin", "OracleTwinGuidedBO", "WrongTwinGuidedBO", "wrong_twin"]


def wrong_twin():
    """A fitted :class:`~agents.twin.LinearTwin` of another plant: DCMotor-v0 behind a 60 ms dead time and a
    120-unit drive limit, identified from two experiments (its optimum costs DCMotor-v0 over 1.5 J*)."""
    other = gym.make("gbo_envs/DCMotor-v0", effects={"time_delay": {"delay": 0.06}, "saturation": {"limit": 120.0}})
    other.reset(seed=0)
    records = [other.step(np.array(gains))[4] for gains in ([0.5, 1.2], [0.9, 1.6])]
    return LinearTwin(IdentifyOptions(solver=SrivcOptions(n_samples=100))).fit(records)


class WrongTwinGuidedBO(GuidedBO):
    """The default :class:`~agents.guided_bo.GuidedBO` with ``twin=wrong_twin()`` (made when the run starts)."""

    name = "guided-bo-wrong-twin"

    def run(self, env, *args, **kwargs):
        self.twin = wrong_twin()
        return super().run(env, *args, **kwargs)


class OracleTwin(BaseEstimator):
    """A plant's own model as a fitted twin: its linear part and effect blocks with their true parameters.

    Parameters
    ----------
    loop : gbo_envs.ClosedLoop or None
        The plant env's closed loop (``env.unwrapped.loop``); ``fit`` copies its plant and effects (the
        records are ignored).

    Attributes
    ----------
    plant_ : gbo_envs.ContinuousPlant
    effects_ : tuple of EffectBlock
    effect_params_ : dict
        ``{effect: {}}`` (names only, for the run's records).
    params_ : ndarray
        Numerator and denominator coefficients of ``plant_``.
    rmse_ : float
        0: the model is exact.
    """

    def __init__(self, *, loop=None) -> None:
        self.loop = loop

    def fit(self, records=None, y=None) -> OracleTwin:
        """Copy the plant's model; ``records`` are ignored."""
        self.plant_ = self.loop.plant
        self.effects_ = tuple(self.loop.effects)
        self.effect_params_ = {block.name: {} for block in self.effects_}
        self.params_ = np.concatenate([np.ravel(self.loop.plant.num), np.ravel(self.loop.plant.den)]).astype(float)
        self.rmse_ = 0.0
        return self

    def score(self, records, y=None) -> float:
        """0: the exact model never mispredicts (negative normalised RMSE, scikit-learn's sign)."""
        return 0.0


class OracleTwinGuidedBO(GuidedBO):
    """The default :class:`~agents.guided_bo.GuidedBO` with the plant's own model as its fitted twin."""

    name = "guided-bo-oracle-twin"

    def run(self, env, *args, **kwargs):
        self.twin = OracleTwin(loop=env.unwrapped.loop).fit()
        return super().run(env, *args, **kwargs)


class NoiseTwinMFBO(MultiFidelityBO):
    """:class:`~agents.mf_bo.MultiFidelityBO` whose twin cost is pure noise: log-normal (sigma 1) around the
    median measured cost."""

    name = "mf-bo-noise-twin"

    def _setup(self) -> None:
        super()._setup()
        self._noise = np.random.default_rng(12345 if self.seed is None else self.seed + 12345)

    def _twin_costs(self, twin_env, unit):
        cache = self._twin_cache[1]
        scale = float(np.median(self._plant_y))
        for x in unit:
            cache.setdefault(tuple(x), scale * float(np.exp(self._noise.standard_normal())))
        return np.array([cache[tuple(x)] for x in unit])


agents.register("guided-bo-wrong-twin", WrongTwinGuidedBO)
agents.register("guided-bo-oracle-twin", OracleTwinGuidedBO)
agents.register("mf-bo-noise-twin", NoiseTwinMFBO)
