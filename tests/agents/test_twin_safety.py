"""Safe tuning's run-wide risk and guided BO's twin safety filter (issue 55, points 3 and 4)."""

from __future__ import annotations

import collections
import math

import gymnasium as gym
import numpy as np
import pytest
from scipy import stats

import agents
import gbo_envs
from agents.feasibility import ConstraintModel, run_risk
from agents.twin.env import TwinEnv
from agents.twin.prior import TwinSimulation
from agents.twin_keeper import TwinKeeper
from agents.twin_safety import TwinSafeAcquisition, TwinSafetyFilter

ENV = "gbo_envs/DCMotor-v0"
LIMITS = {"overshoot_pct": 2.0, "peak_u": 140.0}
SAFE_START = [[0.3, 1.0]]
#: J*_c of DCMotor-v0 with LIMITS on the 100 x 100 grid (docs/constraints.md)
OPTIMUM = 0.2794


def _env():
    return gym.make(ENV, constraints=LIMITS)


def _twin():
    """The simulations of the linear twin of DCMotor-v0 fitted on one record at the safe start, and the plant env."""
    env = _env()
    keeper = TwinKeeper(twin="linear")
    keeper.setup(agents.GainSpace.from_env(env), env.unwrapped, constraints=env.unwrapped.constraints)
    env.reset(seed=0)
    info = env.step(np.array(SAFE_START[0]))[4]
    keeper.tell(info["gains"], info["cost"], info)
    return keeper.twin_simulation(), env


def _biased(bias: float) -> TwinSimulation:
    return TwinSimulation(_BiasedTwin(bias), gbo_envs.constraints.Constraints(LIMITS))


# -- the run's risk -----------------------------------------------------------------------------------------
def test_the_run_risk_sums_to_delta_over_the_run_and_is_refused_outside_its_range():
    risks = [run_risk(0.05, t) for t in range(1, 100_000)]
    assert risks[0] == pytest.approx(6 * 0.05 / math.pi**2)
    assert sum(risks) == pytest.approx(0.05, rel=1e-4) and sum(risks) < 0.05
    assert all(a > b for a, b in zip(risks, risks[1:]))
    with pytest.raises(ValueError, match="delta"):
        run_risk(1.0, 1)
    with pytest.raises(ValueError, match="experiment"):
        run_risk(0.05, 0)


def test_bo_safe_breaks_no_limit_on_the_dc_motor():
    # with PF >= 1 - delta at every proposal, experiment 7 ran (0.63, 0.894): peak command 149.3
    tuner = agents.make("bo", safe=True, safe_start=SAFE_START)
    result = tuner.run(_env(), budget=10, seed=0)
    assert result.violations == 0
    assert tuner.safe_level() == pytest.approx(1 - run_risk(0.05, 11))


# -- the filter ---------------------------------------------------------------------------------------------
def test_the_filter_predicts_the_slacks_the_twin_simulates_and_refuses_them_beyond_the_margin():
    twin, env = _twin()
    safety = TwinSafetyFilter(env.unwrapped.constraints, 0.05)
    gains = np.array([[0.3, 1.0], [0.85, 1.07], [0.41, 1.3]])
    predicted = safety.predicted_slacks(twin, gains)
    _, plant, _ = env.unwrapped.evaluate_constraints(gains)
    np.testing.assert_allclose(predicted, plant, atol=0.2)  # the linear twin of the linear plant, from a noisy record
    assert not safety.admits(twin, gains, 3).any()  # no measured error yet: the twin admits nothing
    for g in gains[[0, 2]]:  # two out-of-sample errors of the twin, where the plant keeps the limits
        safety.expect(twin, g)
        env.reset(seed=1)
        safety.observe(g, env.step(g)[4])
    assert len(safety.errors_) == 2 and np.all(np.isfinite(safety.margin(3)))
    admitted = safety.admits(twin, gains, 3)
    assert admitted[0] and not admitted[1]  # (0.85, 1.07) breaks both limits on the twin as on the plant


def test_the_margin_is_the_student_t_prediction_bound_of_the_errors():
    safety = TwinSafetyFilter(gbo_envs.constraints.Constraints(LIMITS), 0.05)
    safety.errors_ = [np.array([0.1, 1.0]), np.array([0.3, -1.0]), np.array([0.2, 0.5])]
    safety.error_twins_ = [0, 0, 0]  # one twin predicted them all
    errors = np.vstack(safety.errors_)
    risk = run_risk(0.05, 4) / 2  # delta_t split over the two constraints
    expected = errors.mean(0) + stats.t.ppf(1 - risk, 2) * errors.std(0, ddof=1) * math.sqrt(1 + 1 / 3)
    np.testing.assert_allclose(safety.margin(4), expected)
    safety.errors_.append(np.array([np.inf, 0.0]))  # the plant diverged where the twin did not
    safety.error_twins_.append(0)
    margin = safety.margin(5)
    assert margin[0] == np.inf and np.isfinite(margin[1])
    safety.error_twins_.pop()
    with pytest.raises(ValueError, match="error_twins_"):
        safety.margin(5)


