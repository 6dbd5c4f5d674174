"""Speed of multi-fidelity BO (``agents.make("mf-bo")``): its acquisition, and whole runs per real experiment.

Its data efficiency against guided BO and BO is the study ``mf_bo`` (``gbo bench mf_bo``,
``docs/reports/mf_bo/``). This script times what the study does not:

* by default, one optimisation of the cost-weighted multi-fidelity max-value entropy search
  (MF-MES, what mf-bo uses) against the multi-fidelity knowledge gradient (MF-KG), on the same
  MF GP, in CPU seconds; prints one JSON object;
* ``--run-timing``: wall and CPU seconds per real experiment of whole mf-bo runs in this process
  with all cores (the studies pin each run to one thread)::

    python benchmarks/bench_mf_bo.py
    python benchmarks/bench_mf_bo.py --run-timing --envs LinearMotor-v0 --seeds 3
"""

from __future__ import annotations

import argparse
import json
import time

import gymnasium as gym
import numpy as np


def acquisition_timing(repeats: int = 3) -> dict:
    """CPU s of one ``optimize_acqf_mixed`` of cost-weighted MF-MES and MF-KG, on the same MF GP.

    The GP: 30 plant and 60 twin points (``s = 0.8``) of a smooth two-gain function,
    outcomes standardised; both with mf-bo's optimiser settings (2 restarts, 32 raw
    samples) and 8 fantasies.
    """
    import torch
    from botorch.acquisition import FixedFeatureAcquisitionFunction, PosteriorMean, qMultiFidelityKnowledgeGradient
    from botorch.acquisition.cost_aware import InverseCostWeightedUtility
    from botorch.acquisition.max_value_entropy_search import qMultiFidelityMaxValueEntropy
    from botorch.acquisition.utils import project_to_target_fidelity
    from botorch.fit import fit_gpytorch_mll
    from botorch.models import SingleTaskMultiFidelityGP
    from botorch.models.cost import AffineFidelityCostModel
    from botorch.models.transforms.outcome import Standardize
    from botorch.optim import optimize_acqf, optimize_acqf_mixed
    from gpytorch.mlls import ExactMarginalLogLikelihood

    from agents.mf_bo import CANDIDATES, NUM_FANTASIES, NUM_MV_SAMPLES, NUM_RESTARTS, RAW_SAMPLES

    torch.set_num_threads(1)
    torch.manual_seed(0)
    rng = np.random.default_rng(0)
    s = 0.8
    unit = rng.random((90, 2))
    fidelity = np.r_[np.ones(30), np.full(60, s)]
    y = np.sin(6 * unit[:, 0]) + (unit[:, 1] - 0.3) ** 2 + (1 - fidelity) * 0.3 * np.cos(5 * unit[:, 1])
    train_x = torch.as_tensor(np.column_stack([unit, fidelity]))
    model = SingleTaskMultiFidelityGP(train_x, -torch.as_tensor(y).unsqueeze(-1), data_fidelities=[2],
                                      outcome_transform=Standardize(m=1))
    fit_gpytorch_mll(ExactMarginalLogLikelihood(model.likelihood, model))
    weight = 0.9 / (1.0 - s)
    utility = InverseCostWeightedUtility(cost_model=AffineFidelityCostModel(fidelity_weights={2: weight},
                                                                            fixed_cost=1.0 - weight))

    def project(X):
        return project_to_target_fidelity(X, target_fidelities={2: 1.0}, d=3)

    bounds = torch.tensor([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]], dtype=torch.float64)
    fixed = [{2: s}, {2: 1.0}]
    seconds = {"MF-MES": [], "MF-KG": []}
    for _ in range(repeats):
        start = time.process_time()
        mes = qMultiFidelityMaxValueEntropy(model, candidate_set=torch.rand(CANDIDATES, 2, dtype=torch.float64),
                                            num_fantasies=NUM_FANTASIES, num_mv_samples=NUM_MV_SAMPLES,
                                            cost_aware_utility=utility, project=project)
        optimize_acqf_mixed(mes, bounds=bounds, q=1, num_restarts=NUM_RESTARTS, raw_samples=RAW_SAMPLES,
                            fixed_features_list=fixed)
        seconds["MF-MES"].append(time.process_time() - start)
        start = time.process_time()
        current = FixedFeatureAcquisitionFunction(PosteriorMean(model), d=3, columns=[2], values=[1.0])
        _, value = optimize_acqf(current, bounds=bounds[:, :2], q=1, num_restarts=NUM_RESTARTS,
                                 raw_samples=RAW_SAMPLES)
        kg = qMultiFidelityKnowledgeGradient(model, num_fantasies=NUM_FANTASIES, current_value=value,
                                             cost_aware_utility=utility, project=project)
        optimize_acqf_mixed(kg, bounds=bounds, q=1, num_restarts=NUM_RESTARTS, raw_samples=RAW_SAMPLES,
                            fixed_features_list=fixed)
        seconds["MF-KG"].append(time.process_time() - start)
    return {name: {"mean_cpu_s": round(float(np.mean(v)), 3), "min_cpu_s": round(float(np.min(v)), 3),
                   "repeats": repeats} for name, v in seconds.items()}


def run_timing(labels: list[str], seeds: int) -> list[dict]:
    """Wall and CPU seconds per real experiment of whole mf-bo runs in this process, all cores.

    The studies pin each run to one thread; this is the figure on the machine as a
    user runs one tuning (torch and BLAS with their default threads). The plant's
    ``step`` is included (on hardware it is the experiment itself).
    """
    import agents
    import gbo_envs  # noqa: F401  (registers the envs)

    out = []
    for label in labels:
        for seed in range(seeds):
            env = gym.make(f"gbo_envs/{label}")
            start, cpu = time.perf_counter(), time.process_time()
            result = agents.make("mf-bo").run(env, budget=env.spec.max_episode_steps, seed=seed, progress=False)
            wall, cpu = time.perf_counter() - start, time.process_time() - cpu
            out.append({"plant": label, "seed": seed, "real_experiments": result.n_experiments,
                        "wall_s_per_experiment": round(wall / result.n_experiments, 3),
                        "cpu_s_per_experiment": round(cpu / result.n_experiments, 3)})
            print(out[-1], flush=True)
    return out


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run-timing", action="store_true", help="time whole mf-bo runs instead")
    parser.add_argument("--envs", nargs="+", default=["DCMotor-v0"], help="registered env names (--run-timing)")
    parser.add_argument("--seeds", type=int, default=3, help="runs per env (--run-timing)")
    args = parser.parse_args(argv)
    if not args.run_timing:
        result = acquisition_timing()
        print(json.dumps(result))
        return result
    runs = run_timing(args.envs, args.seeds)
    result = {label: {"wall_s_per_experiment": float(np.mean([r["wall_s_per_experiment"] for r in runs
                                                              if r["plant"] == label])),
                      "max": float(np.max([r["wall_s_per_experiment"] for r in runs if r["plant"] == label]))}
              for label in args.envs}
    print(json.dumps(result))
    return result


if __name__ == "__main__":
    main()
