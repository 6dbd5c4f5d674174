"""The shipped ground-truth tables: they equal the live expectation, and only a request they fit exactly uses them."""

from __future__ import annotations

import dataclasses
import json
import sys
import warnings

import gymnasium as gym
import numpy as np
import pytest

import gbo_envs
from gbo_envs import ground_truth, ground_truth_tables
from gbo_envs.envs.rigs import DC_RIG
from gbo_envs.ground_truth import search_settings
from gbo_envs.ground_truth_tables import TABLE_DIR, fingerprint, load_table, save_table, table_path
from gbo_envs.optimum_search import SearchDisagreement

SHIPPED = sorted(f"gbo_envs/{path.stem}" for path in TABLE_DIR.glob("*.npz"))


def _is_search(env_id: str) -> bool:
    with np.load(table_path(env_id), allow_pickle=False) as data:
        return "check_gains" in data


#: Shipped grids (two gains) and certified searches (three gains and more).
GRIDS = [env_id for env_id in SHIPPED if not _is_search(env_id)]
SEARCHES = [env_id for env_id in SHIPPED if _is_search(env_id)]


def test_the_dc_rig_table_is_shipped():
    assert "gbo_envs/DCMotorRig-v0" in GRIDS
    assert all(env_id in gbo_envs.ENV_IDS for env_id in SHIPPED)


def test_the_envs_with_more_gains_ship_their_search():
    assert {"gbo_envs/DCMotorPID-v0", "gbo_envs/LinearMotorCascade-v0"} <= set(SEARCHES)
    assert all(gym.make(env_id).unwrapped.action_space.shape[0] >= 3 for env_id in SEARCHES)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the PID's two searches agree within the tolerance: no warning
        assert ground_truth("gbo_envs/DCMotorPID-v0").certified


@pytest.mark.parametrize("env_id", SEARCHES)
def test_a_shipped_search_equals_the_live_expectation_and_is_certified(env_id, monkeypatch):
    """A change of the physics, the cost or the defaults that makes a search table stale fails here."""
    env = gym.make(env_id)
    stored = ground_truth_tables.load_search_table(env, search_settings(env.unwrapped.action_space.shape[0]))
    assert stored is not None, "the shipped search does not fit the env's default kwargs: rerun " \
                               "benchmarks/ground_truth_tables.py"
    live = env.unwrapped.evaluate(np.vstack([stored["gains"], stored["check_gains"]]), experiment_index=0)[1]
    np.testing.assert_allclose(live, [stored["cost"], stored["check_cost"]], rtol=1e-12, atol=0.0)
    assert stored["tolerance"] == 1e-3 and stored["check_cost"] >= stored["cost"]
    assert stored["disagreement"] == pytest.approx((stored["check_cost"] - stored["cost"]) / stored["cost"])
    # the default request reads it (no search runs) and warns when the two searches disagree
    monkeypatch.setattr(sys.modules["gbo_envs.ground_truth"], "certified_minimum",
                        lambda *a, **k: pytest.fail("searched live"))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        truth = ground_truth(env_id)
    disagree = [w for w in caught if issubclass(w.category, SearchDisagreement)]
    assert len(disagree) == (0 if stored["disagreement"] <= stored["tolerance"] else 1)
    assert truth.method == "search" and truth.cost == stored["cost"] and truth.disagreement == stored["disagreement"]
    box = env.unwrapped.action_space
    assert np.all((box.low <= truth.gains) & (truth.gains <= box.high))
    noise_free = gym.make(env_id, noise=False)
    noise_free.reset(seed=0)
    assert noise_free.step(truth.gains)[4]["cost"] == pytest.approx(truth.cost, rel=1e-12)


@pytest.mark.parametrize("env_id", GRIDS)
def test_table_cells_equal_the_live_expectation(env_id):
    """A change of the physics, the cost or the defaults that makes a table stale fails here."""
    table = load_table(gym.make(env_id), 100)
    assert table is not None, "the shipped table does not fit the env's default kwargs: rerun " \
                              "benchmarks/ground_truth_tables.py"
    axes, costs = table
    rng = np.random.default_rng(0)
    cells = [np.unravel_index(np.argmin(costs), costs.shape)] + [tuple(rng.integers(0, 100, size=2))
                                                                  for _ in range(3)]
    gains = np.array([[axis[i] for axis, i in zip(axes, cell)] for cell in cells])
    live = gym.make(env_id).unwrapped.evaluate(gains, experiment_index=0)[1]
    np.testing.assert_allclose(live, [costs[cell] for cell in cells], rtol=1e-12, atol=0.0)
    # and what a user reads as the ground truth at the optimum is that of a noise-free step
    env = gym.make(env_id, noise=False)
    env.reset(seed=0)
    truth = ground_truth(env_id)
    assert env.step(truth.gains)[4]["cost"] == pytest.approx(truth.cost, rel=1e-12)