class _BiasedTwin:
    """A twin env whose peak command is ``bias`` V below the plant's (``139.2 + 30 (Kp - 0.3)`` V), no overshoot."""

    def __init__(self, bias: float) -> None:
        self.bias = bias

    def noise_free(self):
        return self

    def evaluate_outcome(self, gains, constraints=None):
        peak = 139.2 + 30.0 * (gains[:, 0] - 0.3) - self.bias
        slacks = np.column_stack([np.full(len(gains), -2.0), peak - 140.0])
        return np.zeros((len(gains), 4)), np.ones(len(gains)), slacks, np.all(slacks <= 0.0, axis=1)

    def evaluate_constraints(self, gains, constraints=None):
        return self.evaluate_outcome(gains, constraints)[1:]


def test_the_margin_bounds_the_current_twins_error_with_the_spread_within_each_twin():
    # DCMotorRig-v0, seed 0: the refitted twins' peak command errors at the safe start were 8.87 V (5 experiments),
    # then 7.27 V and 5.09 V; one sample of all of them gave a margin of 13-15 V, above every twin's error
    safety = TwinSafetyFilter(gbo_envs.constraints.Constraints(LIMITS), 0.05)
    start, rng = np.array([0.3, 1.0]), np.random.default_rng(0)
    errors = {8.87: 5, 5.09: 2}
    for bias, count in errors.items():
        twin = _biased(bias)
        for _ in range(count):
            safety.expect(twin, start)
            plant = -0.8 + 0.01 * rng.standard_normal()
            safety.observe(start, {"constraints": {"overshoot_pct": -2.0, "peak_u": plant}})
    # the start: twin slack -5.9 V; (0.33, 1.0): -5.0 V, within the margin of the current twin's 5.1 V error
    assert safety.admits(twin, np.array([start, [0.33, 1.0]]), 8).tolist() == [True, False]
    assert safety.error_twins_ == [0] * 5 + [1] * 2
    e = np.vstack(safety.errors_)[:, 1]
    first, second = e[:5], e[5:]
    within = math.sqrt((np.sum((first - first.mean()) ** 2) + np.sum((second - second.mean()) ** 2)) / (7 - 2))
    bound = second.mean() + stats.t.ppf(1 - run_risk(0.05, 8) / 2, 5) * within * math.sqrt(1 + 1 / 2)
    assert safety.margin(8)[1] == pytest.approx(bound, rel=1e-12)
    assert 5.09 < safety.margin(8)[1] < 5.5 < np.mean(e)  # the current twin's bias, not the mix of the two
    assert not safety.admits(_biased(9.0), start, 9).any()  # a refitted twin, its bias not measured yet


def test_the_filter_learns_only_from_gains_it_predicted():
    twin, env = _twin()
    safety = TwinSafetyFilter(env.unwrapped.constraints, 0.05)
    safety.expect(twin, np.array([0.3, 1.0]))
    env.reset(seed=0)
    safety.observe(np.array([0.4, 1.2]), env.step(np.array([0.4, 1.2]))[4])  # other gains: no error learned
    assert safety.errors_ == []
    with pytest.raises(ValueError, match="delta"):
        TwinSafetyFilter(env.unwrapped.constraints, 0.0)
    with pytest.raises(ValueError, match="constraints"):
        TwinSafetyFilter(gbo_envs.constraints.Constraints({}), 0.05)


def test_the_filter_takes_only_a_twin_simulation_of_its_constraints():
    twin, env = _twin()
    safety = TwinSafetyFilter(env.unwrapped.constraints, 0.05)
    gains = np.array([[0.3, 1.0]])
    for call in (lambda: safety.predicted_slacks(twin.twin_env, gains), lambda: safety.expect(twin.twin_env, gains[0]),
                 lambda: safety.admits(twin.twin_env, gains, 3),
                 lambda: TwinSafeAcquisition(None, None, safety, twin.twin_env, None, 3)):
        with pytest.raises(TypeError, match="twin: expected an agents.twin.prior.TwinSimulation .* got TwinEnv"):
            call()
    with pytest.raises(ValueError, match="twin: the simulation judges the constraints None"):
        safety.admits(TwinSimulation(twin.twin_env), gains, 3)
    assert not safety.admits(None, gains, 3).any() and safety.checked(twin) is twin


# -- guided BO in safe mode ---------------------------------------------------------------------------------
def test_guided_bo_safe_grows_its_safe_set_on_the_twin_and_keeps_the_limits():
    tuner = agents.make("guided-bo", safe=True, safe_start=SAFE_START)
    result = tuner.run(_env(), budget=8, seed=0)
    frame = result.to_pandas()
    assert result.violations == 0
    np.testing.assert_allclose(frame[["Kp", "Ki"]].to_numpy()[0], SAFE_START[0])
    assert result.info["twin_admitted"] >= 1  # proposals the constraint GPs alone did not call safe
    assert frame["true_cost"].min() <= 1.05 * OPTIMUM
    assert tuner.get_params()["safe"] is True and tuner.get_params()["safe_start"] == SAFE_START


