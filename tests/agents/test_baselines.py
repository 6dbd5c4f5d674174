"""Grid, random, nominal PGM, the Optuna adapter and the noise estimate."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from scipy.stats import kstest

import agents
import gbo_envs  # noqa: F401
from agents.nominal import PAPER_NOMINAL_GAINS, PAPER_TABLE_FOPDT, fopdt_from_second_order, pgm_pi_gains
from tests.support import DC_MOTOR_SPACE as SPACE


def _asks(tuner, n):
    out = []
    for _ in range(n):
        gains = tuner.ask()
        out.append(gains)
        tuner.tell(gains, 1.0)
    return np.asarray(out)


def test_grid_is_sized_to_the_budget_and_visits_distinct_cell_centres():
    result = agents.GridSearch().run(gym.make("gbo_envs/DCMotor-v0"), budget=35, seed=0)
    gains = result.to_pandas()[["Kp", "Ki"]].to_numpy()
    assert len(np.unique(gains, axis=0)) == 35  # 6 x 6 grid, 35 of its 36 points
    unit = SPACE.to_unit(gains) * 6 - 0.5
    np.testing.assert_allclose(unit, np.round(unit), atol=1e-9)
    assert result.info["params"] == {"budget": 35}


def test_grid_order_is_a_seeded_permutation_that_starts_over():
    shuffled = [agents.GridSearch(budget=16), agents.GridSearch(budget=16)]
    for tuner, seed in zip(shuffled, (1, 2)):
        tuner.setup(SPACE, seed=seed)
    assert not np.array_equal(shuffled[0].points, shuffled[1].points)
    assert np.array_equal(np.sort(shuffled[0].points, axis=0), np.sort(shuffled[1].points, axis=0))
    assert len(shuffled[0].points) == 16  # 4 x 4
    # after the whole grid the sequence starts over
    np.testing.assert_array_equal(_asks(shuffled[0], 17)[16], shuffled[0].points[0])
    with pytest.raises(ValueError, match=r"budget: must be an int in \[1, inf\)"):
        agents.GridSearch(budget=0)


def test_random_search_is_uniform_over_the_set():
    tuner = agents.RandomSearch()
    tuner.setup(SPACE, seed=0)
    unit = SPACE.to_unit(_asks(tuner, 400))
    for column in unit.T:  # Kolmogorov-Smirnov against U(0, 1)
        assert kstest(column, "uniform").pvalue > 1e-3
    np.testing.assert_allclose(unit.mean(axis=0), [0.5, 0.5], atol=0.05)


def test_pgm_formulas_by_hand():
    kp, ki, omega = pgm_pi_gains(60.0, 20.0, gain=2.0, tau=1.5, delay=0.1)
    a, phi = 10.0, np.pi / 3
    omega_hand = (a * phi + 0.5 * np.pi * a * (a - 1)) / ((a**2 - 1) * 0.1)
    assert omega == pytest.approx(omega_hand)
    assert kp == pytest.approx(omega_hand * 1.5 / (a * 2.0))
    assert ki == pytest.approx(2 * omega_hand - 4 * omega_hand**2 * 0.1 / np.pi + 1 / 1.5)
    with pytest.raises(ValueError, match="phase_margin"):
        pgm_pi_gains(95.0, 46.0, 1.0, 1.0, 1.0)


def test_paper_table_fopdt_reproduces_the_nominal_table():
    for phase, (kp_paper, ki_paper) in PAPER_NOMINAL_GAINS.items():
        kp, ki, _ = pgm_pi_gains(phase, 46.0, **PAPER_TABLE_FOPDT)
        assert kp == pytest.approx(kp_paper, abs=0.006)
        assert ki == pytest.approx(ki_paper, abs=0.006)


@pytest.mark.parametrize("env_id", ["gbo_envs/DCMotor-v0", "gbo_envs/DCMotorRig-v0"])
@pytest.mark.parametrize("phase", [60.0, 75.0])
def test_nominal_by_default_is_the_papers_table(env_id, phase):
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no clipping warning
        result = agents.make("nominal", phase_margin_deg=phase).run(gym.make(env_id), budget=2, seed=0)
    np.testing.assert_allclose(result.to_pandas()[["Kp", "Ki"]].to_numpy(), [PAPER_NOMINAL_GAINS[phase]] * 2,
                               atol=0.006)
    assert result.info["clipped"] is False and result.info["fopdt"] == PAPER_TABLE_FOPDT


def test_nominal_on_the_identified_model_is_clipped_and_constant():
    fopdt = fopdt_from_second_order(9.544, 4.145, 4.199, 0.002)
    assert fopdt["gain"] == pytest.approx(2.2729, abs=1e-4) and fopdt["tau"] == pytest.approx(0.98714, abs=1e-5)
    with pytest.warns(UserWarning, match="clipped"):
        result = agents.NominalPGM(fopdt="identified").run(gym.make("gbo_envs/DCMotor-v0"), budget=3, seed=0)
    frame = result.to_pandas()
    np.testing.assert_allclose(frame[["Kp", "Ki"]].to_numpy(), [[1.10, 2.08]] * 3)
    assert result.info["clipped"] is True
    np.testing.assert_allclose(result.info["unclipped_gains"], [1.7067, 3.5936], atol=1e-3)
    nominal = agents.NominalPGM()
    with pytest.raises(ValueError, match="nominal_fopdt"):
        nominal.setup(SPACE, seed=0)
    with pytest.raises(ValueError, match=r"phase_margin_deg: .*\(0(\.0)?, 90(\.0)?\)"):
        agents.NominalPGM(phase_margin_deg=95.0)
    with pytest.raises(ValueError, match="fopdt"):
        agents.NominalPGM(fopdt="paper")


def test_optuna_adapter_uses_ask_and_tell():
    tuner = agents.OptunaTuner(sampler="random")
    tuner.setup(SPACE, seed=0)
    first = tuner.ask()
    assert tuner.ask() == first  # asking again without tell repeats the pending trial
    tuner.tell(first, 0.7)
    tuner.tell((0.5, 1.5), 0.4)  # gains that were never asked become a finished trial
    trials = tuner.study.get_trials(deepcopy=False)
    assert [t.value for t in trials] == [0.7, 0.4]
    assert trials[1].params == {"Kp": 0.5, "Ki": 1.5}
    assert tuner.study.best_value == 0.4
    with pytest.raises(ValueError, match="sampler"):
        agents.OptunaTuner(sampler="nope")


def test_estimate_noise_uses_repeated_measured_costs():
    env = gym.make("gbo_envs/DCMotor-v0")
    env.reset(seed=0)
    sigma, costs = agents.estimate_noise(env, gains=(0.5, 1.2), repeats=5)
    assert costs.shape == (5,) and sigma == pytest.approx(np.std(costs, ddof=1))
    assert env.unwrapped.experiment_index == 5  # they are real experiments
    env.reset(seed=1)
    sigma_many, _ = agents.estimate_noise(env, repeats=200, seed=3)
    assert sigma_many == pytest.approx(0.009, rel=0.15)  # the env's default cost noise
    with pytest.raises(ValueError, match="repeats"):
        agents.estimate_noise(env, repeats=1)


@pytest.mark.slow
def test_nominal_example_prints_the_papers_designs_and_a_clipped_one(capsys):
    import runpy

    from tests.support import REPO_ROOT

    rows = runpy.run_path(str(REPO_ROOT / "examples" / "nominal_pgm.py"))["main"]()
    assert [row["clipped"] for row in rows] == [False, False, True, False]
    np.testing.assert_allclose([rows[0]["Kp"], rows[0]["Ki"]], PAPER_NOMINAL_GAINS[60.0], atol=0.006)
    assert 1.0 < rows[1]["ratio"] < rows[0]["ratio"] < rows[2]["ratio"]  # 75 deg is the better nominal
    assert "J / J*" in capsys.readouterr().out
