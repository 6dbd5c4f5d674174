"""The peer-library adapters (BoTorch, scikit-optimize, bayesian-optimization, Optuna GP) and benchmarks/peers.py."""

from __future__ import annotations

import json
import sys

import gymnasium as gym
import numpy as np
import pytest

import agents
import gbo_envs  # noqa: F401
from tests.support import benchmark_module

#: (registry name, keywords) of every peer row; each starts from BO's initial design with n_initial
PEERS = [("botorch", {}), ("botorch", {"acquisition": "logei"}), ("skopt", {}), ("bayes-opt", {}),
         ("optuna-gp", {"n_initial": 1})]

#: import name of the library behind each adapter
LIBRARIES = {"botorch": "botorch", "skopt": "skopt", "bayes-opt": "bayes_opt"}


def _make(name: str, **kwargs):
    try:
        return agents.make(name, **kwargs)
    except ImportError as exc:
        pytest.skip(f"{name}: optional dependency missing ({exc})")


@pytest.mark.filterwarnings("ignore")
@pytest.mark.parametrize(("name", "kwargs"), PEERS)
def test_each_peer_runs_three_experiments_inside_the_feasible_set(name, kwargs):
    env = gym.make("gbo_envs/DCMotor-v0")
    frame = _make(name, **kwargs).run(env, budget=3, seed=0).to_pandas()
    gains = frame[["Kp", "Ki"]].to_numpy()
    assert gains.shape == (3, 2) and np.all(np.isfinite(frame["cost"]))
    assert np.all(gains >= env.unwrapped.action_space.low) and np.all(gains <= env.unwrapped.action_space.high)
    assert len({tuple(g) for g in gains}) == 3  # the library proposed after the one design point


@pytest.mark.filterwarnings("ignore")
@pytest.mark.parametrize(("name", "kwargs"), PEERS)
def test_first_asks_are_bos_latin_hypercube_design_for_the_same_seed(name, kwargs):
    space = agents.GainSpace.from_env(gym.make("gbo_envs/DCMotor-v0"))
    tuners = [agents.make("bo", n_initial=3), _make(name, **{**kwargs, "n_initial": 3})]
    asked = []
    for tuner in tuners:
        tuner.setup(space, seed=7)
        gains = []
        for cost in (3.0, 2.0, 1.0):
            gains.append(tuner.ask())
            tuner.tell(gains[-1], cost)
        asked.append(np.array(gains))
    np.testing.assert_array_equal(asked[1], asked[0])
    assert len({tuple(g) for g in asked[0]}) == 3


@pytest.mark.parametrize("name", sorted(LIBRARIES))
def test_missing_library_raises_an_import_error_naming_the_extra(name, monkeypatch):
    monkeypatch.setitem(sys.modules, LIBRARIES[name], None)  # `import botorch` now raises ImportError
    with pytest.raises(ImportError, match=r'pip install "gbo-envs\[peers\]"'):
        agents.make(name)


def test_bad_botorch_options_raise_value_errors_naming_the_parameter():
    pytest.importorskip("botorch")
    with pytest.raises(ValueError, match=r"acquisition: must be one of \('qlognei', 'logei'\)"):
        agents.make("botorch", acquisition="ei")
    with pytest.raises(ValueError, match=r"n_initial: must be an int in \[1, inf\)"):
        agents.make("skopt", n_initial=0)


def _peers_module(monkeypatch, tmp_path):
    return benchmark_module(monkeypatch, "peers", RESULTS=tmp_path, RUNS=tmp_path / "peers_runs.jsonl",
                            ABLATION_RUNS=tmp_path / "guided_bo_ablation_runs.jsonl")


