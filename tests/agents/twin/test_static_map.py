"""Static maps (issue 56, point 1): piecewise-linear input (Hammerstein) and output (Wiener) maps as blocks and as
candidates of a diagnosis, ranked after the catalogue's effects where those explain as much."""

from __future__ import annotations

import numpy as np
import pytest

from agents.twin.candidates import Candidate
from agents.twin.coast_down import coast_downs, speed_tolerance
from agents.twin.diagnose import diagnose
from agents.twin.fits import fit_structure
from agents.twin.least_squares import fit_problems
from agents.twin.linear_fit import linear_fit
from agents.twin.map_figure import map_figure
from agents.twin.open_loop import simulate_open_loop
from agents.twin.ranking import _physics_first, effect_intervals
from agents.twin.records import Batch
from agents.twin.static_map import map_curve, map_evidence, map_options
from benchmarks.real_like_sets import BELT_SENSOR, belt_tacho_records
from evaluation.twin_cli import _check_effects
from gbo_envs import ContinuousPlant, Experiment
from gbo_envs.physics.effects import EFFECT_NAMES, build_effect

PLANT = ContinuousPlant((10.0,), (1.0, 10.0))  # 1 unit per unit, 0.1 s
#: A drive whose gain falls with the level: 1.5 up to 1, then 1.0, then 0.5 (a smooth saturation's shape).
FALLING = {"k0": 0.0, "k1": 1.0, "k2": 2.0, "k3": 3.0, "k4": 4.0, "v0": 0.0, "v1": 1.5, "v2": 2.5, "v3": 3.0,
           "v4": 3.5}


def test_the_map_is_piecewise_linear_with_the_outer_slopes_beyond_its_breakpoints():
    block = build_effect("input_map", FALLING)
    x = np.array([-1.0, 0.5, 1.5, 3.5, 5.0])
    assert block.actuate(x, np.zeros(5)) == pytest.approx([-1.5, 0.75, 2.0, 3.25, 4.0])
    assert build_effect("input_map", {**FALLING, "weight": 0.0}).actuate(x, np.zeros(5)) == pytest.approx(x)
    assert "input_map" not in EFFECT_NAMES  # built like an effect, not a catalogue effect


def test_a_one_way_map_inverts_its_zero_to_zero_and_rejects_unordered_breakpoints():
    one_way = build_effect("output_map", {"k0": -1.0, "k1": 0.0, "k2": 1.0, "k3": 2.0, "k4": 3.0, "v0": 0.0,
                                          "v1": 0.0})
    assert one_way.measure(np.array([-2.0, -0.5, 2.5])) == pytest.approx([0.0, 0.0, 2.5])
    assert one_way.level_for(np.array([0.0, 1.5])) == pytest.approx([0.0, 1.5])
    with pytest.raises(ValueError, match="'k0'..'k4'"):
        build_effect("input_map", {"k0": 0.0, "k1": 2.0, "k2": 1.0, "k3": 3.0, "k4": 4.0})


def _records(effects, levels=((0.5, 1.5, 2.5, 3.5), (1.0, 3.0, 2.0, 0.5), (3.5, 0.5, 2.0, 1.0)), dt=0.01,
             seed=0) -> list:
    """Staircases from rest (0.2 s at u = 0, then 0.6 s per level) through ``effects``; noise 0.005."""
    rng = np.random.default_rng(seed)
    out = []
    for k, stairs in enumerate(levels):
        u = np.concatenate([np.zeros(20), np.repeat(stairs, 60)])
        blocks = tuple(build_effect(name, params) for name, params in effects.items())
        res = simulate_open_loop(PLANT, u[None], dt, blocks, y0=0.0, bias=0.0)
        y = res.y[0] + 0.005 * rng.standard_normal(u.size)
        out.append(Experiment(gains=(), t=np.arange(u.size) * dt, r=u.copy(), u=u, y=y, index=k))
    return out


