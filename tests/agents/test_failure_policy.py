"""The one failure policy of the tuning loop, with and without an experiment log (Tuner.run and TuningSession)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import gbo_envs  # noqa: F401  (registers the envs)
from agents.base import Tuner, TuningStopped
from evaluation.sessions import SessionStore, TuningSession
from gbo_envs import CostSpec, FailurePolicy, PIController, StepExperiment
from gbo_envs.envs.external import ExternalPlantEnv
from tests.support import RaiseAt

ENV = "gbo_envs/DCMotor-v0"
MODES = ("run", "session")


class Recording(Tuner):
    """Uniform random search that remembers what it was told: ``(cost, record is None, unstable)``."""

    name = "test-recording"

    def __init__(self) -> None:
        self._params = {}

    def _setup(self) -> None:
        self.told = []

    def _ask(self) -> np.ndarray:
        return self.rng.uniform(self.space.low, self.space.high)

    def _tell(self, gains, cost, record) -> None:
        self.told.append((cost, record is None, None if record is None else bool(record.get("unstable"))))


class EditInfo(gym.Wrapper):
    """Replaces ``info`` entries on the given (1-based) step calls."""

    def __init__(self, env, calls, **changes) -> None:
        super().__init__(env)
        self.calls, self.changes, self.count = set(calls), changes, 0

    def step(self, action):
        self.count += 1
        observation, reward, terminated, truncated, info = self.env.step(action)
        if self.count in self.calls:
            info = {**info, **self.changes}
        return observation, reward, terminated, truncated, info


def _rig(fail_calls, on_failure):
    """An external rig (the noise-free DC motor loop) whose listed calls (1-based) raise ConnectionError."""
    plant = gym.make(ENV, noise=False).unwrapped
    calls = []

    def run_experiment(gains):
        calls.append(1)
        if len(calls) in fail_calls:
            raise ConnectionError(f"link lost on call {len(calls)}")
        response = plant.loop.simulate(np.asarray(gains)[None, :])
        return response.t, response.r, response.u[0], response.y[0]

    return ExternalPlantEnv(run_experiment, {"Kp": (0.11, 1.10), "Ki": (0.87, 2.08)}, controller=PIController(),
                            experiment=StepExperiment((245.0, 306.0), dt=0.002, duration=5.0),
                            cost=CostSpec(normalizers=plant.normalizers),
                            failure_policy=FailurePolicy(on_failure=on_failure, failure_cost=5.0))


def _tune(mode, env, tuner, budget, tmp_path, **options):
    if mode == "run":
        return tuner.run(env, budget=budget, seed=0, **options)
    return TuningSession(tmp_path / "runs.sqlite", env, tuner, budget=budget, seed=0, env_id="plant", **options).run()


def _plant_rows(tmp_path):
    with SessionStore(tmp_path / "runs.sqlite") as store:
        return store.experiments(1, source="plant")


def _gains(result):
    return [tuple(row[n] for n in result.gain_names) for row in result.plant_rows]


@pytest.mark.parametrize("mode", MODES)
def test_penalised_failures_are_told_the_penalty_without_a_record(mode, tmp_path):
    tuner = Recording()
    result = _tune(mode, _rig({2, 3}, "penalize"), tuner, 5, tmp_path)
    assert [cost for cost, _, _ in tuner.told][1:3] == [5.0, 5.0]
    assert [no_record for _, no_record, _ in tuner.told] == [False, True, True, False, False]
    assert result.n_experiments == 5 and [row["cost"] for row in result.plant_rows][1:3] == [5.0, 5.0]
    if mode == "session":
        rows = _plant_rows(tmp_path)
        assert [r.status for r in rows] == ["ok", "failed", "failed", "ok", "ok"]
        assert [r.cost for r in rows if r.status == "failed"] == [None, None]  # a penalty is not a measurement
        assert [r.told_cost for r in rows if r.status == "failed"] == [5.0, 5.0]


@pytest.mark.parametrize("mode", MODES)
def test_skipped_failures_are_not_told_and_do_not_count(mode, tmp_path):
    tuner = Recording()
    result = _tune(mode, _rig({2, 3}, "skip"), tuner, 5, tmp_path)
    assert len(tuner.told) == 5 and all(not no_record for _, no_record, _ in tuner.told)
    assert result.n_experiments == 5 and [row["experiment"] for row in result.plant_rows] == [1, 2, 3, 4, 5]
    reference = Recording().run(_rig(set(), "skip"), budget=7, seed=0)
    # experiments 2 and 3 were proposed, failed and proposed again: the tuner drew 7 proposals
    assert _gains(result) == [_gains(reference)[k] for k in (0, 3, 4, 5, 6)]
    if mode == "session":
        assert [(r.status, r.told) for r in _plant_rows(tmp_path)] == (
            [("ok", True), ("failed", False), ("failed", False)] + [("ok", True)] * 4)


@pytest.mark.parametrize("mode", MODES)
def test_stop_policy_and_too_many_skips_stop_with_the_finished_experiments(mode, tmp_path):
    with pytest.raises(TuningStopped, match="experiment 3 failed .*ConnectionError.*'stop'") as caught:
        _tune(mode, _rig({3}, "stop"), Recording(), 4, tmp_path / "stop")
    assert caught.value.result.n_experiments == 2
    with pytest.raises(TuningStopped, match="3 failed experiments in a row") as caught:
        _tune(mode, _rig(set(range(2, 99)), "skip"), Recording(), 4, tmp_path / "dead", max_consecutive_skips=3)
    assert caught.value.result.n_experiments == 1


@pytest.mark.parametrize("mode", MODES)
def test_an_env_error_propagates_and_the_tuner_is_not_told(mode, tmp_path):
    tuner = Recording()
    env = RaiseAt(gym.make(ENV), calls=[3], error=RuntimeError("amplifier tripped"))
    with pytest.raises(RuntimeError, match="amplifier tripped"):
        _tune(mode, env, tuner, 5, tmp_path)
    assert len(tuner.told) == 2
    if mode == "session":
        rows = _plant_rows(tmp_path)
        assert [(r.status, r.told) for r in rows] == [("ok", True), ("ok", True), ("failed", False)]
        assert rows[-1].reason == "RuntimeError: amplifier tripped"


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("cost", [np.nan, np.inf])
def test_a_non_finite_cost_is_a_failed_experiment_and_raises(mode, cost, tmp_path):
    tuner = Recording()
    with pytest.raises(ValueError, match="experiment 2: env.step reported a non-finite cost"):
        _tune(mode, EditInfo(gym.make(ENV), calls=[2], cost=cost), tuner, 4, tmp_path)
    assert len(tuner.told) == 1
    if mode == "session":
        rows = _plant_rows(tmp_path)
        assert [(r.status, r.told, r.told_cost) for r in rows] == [("ok", True, rows[0].cost), ("failed", False, None)]
        assert "non-finite cost" in rows[-1].reason


@pytest.mark.parametrize("mode", MODES)
def test_an_unstable_loop_is_learned_like_any_cost(mode, tmp_path):
    tuner = Recording()
    result = _tune(mode, EditInfo(gym.make(ENV), calls=[2], unstable=True, cost=10.0), tuner, 3, tmp_path)
    assert tuner.told[1] == (10.0, False, True)
    assert [row["unstable"] for row in result.plant_rows] == [False, True, False]
    assert result.plant_rows[1]["cost"] == 10.0
    if mode == "session":
        assert [(r.status, r.unstable) for r in _plant_rows(tmp_path)] == [("ok", False), ("ok", True), ("ok", False)]


def test_max_consecutive_skips_is_validated():
    with pytest.raises(ValueError, match="max_consecutive_skips"):
        Recording().run(gym.make(ENV), budget=2, max_consecutive_skips=0)
