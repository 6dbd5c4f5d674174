"""Multi-fidelity BO against guided BO and the default BO (issue 17).

``agents.make("mf-bo")`` (the twin as the low fidelity of one BoTorch GP) is run on
the plants of ``effect_aware_guided_bo.py`` with the env's episode length as
budget; ``bo`` and ``guided-bo`` are not rerun: their runs on the same seeds are
read from ``benchmarks/results/guided_bo_ablation_runs.jsonl``
(``guided_bo_ablation.py``, same budget, seeds and ground truth). The variant
``mf-bo, noise twin`` replaces the twin's cost by pure noise (log-normal around
the plant's median measured cost, independent of the gains): the fidelity
estimate must drop and the tuner must behave as ``bo``.

Per plant: the mean real experiments until the best evaluated gains reach the
optimality ratio ``J / J*`` 1.05 (and 1.01 on the linear motors), with the 95 %
Student-t interval and the misses (a miss counts as ``budget + 1``), over the seeds
every tuner of the row ran, the ratio to ``bo`` and to ``guided-bo``, and mf-bo's
CPU time (``time.process_time``, one thread) per real experiment, its twin
evaluations per run and its final fidelity ``s_twin``.

Finished runs are appended to ``benchmarks/results/mf_bo_runs.jsonl`` and skipped
when the command is run again (an interrupted study resumes). Writes
``benchmarks/results/mf_bo.md``, with the seed-by-seed difference to ``guided-bo``
(its 95 % interval covering 0: no worse within the interval)::

    nice -n 15 python benchmarks/mf_bo.py --plants DCMotor-v0 --seeds 30 --workers 1
    python benchmarks/mf_bo.py --plants DCMotor-v0 --variants "mf-bo, noise twin" --seeds 10
    python benchmarks/mf_bo.py --summary
    python benchmarks/mf_bo.py --acquisition-timing     # MF-MES against MF-KG, CPU s per optimisation
    python benchmarks/mf_bo.py --run-timing --plants LinearMotor-v0 --seeds 3  # wall s per real experiment
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
from data_efficiency import experiments_to_reach
from effect_aware_guided_bo import PLANTS, interval, optimum, thresholds
from run_log import load_runs, run_missing

RESULTS = Path(__file__).resolve().parent / "results"
RUNS = RESULTS / "mf_bo_runs.jsonl"
#: The bo and guided-bo runs reused (never rerun here).
REFERENCE_RUNS = RESULTS / "guided_bo_ablation_runs.jsonl"
REFERENCES = ("bo", "guided-bo")
VARIANTS = ("mf-bo", "mf-bo, noise twin")


def _noise_twin_tuner():
    """``mf-bo`` whose twin cost is pure noise: log-normal (sigma 1) around the median measured cost."""
    from agents.mf_bo import MultiFidelityBO

    class NoiseTwinMFBO(MultiFidelityBO):
        def _setup(self) -> None:
            super()._setup()
            self._noise = np.random.default_rng(12345 if self.seed is None else self.seed + 12345)

        def _twin_costs(self, twin_env, unit):
            cache = self._twin_cache[1]
            scale = float(np.median(self._plant_y))
            for x in unit:
                cache.setdefault(tuple(x), scale * float(np.exp(self._noise.standard_normal())))
            return np.array([cache[tuple(x)] for x in unit])

    return NoiseTwinMFBO()


def run_one(label: str, variant: str, seed: int, best: float) -> dict:
    """One mf-bo run: its minimum-observed optimality-ratio curve, CPU time and fidelity trace."""
    import agents
    import gbo_envs  # noqa: F401  (registers the envs in a fresh worker)
    from agents.thread_limits import single_thread

    env_id, kwargs = PLANTS[label]
    env = gym.make(env_id, **kwargs)
    tuner = agents.make("mf-bo") if variant == "mf-bo" else _noise_twin_tuner()
    start, cpu = time.perf_counter(), time.process_time()
    with single_thread(user_api=None):
        result = tuner.run(env, budget=env.spec.max_episode_steps, seed=seed, progress=False)
    cpu = time.process_time() - cpu
    info = result.info
    return {"plant": label, "variant": variant, "seed": seed, "ratios": (result.min_true_cost_curve() / best).tolist(),
            "seconds": round(time.perf_counter() - start, 2), "cpu_seconds": round(cpu, 2),
            "cpu_per_experiment": round(cpu / result.n_experiments, 3),
            "twin_evaluations": info["twin_evaluations"],
            "fidelity": [round(step["fidelity"], 3) for step in info["fidelity_trace"]]}


def summarise(runs: list[dict], references: list[dict]) -> str:
    """The Markdown table: per plant, ratio and variant, the seeds every tuner of the row ran."""
    lines = ["| plant | ratio | seeds | mf-bo variant | variant: real experiments | bo | guided-bo | / bo | "
             "/ guided-bo | variant - guided-bo, paired | CPU s / real experiment | twin evaluations / run | "
             "final s_twin |", "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for label in PLANTS:
        reference = {v: {r["seed"]: r for r in references if r["plant"] == label and r["variant"] == v}
                     for v in REFERENCES}
        for variant in VARIANTS:
            mine = {r["seed"]: r for r in runs if r["plant"] == label and r["variant"] == variant}
            seeds = sorted(set(mine) & set(reference["bo"]) & set(reference["guided-bo"]))
            if len(seeds) < 2:
                continue
            for level in thresholds(label):
                cells, means, counts_of = [], [], []
                for runs_of in (mine, reference["bo"], reference["guided-bo"]):
                    counts = np.array([experiments_to_reach(runs_of[s]["ratios"], level) for s in seeds])
                    mean, low, high = interval(counts)
                    misses = int(np.sum(counts > len(runs_of[seeds[0]]["ratios"])))
                    cells.append(f"{mean:.1f} [{low:.1f}, {high:.1f}] ({misses} misses)")
                    means.append(mean)
                    counts_of.append(counts)
                # the seed-by-seed difference: its interval covering 0 is "no worse within the 95 % interval"
                paired = "{:+.1f} [{:+.1f}, {:+.1f}]".format(*interval(counts_of[0] - counts_of[2]))
                cpu = np.mean([mine[s]["cpu_per_experiment"] for s in seeds])
                twin = np.mean([mine[s]["twin_evaluations"] for s in seeds])
                fidelity = np.mean([mine[s]["fidelity"][-1] for s in seeds])
                lines.append(f"| {label} | {level} | {len(seeds)} | {variant} | {' | '.join(cells)} | "
                             f"{means[0] / means[1]:.2f} | {means[0] / means[2]:.2f} | {paired} | {cpu:.2f} | "
                             f"{twin:.1f} | {fidelity:.2f} |")
    return "\n".join(lines)


def acquisition_timing(repeats: int = 3) -> str:
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
    return "\n".join(f"{name}: {np.mean(v):.2f} CPU s per optimisation (mean of {repeats}, min {np.min(v):.2f})"
                     for name, v in seconds.items())


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
        env_id, kwargs = PLANTS[label]
        for seed in range(seeds):
            env = gym.make(env_id, **kwargs)
            start, cpu = time.perf_counter(), time.process_time()
            result = agents.make("mf-bo").run(env, budget=env.spec.max_episode_steps, seed=seed, progress=False)
            wall, cpu = time.perf_counter() - start, time.process_time() - cpu
            out.append({"plant": label, "seed": seed, "real_experiments": result.n_experiments,
                        "wall_s_per_experiment": round(wall / result.n_experiments, 3),
                        "cpu_s_per_experiment": round(cpu / result.n_experiments, 3)})
            print(out[-1], flush=True)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--plants", nargs="+", default=["DCMotor-v0"], choices=list(PLANTS))
    parser.add_argument("--variants", nargs="+", default=["mf-bo"], choices=list(VARIANTS))
    parser.add_argument("--seeds", type=int, default=30, help="seeds 0..N-1 (default 30)")
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--summary", action="store_true", help="only write the table of the runs so far")
    parser.add_argument("--acquisition-timing", action="store_true",
                        help="only time one optimisation of MF-MES and of MF-KG")
    parser.add_argument("--run-timing", action="store_true",
                        help="only time whole mf-bo runs of --plants, --seeds each, with all cores")
    args = parser.parse_args()
    if args.run_timing:
        runs = run_timing(args.plants, args.seeds)
        for label in args.plants:
            wall = [r["wall_s_per_experiment"] for r in runs if r["plant"] == label]
            print(f"{label}: {np.mean(wall):.2f} wall s per real experiment (mean of {len(wall)} runs, "
                  f"max {np.max(wall):.2f})")
        return
    if args.acquisition_timing:
        print(acquisition_timing())
        return
    if args.summary:
        runs = load_runs(RUNS)
    else:
        optima = {label: optimum(label)["cost"] for label in args.plants}
        runs = run_missing(RUNS, run_one, args.plants, args.variants, args.seeds, optima, args.workers)
    table = summarise(runs, load_runs(REFERENCE_RUNS))
    (RESULTS / "mf_bo.md").write_text(
        "Real experiments to each optimality ratio, mean [95 % CI] (misses; a miss counts as budget + 1), mf-bo "
        "against bo and guided-bo on the seeds all three ran (bo and guided-bo from guided_bo_ablation_runs.jsonl); "
        "CPU time per real experiment of mf-bo (one thread) (benchmarks/mf_bo.py).\n\n" + table + "\n")
    print(table)


if __name__ == "__main__":
    main()