def test_peers_summary_of_a_fake_runs_file(monkeypatch, tmp_path, capsys):
    bench = _peers_module(monkeypatch, tmp_path)
    # bo reaches 1.05 at experiments 2 and 4; skopt at 3 and never (a miss, counted as budget + 1 = 5)
    curves = {("bo", 0): [1.2, 1.04, 1.0, 1.0], ("bo", 1): [1.5, 1.2, 1.08, 1.01],
              ("skopt", 0): [1.2, 1.2, 1.03, 1.0], ("skopt", 1): [1.5, 1.3, 1.2, 1.1],
              ("skopt", 2): [1.0, 1.0, 1.0, 1.0]}  # seed 2 has no bo run: left out
    runs = [{"env": "DCMotor-v0", "row": row, "seed": seed, "ratios": ratios, "seconds": 2.0 * (row == "bo") + 1.0}
            for (row, seed), ratios in curves.items()]
    bench.RUNS.write_text("".join(json.dumps(run) + "\n" for run in runs))
    monkeypatch.setattr(sys, "argv", ["peers.py", "--summary"])
    bench.main()
    table = bench.summarise(runs).set_index(["ratio", "row"])
    assert table.loc[(1.05, "bo"), ["seeds", "mean", "misses", "seconds"]].tolist() == [2, 3.0, 0, 3.0]
    assert table.loc[(1.05, "skopt"), ["mean", "misses", "vs_bo"]].tolist() == [4.0, 1, 4.0 / 3.0]
    assert table.loc[(1.1, "skopt"), "mean"] == 3.5  # reaches 1.1 at experiments 3 and 4
    # Student-t 95 % interval of (2, 4): 3 +- t(0.975, 1) * sqrt(2) / sqrt(2)
    assert table.loc[(1.05, "bo"), "ci_high"] == pytest.approx(3.0 + 12.7062047, rel=1e-6)
    markdown = (tmp_path / "peers.md").read_text()
    assert "### DCMotor-v0, ratio 1.05 (2 seeds)" in markdown
    assert "| skopt | 4.0 [-8.7, 16.7] (1) | 1.33 | 2 | 1.0 |" in markdown
    csv = (tmp_path / "peers.csv").read_text().splitlines()
    assert csv[0] == "env,ratio,row,seeds,mean,ci_low,ci_high,misses,vs_bo,seconds" and len(csv) == 5
    assert "| bo | 3.0 [-9.7, 15.7] (0) | 1.00 | 2 | 3.0 |" in capsys.readouterr().out


def test_peers_summary_takes_guided_bo_from_the_ablation_log_on_the_seeds_it_shares_with_bo(monkeypatch, tmp_path):
    bench = _peers_module(monkeypatch, tmp_path)
    bo = {0: [1.2, 1.04, 1.0, 1.0], 1: [1.5, 1.2, 1.08, 1.01], 2: [1.0, 1.0, 1.0, 1.0]}
    runs = [{"env": "DCMotor-v0", "row": "bo", "seed": seed, "ratios": ratios, "seconds": 1.0}
            for seed, ratios in bo.items()]
    runs.append({"env": "DCMotor-v0", "row": "guided-bo", "seed": 1, "ratios": [1.04] * 4, "seconds": 1.0})
    ablation = [{"plant": plant, "variant": variant, "seed": seed, "ratios": [1.2, 1.0, 1.0, 1.0], "seconds": 9.0}
                for plant, variant, seed in [("DCMotor-v0", "guided-bo", 0), ("DCMotor-v0", "guided-bo", 1),
                                             ("DCMotor-v0", "bo", 3), ("DC+backlash", "guided-bo", 0),
                                             ("DCMotor-v0", "bo, envelope settling", 2)]]
    bench.ABLATION_RUNS.write_text("".join(json.dumps(run) + "\n" for run in ablation))
    pulled = bench.ablation_runs(runs)
    # only the guided-bo and envelope-BO runs of a peers env at a seed this study lacks
    assert [(r["env"], r["row"], r["seed"]) for r in pulled] == [("DCMotor-v0", "guided-bo", 0),
                                                                  ("DCMotor-v0", "bo-envelope", 2)]
    table = bench.summarise(runs + pulled).set_index(["ratio", "row"])
    assert table.loc[(1.05, "bo"), ["seeds", "mean"]].tolist() == [3, 7.0 / 3.0]  # on all its seeds
    # guided-bo on seeds 0 (ablation: 1.05 at experiment 2) and 1 (this study: at 1), against bo on 0 and 1 (2, 4)
    assert table.loc[(1.05, "guided-bo"), ["seeds", "mean", "vs_bo"]].tolist() == [2, 1.5, 0.5]


def test_peers_does_not_rerun_the_seeds_the_ablation_log_has(monkeypatch, tmp_path):
    bench = _peers_module(monkeypatch, tmp_path)
    ablation = [{"plant": "DCMotor-v0", "variant": variant, "seed": 0, "ratios": [1.0], "seconds": 1.0}
                for variant in ("guided-bo", "bo, envelope settling")]
    bench.ABLATION_RUNS.write_text("".join(json.dumps(run) + "\n" for run in ablation))
    asked = []
    monkeypatch.setattr(bench, "append_runs", lambda path, run, todo, workers: asked.extend(todo) or [])
    monkeypatch.setattr(sys, "argv", ["peers.py", "--envs", "DCMotor-v0", "--rows", "bo", "bo-envelope", "guided-bo",
                                      "--seeds", "2"])
    bench.main()
    assert sorted((row, seed) for _, row, seed, _ in asked) == [("bo", 0), ("bo", 1), ("bo-envelope", 1),
                                                                 ("guided-bo", 1)]


def test_peers_skips_a_row_whose_library_is_missing(monkeypatch, tmp_path, capsys):
    bench = _peers_module(monkeypatch, tmp_path)
    monkeypatch.setitem(sys.modules, "skopt", None)
    assert not bench.available("skopt")
    assert 'note: skipping skopt: scikit-optimize is not installed; install the peer libraries with pip install ' \
           '"gbo-envs[peers]"' in capsys.readouterr().out
