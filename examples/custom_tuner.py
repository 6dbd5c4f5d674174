"""A third-party tuner in under 30 lines: random steps around the best gains measured so far.

Run it: ``python examples/custom_tuner.py``. Rank it on the benchmark suite against the shipped
references (docs/benchmark.md, "Benchmark your tuner")::

    gbo bench suite --import examples.custom_tuner --tuner local-random --suite quick
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np

import agents
import gbo_envs  # noqa: F401  (registers the envs)


class LocalRandomSearch(agents.Tuner):
    """Gaussian steps of ``step`` times each gain's range around the best gains so far."""

    name = "local-random"

    def __init__(self, *, step: float = 0.1) -> None:
        self.step = step
        self._params = {"step": step}  # shown by get_params() and stored in results

    def _setup(self) -> None:  # called by run(): self.space and self.rng are ready
        self.best_gains, self.best_cost = None, np.inf

    def _ask(self) -> np.ndarray:
        if self.best_gains is None:
            return self.rng.uniform(self.space.low, self.space.high)
        step = self.step * (self.space.high - self.space.low) * self.rng.standard_normal(self.space.dim)
        return np.clip(self.best_gains + step, self.space.low, self.space.high)

    def _tell(self, gains: np.ndarray, cost: float, record: dict | None) -> None:
        if cost < self.best_cost:
            self.best_gains, self.best_cost = gains, cost


agents.register("local-random", LocalRandomSearch)

if __name__ == "__main__":
    result = agents.make("local-random", step=0.05).run(gym.make("gbo_envs/DCMotor-v0"), budget=20, seed=0)
    print(result.to_pandas()[["experiment", "Kp", "Ki", "cost", "best_cost"]].tail())
