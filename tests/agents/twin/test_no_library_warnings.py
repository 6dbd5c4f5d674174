"""The twin's fits say nothing through library warnings (issue 39): what they meet is understood and handled.

Guided BO diagnoses its twin on effect plants; scipy's ``BadCoefficients`` of a zero-gain model and
``RuntimeWarning: invalid value encountered in scalar subtract`` of Brent's method fed ``inf`` reached
the user's terminal.
"""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest

import agents
import agents.twin.candidates as candidates
import gbo_envs  # noqa: F401  (registers the envs)
from agents.twin.fits import fit_model
from agents.twin.guesses import effect_starts
from agents.twin.linear_fit import PROFILE_EFFECTS
from agents.twin.model import ModelSpec
from agents.twin.records import Batch
from gbo_envs.physics import ContinuousPlant

#: The README's effect plant: a 150-unit drive limit and Coulomb friction of 20.
EFFECTS = {"saturation": {"limit": 150.0}, "coulomb_friction": {"torque": 20.0}}


def _saturated_record():
    """One experiment whose command stays above the drive limit throughout (174 -> 226 against 150): no input
    variation reaches the plant, and the linear model of it has zero gain."""
    env = gym.make("gbo_envs/DCMotor-v0", effects=EFFECTS)
    env.reset(seed=0)
    info = env.step(np.array([0.74059207, 1.19644192]))[4]
    assert info["u"].min() > 150.0
    return info["experiment"]


def test_a_zero_gain_model_is_realised_without_a_warning():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        a, b, c = ContinuousPlant((1e-18,), (1.0, 0.3, 0.28)).state_space()
    assert a.shape == (2, 2) and np.allclose(c, 0.0, atol=1e-15)


def test_the_effect_profiles_of_a_saturated_record_emit_no_warning():
    data = Batch.from_records([_saturated_record()], n_samples=100)
    base = fit_model(data, spec=ModelSpec(n_poles=2))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for name in PROFILE_EFFECTS:
            candidates.candidate_problems(data, base, name)


def test_brent_gets_no_inf_from_a_profile_that_fails_on_part_of_its_interval(monkeypatch):
    """Effect values the profile cannot fit (``inf``) are handed to the bounded Brent search as finite values worse
    than every fitted one; two of them made its parabolic step ``inf - inf`` ("invalid value in scalar subtract")."""
    records = [gym.make("gbo_envs/DCMotor-v0", effects={"saturation": {"limit": 138.0}}).unwrapped
               .step(np.array(gains))[4]["experiment"] for gains in ([0.9, 1.5], [0.4, 1.9])]
    data = Batch.from_records(records, n_samples=100)
    base = fit_model(data, spec=ModelSpec(n_poles=2))
    n_starts = len(effect_starts("saturation", data, base)[0])
    real, starts, searched = candidates.profile, [], []

    def failing_below_the_middle(data, spec, theta, **kwargs):
        limit = float(theta[-1])
        if len(starts) < n_starts:  # the starts are profiled first
            starts.append((limit, real(data, spec, theta, **kwargs)[0]))
            return real(data, spec, theta, **kwargs)
        searched.append(limit)
        best = int(np.argmin([rmse for _, rmse in starts]))
        a, b = starts[max(best - 1, 0)][0], starts[min(best + 1, n_starts - 1)][0]
        if limit < 0.5 * (a + b):  # Brent's interval: the limits in its lower half leave no model (as a limit
            return np.inf, theta, np.zeros(data.n_records), np.zeros(data.n_records)  # below the rest input)
        return real(data, spec, theta, **kwargs)

    monkeypatch.setattr(candidates, "profile", failing_below_the_middle)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        problems = candidates.candidate_problems(data, base, "saturation")
    assert len(searched) > 1 and len(problems) == 1  # Brent ran, and a fitted value was kept


def test_the_delay_search_gets_no_inf_either(monkeypatch):
    """The same in SRIVC's delay refinement (``identify_linear``): a delay without a model is a finite value."""
    import agents.twin.identify as identify

    info = gym.make("gbo_envs/DCMotor-v0").unwrapped.step(np.array([0.5, 1.2]))[4]
    grid = np.arange(0.0, 0.0101, 0.002)  # the scan; the refinement then searches (0, 0.004) around 0.002
    real, taus = identify.simulation_error, []

    def failing_below_the_middle(orders, theta, delay, signals, offset=True):
        taus.append(float(delay))
        if len(taus) > grid.size and delay < 0.002:
            return np.inf, np.inf, np.zeros((1, 2))
        return real(orders, theta, delay, signals, offset)

    monkeypatch.setattr(identify, "simulation_error", failing_below_the_middle)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        fit = identify.identify_linear([info], max_delay=0.01, delay_step=0.002)
    assert len(taus) > grid.size + 1 and 0.002 <= fit.delay <= 0.004


@pytest.mark.slow
def test_guided_bo_on_the_readme_effect_plant_emits_no_warning():
    env = gym.make("gbo_envs/DCMotor-v0", effects=EFFECTS)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warnings.filterwarnings("ignore", message=".*Box (action|observation) space.*")  # gymnasium's checker
        agents.make("guided-bo", grid_points=40).run(env, budget=4, seed=0)
