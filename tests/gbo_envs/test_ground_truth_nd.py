"""Ground truth from three gains up: the certified search (gbo_envs.optimum_search) behind gbo_envs.ground_truth."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import gbo_envs
from gbo_envs.ground_truth_tables import load_search_table, save_search_table, search_fingerprint
from gbo_envs.optimum_search import SearchDisagreement, certified_minimum

# an unexpected disagreement of the two searches fails the test
pytestmark = pytest.mark.filterwarnings("error::gbo_envs.optimum_search.SearchDisagreement")

LOW, HIGH = np.array([0.0, 10.0, -1.0]), np.array([2.0, 50.0, 1.0])
A, B = np.array([0.3, 0.7, 0.4]), np.array([0.75, 0.25, 0.6])


def two_basins(gains, deep: float = 1.0, scale=(1.0, 2.0, 0.5)) -> np.ndarray:
    """A cheap 3-gain cost: a wide basin at A, a narrower and deeper (global) one at B, a slight tilt."""
    u = (np.atleast_2d(gains) - LOW) / (HIGH - LOW)
    return (1.0 - 0.8 * np.exp(-np.sum((u - A) ** 2, axis=1) / 0.02)
            - deep * np.exp(-np.sum(((u - B) * np.asarray(scale)) ** 2, axis=1) / 0.01) + 0.1 * np.sum(u**2, axis=1))


class ThreeGainEnv(gym.Env):
    """The plant interface ``ground_truth`` uses (action box, gain names and units, batched ``evaluate``)."""

    gain_names = ("Kp", "Ki", "Kd")
    gain_units = ("V s/rad", "V/rad", "V s^2/rad")
    normalizers = np.ones(4)

    def __init__(self) -> None:
        self.action_space = gym.spaces.Box(LOW, HIGH, dtype=np.float64)
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (1,), dtype=np.float64)
        self.evaluated = 0

    def evaluate(self, gains, experiment_index=None):
        gains = np.atleast_2d(gains)
        self.evaluated += gains.shape[0]
        return np.zeros((gains.shape[0], 4)), two_basins(gains)


def brute_force(cost, points_per_gain: int = 81) -> tuple[np.ndarray, float]:
    axes = [np.linspace(lo, hi, points_per_gain) for lo, hi in zip(LOW, HIGH)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, len(axes))
    costs = cost(grid)
    return grid[int(np.argmin(costs))], float(np.min(costs))


def test_a_3_gain_ground_truth_is_a_search_that_agrees_with_brute_force():
    env = ThreeGainEnv()
    truth = gbo_envs.ground_truth(env)
    assert truth.method == "search" and truth.axes == () and truth.costs is None
    gains, cost = brute_force(two_basins)
    spacing = (HIGH - LOW) / 80
    assert truth.cost <= cost  # the search is at least as good as an 81^3 grid ...
    assert np.all(np.abs(truth.gains - gains) <= spacing)  # ... and in the grid minimum's cell
    assert truth.cost == pytest.approx(float(two_basins(truth.gains)[0]), rel=1e-12)
    assert np.all((LOW <= truth.gains) & (truth.gains <= HIGH))
    # the second, independent search agrees within the stated tolerance
    assert truth.tolerance == 1e-3 and truth.certified
    assert truth.check_cost >= truth.cost
    assert truth.disagreement == pytest.approx((truth.check_cost - truth.cost) / truth.cost)
    assert truth.disagreement <= truth.tolerance
    assert np.all(np.abs(truth.check_gains - truth.gains) <= spacing)
    assert truth.evaluations == env.evaluated  # every evaluation was counted, in batches
    assert truth.gain_names == ThreeGainEnv.gain_names and truth.gain_units == ThreeGainEnv.gain_units


def test_the_searches_use_different_sobol_points_and_methods():
    best, other, _ = certified_minimum(two_basins, LOW, HIGH, n_points=1024, n_starts=4)
    assert {best.method, other.method} == {"L-BFGS-B", "Nelder-Mead"} and {best.seed, other.seed} == {0, 1}
    with pytest.raises(ValueError, match="seeds: need two different integers"):
        certified_minimum(two_basins, LOW, HIGH, seeds=(3, 3))


def test_a_disagreement_above_the_tolerance_warns_and_is_reported():
    # four Sobol points and one start per search: search A finds the shallow basin only
    with pytest.warns(SearchDisagreement, match="disagree by 0.11"):
        best, other, disagreement = certified_minimum(
            lambda g: 1.0 - 0.5 * np.exp(-np.sum(((g - LOW) / (HIGH - LOW) - A) ** 2, axis=1) / 0.01)
            - 0.55 * np.exp(-np.sum(((g - LOW) / (HIGH - LOW) - B) ** 2, axis=1) / 0.01),
            LOW, HIGH, n_points=4, n_starts=1)
    assert best.cost == pytest.approx(0.45) and other.cost == pytest.approx(0.5)
    assert disagreement == pytest.approx(0.1 / 0.9, rel=1e-6)


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"method": "exhaustive"}, r"method: must be one of \('auto', 'grid', 'search'\)"),
    ({"n_starts": 0}, "n_starts: must be an integer >= 1"),
    ({"n_points": 4}, "n_points: must be an integer >= 16"),
    ({"tolerance": 0.0}, "tolerance: must be > 0"),
])
def test_bad_search_settings_name_the_parameter(kwargs, message):
    with pytest.raises(ValueError, match=message):
        gbo_envs.ground_truth(ThreeGainEnv(), **kwargs)


def test_two_gains_keep_the_grid_and_may_ask_for_the_search():
    grid = gbo_envs.ground_truth("gbo_envs/DCMotor-v0", resolution=12, noise=False, n_jobs=1)
    assert grid.method == "grid" and grid.costs.shape == (12, 12) and grid.tolerance is None
    assert grid.certified is None
    search = gbo_envs.ground_truth("gbo_envs/DCMotor-v0", method="search", n_points=256, n_starts=2, noise=False)
    assert search.method == "search" and search.certified
    assert search.cost <= grid.cost  # off-grid refinement beats a 12 x 12 grid


def test_plot_of_more_than_two_gains_draws_a_slice_through_the_optimum_or_says_what_it_needs():
    pytest.importorskip("matplotlib")
    env = ThreeGainEnv()
    truth = gbo_envs.ground_truth(env)
    with pytest.raises(ValueError, match="env: the ground truth has 3 gains; pass the env"):
        truth.plot()
    cut = truth.slice(env, pair=(0, 2), resolution=9)
    assert cut.gain_names == ("Kp", "Kd") and cut.costs.shape == (9, 9)
    assert np.all(cut.costs >= truth.cost - 1e-12)  # the slice passes through the minimum
    np.testing.assert_array_equal(cut.gains, truth.gains[[0, 2]])
    ax = truth.plot(env=env, pair=(0, 2), resolution=9)
    assert ax.get_xlabel().startswith("gain Kp") and ax.get_ylabel().startswith("gain Kd")
    with pytest.raises(ValueError, match=r"pair: need two different gain indices in \[0, 3\)"):
        truth.slice(env, pair=(1, 1))


def test_a_search_table_round_trips_and_is_used_only_for_its_settings(tmp_path, monkeypatch):
    import gbo_envs.ground_truth_tables as tables

    env = gym.make("gbo_envs/DCMotor-v0")
    search = {"n_points": 256, "n_starts": 2, "tolerance": 1e-3, "seeds": [0, 1]}
    assert search_fingerprint(env, search)["search"] == search
    monkeypatch.setattr(tables, "TABLE_DIR", tmp_path)
    result = {"gains": [0.5, 1.2], "cost": 0.0, "tolerance": 1e-3, "check_gains": [0.5, 1.2], "check_cost": 0.0,
              "disagreement": 0.0, "evaluations": 7}
    save_search_table(env, search, result)
    assert load_search_table(env, search)["evaluations"] == 7
    assert load_search_table(env, search | {"n_points": 512}) is None
    assert tables.load_table(env, 100) is None  # a search table is no grid
    truth = gbo_envs.ground_truth(env, method="search", n_points=256, n_starts=2)
    assert truth.cost == 0.0 and truth.evaluations == 7  # the (fake) table is what a fitting request reads
    assert gbo_envs.ground_truth(env, method="search", n_points=256, n_starts=2, use_table=False).cost > 0


@pytest.mark.parametrize(("env_id", "message"), [
    ("LinearMotorCascade-v0", r"'LinearMotorCascade-v0' is not a registered env id; did you mean "
                              r"'gbo_envs/LinearMotorCascade-v0'\?"),
    ("gbo_envs/NoSuchMotor-v0", r"'gbo_envs/NoSuchMotor-v0' is not a registered env id; the registered ids"),
])
def test_an_unregistered_id_is_named_with_the_id_it_may_mean(env_id, message):
    with pytest.raises(ValueError, match=f"env_or_id: {message}"):
        gbo_envs.ground_truth(env_id)
    with pytest.raises(ValueError, match=f"env_or_id: {message}"):
        gbo_envs.feasible_set(env_id, constraints={"overshoot_pct": 2.0})
