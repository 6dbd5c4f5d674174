"""Oracle split of guided BO on an effect plant: is the loss in identifying the twin, or in using it? (issue 15)

Per plant, the default ``agents.make("guided-bo")`` runs with three twins over the
same seeds:

* ``auto``: the default, the twin diagnosed from the records (``twin="auto"``);
* ``oracle``: :class:`OracleTwin`, the plant's own linear part and effects with its
  true parameters, fitted from nothing (the records are ignored);
* ``linear``: the paper's linear SRIVC twin (``twin="linear"``).

If the oracle reaches the optimality ratio in a few experiments where ``auto``
does not, the loss is in identification; if the oracle fails too, it is in how
the twin prior is used, or in the plant's surface itself. Each run logs its
minimum-observed optimality-ratio curve, its twin activations and repeats, and
every twin change (the experiment after which it was fitted, its effects and
RMSE). Runs are appended to ``benchmarks/results/guided_bo_oracle_runs.jsonl``
and skipped when the command is run again; the table goes to
``benchmarks/results/guided_bo_oracle.md``::

    python benchmarks/guided_bo_oracle.py --plants DC+saturation --seeds 5
    python benchmarks/guided_bo_oracle.py --summary
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
from effect_aware_guided_bo import PLANTS, count_cell, effects_column, study_arguments, study_runs, thresholds
from sklearn.base import BaseEstimator

RESULTS = Path(__file__).resolve().parent / "results"
RUNS = RESULTS / "guided_bo_oracle_runs.jsonl"
TWINS = ("auto", "oracle", "linear")


class OracleTwin(BaseEstimator):
    """The plant's own model as a fitted twin: its linear part and effect blocks, true parameters.

    Parameters
    ----------
    plant : str
        A label of :data:`effect_aware_guided_bo.PLANTS`; ``fit`` copies that env's loop
        plant and effects (the records are ignored).

    Attributes
    ----------
    plant_ : gbo_envs.ContinuousPlant
        The plant env's linear plant.
    effects_ : tuple of EffectBlock
        The plant env's effect blocks.
    effect_params_ : dict
        ``{effect: {}}`` (names only, for the run's records).
    params_ : ndarray
        Numerator and denominator coefficients of ``plant_``.
    rmse_ : float
        0: the model is exact (the DC and linear motor records carry no output noise).
    """

    def __init__(self, *, plant: str = "DCMotor-v0") -> None:
        self.plant = plant

    def fit(self, records=None, y=None) -> OracleTwin:
        """Copy the plant env's model; ``records`` are ignored."""
        env_id, kwargs = PLANTS[self.plant]
        loop = gym.make(env_id, **kwargs).unwrapped.loop
        self.plant_ = loop.plant
        self.effects_ = tuple(loop.effects)
        self.effect_params_ = {block.name: {} for block in self.effects_}
        self.params_ = np.concatenate([np.ravel(loop.plant.num), np.ravel(loop.plant.den)]).astype(float)
        self.rmse_ = 0.0
        return self

    def score(self, records, y=None) -> float:
        """0: the exact model never mispredicts (negative normalised RMSE, scikit-learn's sign)."""
        return 0.0


def run_one(label: str, twin: str, seed: int, best: float) -> dict:
    """One default guided-BO run with the given twin: ratio curve, activations and twin changes."""
    import agents
    import gbo_envs  # noqa: F401  (registers the envs in a fresh worker)
    from agents.thread_limits import single_thread

    env_id, kwargs = PLANTS[label]
    env = gym.make(env_id, **kwargs)
    chosen = OracleTwin(plant=label).fit() if twin == "oracle" else twin
    start = time.process_time()
    with single_thread(user_api=None):
        result = agents.make("guided-bo", twin=chosen).run(env, budget=env.spec.max_episode_steps, seed=seed,
                                                            progress=False)
    info = result.info
    rows = result.plant_rows
    return {"plant": label, "variant": twin, "seed": seed,
            "ratios": (result.min_true_cost_curve() / best).tolist(),
            "true_ratios": [row.get("true_cost", np.nan) / best for row in rows],
            "gains": [[row[name] for name in result.gain_names] for row in rows],
            "cpu_seconds": round(time.process_time() - start, 2), "activations": info.get("activations"),
            "repeats": info.get("repeats"), "distrusts": info.get("distrusts"),
            "twin_changes": [{"experiment": c["experiment"], "effects": c["effects"], "rmse": c["rmse"]}
                             for c in info.get("twin_changes") or []]}


def summarise(runs: list[dict]) -> str:
    """Per plant, ratio and twin: mean real experiments [95 % CI] (misses), activations, repeats."""
    lines = ["| plant | ratio | twin | seeds | real experiments | activations | repeats | effects of the last twin "
             "(runs) | CPU s/run |", "|---|---|---|---|---|---|---|---|---|"]
    for label in PLANTS:
        for threshold in thresholds(label):
            for twin in dict.fromkeys(r["variant"] for r in runs):  # every twin logged, in order of appearance
                mine = sorted((r for r in runs if r["plant"] == label and r["variant"] == twin),
                              key=lambda r: r["seed"])
                if not mine:
                    continue
                _, cell = count_cell(mine, threshold)
                found = effects_column("+".join(sorted(r["twin_changes"][-1]["effects"] if r["twin_changes"] else {}))
                                       or "linear" for r in mine)
                lines.append(f"| {label} | {threshold} | {twin} | {len(mine)} | {cell} | "
                             f"{np.mean([r['activations'] for r in mine]):.1f} | "
                             f"{np.mean([r['repeats'] for r in mine]):.1f} | "
                             f"{found} | "
                             f"{np.mean([r['cpu_seconds'] for r in mine]):.1f} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    study_arguments(parser, TWINS, ["DC+saturation"], seeds=5, workers=1)
    runs = study_runs(RUNS, run_one, parser.parse_args())
    table = summarise(runs)
    (RESULTS / "guided_bo_oracle.md").write_text(
        "Default guided BO with the diagnosed (auto), the true (oracle) and the linear twin: real experiments to "
        "each optimality ratio, mean [95 % CI] (misses; a miss counts as budget + 1) "
        "(benchmarks/guided_bo_oracle.py).\n\n" + table + "\n")
    print(table)


if __name__ == "__main__":
    main()