def test_default_request_reads_the_table_and_any_other_computes_live(monkeypatch):
    calls = []

    def counted(env, gains):
        calls.append(gains.shape[0])
        return np.ones(gains.shape[0])

    # the module (the package's attribute of that name is the function)
    monkeypatch.setattr(sys.modules["gbo_envs.ground_truth"], "_evaluate_part", counted)
    rig = "gbo_envs/DCMotorRig-v0"
    for kwargs in ({}, {"noise": False}, {"expectation_draws": DC_RIG["expectation_draws"], "cost_noise_std": 0.0}):
        truth = ground_truth(rig, n_jobs=1, **kwargs)
        assert calls == [] and truth.costs.shape == (100, 100) and truth.cost < 1.0
    for kwargs in ({"resolution": 99}, {"friction": 4.0}, {"expectation_seed": 1},
                   {"expectation_draws": DC_RIG["expectation_draws"] + 1}, {"use_table": False}):
        calls.clear()
        truth = ground_truth(rig, n_jobs=1, **{"resolution": 100} | kwargs)
        assert sum(calls) == truth.costs.size  # every cell simulated
        assert truth.cost == 1.0
    # an env not made from its registered id has no fingerprint
    calls.clear()
    ground_truth(gbo_envs.envs.rigs.DCMotorRigEnv(), n_jobs=1)
    assert sum(calls) == 100 * 100


def test_fingerprint_is_the_effective_kwargs():
    default = fingerprint(gym.make("gbo_envs/DCMotorRig-v0"), 100)
    assert default["env_id"] == "gbo_envs/DCMotorRig-v0" and default["resolution"] == 100
    assert default["kwargs"]["expectation_draws"] == DC_RIG["expectation_draws"]
    assert default["kwargs"]["expectation_seed"] == 0
    assert default["kwargs"]["friction"] == 5.0 and "noise" not in default["kwargs"]
    # spelling a default out does not change it, a kwarg of the cost does
    assert fingerprint(gym.make("gbo_envs/DCMotorRig-v0", friction=5.0, noise=False), 100) == default
    assert fingerprint(gym.make("gbo_envs/DCMotorRig-v0", unstable_cost=9.0), 100) != default
    assert fingerprint(gym.make("gbo_envs/DCMotorRig-v0"), 50) != default


def test_a_stale_table_is_not_used(tmp_path, monkeypatch):
    monkeypatch.setattr(ground_truth_tables, "TABLE_DIR", tmp_path)
    env = gym.make("gbo_envs/LinearMotorRig-v0")
    axes = tuple(np.linspace(lo, hi, 3) for lo, hi in zip(env.action_space.low, env.action_space.high))
    path = save_table(env, axes, np.arange(9.0).reshape(3, 3))
    assert path == table_path("gbo_envs/LinearMotorRig-v0") and path.parent == tmp_path
    read_axes, costs = load_table(env, 3)
    np.testing.assert_array_equal(costs, np.arange(9.0).reshape(3, 3))
    assert ground_truth(env, resolution=3).cost == 0.0  # the (fake) table is what a fitting request reads
    # other normalisers (a changed plant), another fingerprint or another box: not used
    with np.load(path) as data:
        fields = dict(data)
    np.savez(path, **fields | {"normalizers": fields["normalizers"] * 1.001})
    assert load_table(env, 3) is None
    stamp = json.loads(str(fields["fingerprint"]))
    stamp["kwargs"]["friction"] = 0.4
    np.savez(path, **fields | {"fingerprint": np.array(json.dumps(stamp))})
    assert load_table(env, 3) is None
    np.savez(path, **fields | {"axis_0": fields["axis_0"] * 2})
    assert load_table(env, 3) is None


def test_save_table_needs_a_registered_env(tmp_path):
    with pytest.raises(ValueError, match="env"):
        save_table(gbo_envs.envs.rigs.LinearMotorRigEnv(), (np.zeros(2), np.zeros(2)), np.zeros((2, 2)),
                   tmp_path / "x.npz")


@pytest.mark.parametrize(("env_id", "options"), [
    ("gbo_envs/DCMotorRig-v0", {"plant": gbo_envs.DCMotorPlant(), "measurement_noise": gbo_envs.MeasurementNoise()}),
    ("gbo_envs/LinearMotorRig-v0", {"plant": gbo_envs.LinearMotorPlant(), "drive": gbo_envs.LinearMotorDrive()}),
    ("gbo_envs/DCMotorPID-v0", {"plant": gbo_envs.DCMotorPlant()}),
    ("gbo_envs/LinearMotorCascade-v0", {"drive": gbo_envs.CascadeDrive(), "plant": gbo_envs.LinearMotorPlant()}),
])
def test_every_shipped_table_loads_with_its_default_options_given_or_not(env_id, options):
    """The option objects enter the fingerprint as their fields: the defaults, given or not, read the table;
    another value of a field does not."""
    def load(env):
        n_gains = env.unwrapped.action_space.shape[0]
        if n_gains == 2:
            return load_table(env, 100)
        return ground_truth_tables.load_search_table(env, search_settings(n_gains))

    assert env_id in SHIPPED
    plain, given = gym.make(env_id), gym.make(env_id, **options)
    assert fingerprint(given, 100) == fingerprint(plain, 100)
    assert load(plain) is not None and load(given) is not None
    name, option = next(iter(options.items()))
    changed = dataclasses.replace(option, **{dataclasses.fields(option)[-1].name: 0.0015})
    assert load(gym.make(env_id, **{name: changed})) is None