def test_guided_bo_safe_refuses_without_a_safe_start_constraints_or_the_twin_prior():
    with pytest.raises(ValueError, match="safe_start"):
        agents.make("guided-bo", safe=True)
    with pytest.raises(ValueError, match="guidance"):
        agents.make("guided-bo", safe=True, safe_start=SAFE_START, guidance="iterations")
    with pytest.raises(ValueError, match="constraints"):
        agents.make("guided-bo", safe=True, safe_start=SAFE_START).run(gym.make(ENV), budget=2, seed=0)
    with pytest.raises(ValueError, match="delta"):
        agents.make("guided-bo", safe=True, safe_start=SAFE_START, safe_delta=1.5)


def test_only_the_twin_admits_gains_the_constraint_gps_weigh_them():
    twin, env = _twin()
    space = agents.GainSpace.from_env(env)
    model = ConstraintModel(env.unwrapped.constraints.names, env.unwrapped.constraints.limits)
    env.reset(seed=0)
    for g in ([0.3, 1.0], [0.25, 0.95]):  # two feasible experiments: the GPs call their neighbourhood safe
        model.add(space.to_unit(np.array(g)), env.step(np.array(g))[4])
    model.fit(seed=0)
    X = space.to_unit(np.array([[0.3, 1.0], [0.28, 0.98], [0.85, 1.07]]))
    assert model.probability(X[:1])[0] > 0.99
    safety = TwinSafetyFilter(env.unwrapped.constraints, 0.05)
    acquisition = TwinSafeAcquisition(None, model, safety, twin, space, 3)
    np.testing.assert_array_equal(acquisition(X), -1.0)  # no measured twin error: nothing is safe
    safety.errors_ = [np.array([0.0, 0.1]), np.array([0.0, -0.1])] * 3  # a margin of 0.64 on peak_u
    safety.error_twins_ = [0] * 6  # errors of the twin the acquisition simulates
    value = acquisition(X)
    assert value[0] > 0 and value[1] > 0 and value[2] == -1.0  # the twin admits; PF weighs
    np.testing.assert_allclose(value[:2], model.probability(X[:2]))


# -- one twin simulation, two readers -----------------------------------------------------------------------
@pytest.fixture
def simulated_rows(monkeypatch):
    """Counter of the gain rows each twin env simulates, keyed by (twin env, gains)."""
    rows = collections.Counter()
    expected = TwinEnv._expected

    def counted(self, loop, gains, record=True):
        rows.update((id(self), row.tobytes()) for row in np.atleast_2d(gains))
        return expected(self, loop, gains, record)

    monkeypatch.setattr(TwinEnv, "_expected", counted)
    return rows


def test_the_metrics_prior_and_the_filter_read_one_simulation_of_each_gain(simulated_rows):
    env = _env()
    keeper = TwinKeeper(twin="linear")
    keeper.setup(agents.GainSpace.from_env(env), env.unwrapped, constraints=env.unwrapped.constraints)
    env.reset(seed=0)
    info = env.step(np.array(SAFE_START[0]))[4]
    keeper.tell(info["gains"], info["cost"], info)
    X = np.random.default_rng(0).random((300, 2))
    safety = TwinSafetyFilter(env.unwrapped.constraints, 0.05)
    slacks = safety.predicted_slacks(keeper.twin_simulation(), keeper.space.from_unit(X))
    metrics = keeper.twin_metrics()(X)
    assert sum(simulated_rows.values()) == 300 == keeper.metric_simulations_  # the prior read the filter's
    _, plain_slacks, _ = keeper.twin_env().evaluate_constraints(keeper.space.from_unit(X),
                                                                constraints=env.unwrapped.constraints)
    np.testing.assert_array_equal(slacks, plain_slacks)
    np.testing.assert_array_equal(metrics, keeper.twin_env().evaluate(keeper.space.from_unit(X))[0])
    with pytest.raises(ValueError, match="constraints"):  # a simulation without the filter's limits
        keeper.setup(keeper.space, env.unwrapped)
        keeper.tell(info["gains"], info["cost"], info)
        safety.predicted_slacks(keeper.twin_simulation(), X)


def test_guided_bo_safe_simulates_each_gain_once_per_twin(simulated_rows):
    result = agents.make("guided-bo", safe=True, safe_start=SAFE_START).run(_env(), budget=5, seed=0)
    repeats = sum(count - 1 for count in simulated_rows.values())
    assert len(simulated_rows) > 1000  # the EI grid on the twin
    # the keeper's check of each measured cost against its twin is the only second simulation of a gain
    assert repeats <= 5 and result.info["twin_evaluations"] == len(simulated_rows)