def test_breakpoints_hold_the_identity_at_the_ends_or_at_zero():
    data = Batch.from_records(_records({"input_map": FALLING}))
    one_sign = map_options("input_map", data)
    assert (one_sign["k0"], one_sign["v0"], one_sign["k4"], one_sign["v4"]) == (0.0, 0.0, 3.5, 3.5)
    both = Batch.from_records(_records({"input_map": FALLING}, levels=((1.0, -1.0, 2.0, -2.0),)))
    options = map_options("input_map", both)
    assert options["variant"] == "zero" and options["k1"] == 0.0 and options["v1"] == 0.0


def _fitted(data: Batch, name: str):
    base = linear_fit(data)
    problems = Candidate(name, (map_options(name, data),)).problems(data, base)
    fit_problems(data, problems, max_iter=30)
    return base, min(problems, key=lambda p: p.cost).fit(data)


def test_an_input_map_is_fitted_with_the_linear_part_and_shows_the_falling_gain():
    data = Batch.from_records(_records({"input_map": FALLING}))
    base, fit = _fitted(data, "input_map")
    assert fit.rmse < 0.2 * base.rmse
    _, _, knots, values = map_curve(fit, "input_map")
    slopes = np.diff(values) / np.diff(knots)
    assert slopes[0] > 1.5 * slopes[-1]  # the drive's gain falls with the level (1.5 -> 0.5 in the plant)


def test_the_maps_evidence_gives_the_change_of_the_error_with_its_sign():
    data = Batch.from_records(_records({"input_map": FALLING}))
    base, fit = _fitted(data, "input_map")
    change = 100.0 * (fit.rmse / base.rmse - 1.0)
    assert map_evidence("input_map", data, base, fit).endswith(f", {change:+.0f} %)") and change < -50
    # the fitted inner breakpoints and values get intervals; the outer breakpoints are placed, and not listed
    assert set(effect_intervals(data, fit, "input_map")) == {"k1", "k2", "k3", "v1", "v2", "v3"}


def test_a_kink_between_the_placed_breakpoints_is_found_where_it_is():
    # the drive's gain falls from 1 to 0.3 at 2.25: between the breakpoints placed on the data's quantiles
    kinked = {"k0": 0.0, "k1": 1.0, "k2": 2.25, "k3": 3.0, "k4": 3.5, "v0": 0.0, "v1": 1.0, "v2": 2.25,
              "v3": 2.475, "v4": 2.625}
    levels = ((0.5, 1.5, 2.5, 3.5), (1.0, 3.0, 2.0, 0.5), (3.5, 0.5, 2.0, 1.0), (2.25, 2.75, 1.75, 3.25))
    data = Batch.from_records(_records({"input_map": kinked}, levels=levels))
    placed = [map_options("input_map", data)[f"k{i}"] for i in (1, 2, 3)]
    assert min(abs(np.array(placed) - 2.25)) > 0.2  # no placed breakpoint at the kink
    _, fit = _fitted(data, "input_map")
    fitted = np.array([fit.effect_params["input_map"][f"k{i}"] for i in (1, 2, 3)])
    assert min(abs(fitted - 2.25)) < 0.1
    assert fit.rmse < 1.3 * 0.005  # within the records' noise (0.005)


def test_a_one_way_sensor_is_an_output_map_with_nothing_below_zero():
    sensor = {"k0": -5.0, "k1": 0.0, "k2": 1.0, "k3": 2.0, "k4": 5.0, "v0": 0.0, "v1": 0.0}
    data = Batch.from_records(_records({"output_map": sensor}, levels=((2.0, -1.0, 1.0, -2.0), (-1.5, 2.5, -0.5,
                                                                                                 1.5))))
    assert data.y.min() > -0.05  # the sensor never reads below zero
    base, fit = _fitted(data, "output_map")
    params = fit.effect_params["output_map"]
    assert params["variant"] == "zero" and abs(params["v0"]) < 0.05 * abs(params["k0"])  # flat below zero
    assert fit.rmse < 0.2 * base.rmse


def test_a_map_goes_ahead_of_a_catalogue_effect_only_where_it_explains_and_predicts_clearly_more():
    effect = {"effect": "saturation", "kind": "effect", "share": 85.0, "rmse": 1.0, "delta_bic": -100.0}
    close = {"effect": "input_map", "kind": "map", "share": 90.0, "rmse": 0.97, "delta_bic": -120.0}
    clear = {**close, "share": 99.0, "rmse": 0.5}
    order = {"effect": "pole", "kind": "order", "share": 99.0, "rmse": 0.4, "delta_bic": -300.0}
    assert [c["effect"] for c in _physics_first([order, close, effect])] == ["saturation", "input_map", "pole"]
    assert [c["effect"] for c in _physics_first([clear, effect])] == ["input_map", "saturation"]


def test_the_map_figure_has_units_on_its_axes():
    data = Batch.from_records(_records({"input_map": FALLING}))
    _, fit = _fitted(data, "input_map")
    ax = map_figure(fit, "input_map", unit="V").axes[0]
    assert ax.get_xlabel() == "commanded input u (V)" and ax.get_ylabel() == "plant input m(u) (V)"
    with pytest.raises(ValueError, match="output_map"):
        map_figure(fit, "output_map")


def test_the_belt_set_has_its_falling_gain_coast_downs_and_one_way_tacho():
    records = belt_tacho_records()
    stairs = records[1]
    gain = [stairs.y[20 + 50 * v - 5 : 20 + 50 * v].mean() / v for v in (1, 5)]  # the end of each 5 s stair
    assert gain == pytest.approx([1.06, 0.85], abs=0.01)
    data = Batch.from_records(records)
    assert BELT_SENSOR[0] <= data.y[data.mask].min() and data.y[data.mask].max() <= BELT_SENSOR[1]
    assert coast_downs(data, "speed", speed_tolerance(data.y, data.mask))[:2].all()


def test_the_belt_sets_drive_map_cuts_the_linear_models_error():
    data = Batch.from_records(belt_tacho_records())
    base, fit = _fitted(data, "input_map")
    assert fit.rmse < 0.65 * base.rmse  # 0.146 -> 0.090


@pytest.mark.slow
def test_the_belt_sets_drive_map_and_smooth_friction_replay_it_within_the_noise():
    # issue 56: to within 1.5 times the noise floor (0.00914 V); with the breakpoints held where they were
    # placed the fit ended at 0.0159 V (1.74 times), its drive map's kink at 3 V smeared over 2.6-4 V
    data = Batch.from_records(belt_tacho_records())
    fit = fit_structure(data, {"input_map": {}, "coulomb_friction": {"variant": "smooth"}})
    assert fit.rmse < 1.5 * 0.00914
    assert fit.effect_params["coulomb_friction"]["torque"] == pytest.approx(1.0, rel=0.1)  # the hidden 1.0 V


@pytest.mark.slow
def test_a_hidden_input_map_is_named_by_the_diagnosis():
    d = diagnose(Batch.from_records(_records({"input_map": FALLING})))
    assert d.best == "input_map"
    assert d.fits["input_map"].rmse < 0.2 * d.current.rmse


def test_a_map_named_in_effects_is_fitted_as_the_advice_suggests(tmp_path):
    # the advice after a map says `gbo twin diagnose DATA --effects input_map,...`: that command must run
    _check_effects("input_map,coulomb_friction")
    with pytest.raises(ValueError, match="static maps are input_map, output_map"):
        _check_effects("input_mapp")
    data = Batch.from_records(belt_tacho_records())
    linear, mapped = fit_structure(data), fit_structure(data, ["input_map"])
    assert mapped.spec.effect_names == ("input_map",)
    assert mapped.rmse < 0.8 * linear.rmse
