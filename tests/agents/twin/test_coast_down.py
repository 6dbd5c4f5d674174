"""Friction seen in coast-downs (issue 56, point 2): a deceleration at zero drive makes Coulomb friction
observable in records that neither reverse nor show their rest, and the Coulomb candidate fits it."""

from __future__ import annotations

import numpy as np
import pytest

from agents.twin.candidates import candidate_plan
from agents.twin.coast_down import coast_down_torque, coast_downs, speed_tolerance
from agents.twin.diagnose import diagnose
from agents.twin.evidence import excitation_notes
from agents.twin.fits import fit_structure
from agents.twin.linear_fit import linear_fit
from agents.twin.model import effect_items
from agents.twin.open_loop import simulate_open_loop
from agents.twin.records import Batch
from benchmarks.real_like_sets import BELT_FRICTION, FOC_PLANT, belt_tacho_records
from evaluation.twin_cli import _check_effects
from gbo_envs import Experiment
from gbo_envs.physics.effects import build_effects

TORQUE = 0.1  # A of q-axis current


def coasting_records(torque: float = TORQUE, n_records: int = 4, dt: float = 0.01, seed: int = 1) -> list:
    """Records that start moving (the drive on for 30 ms before the log starts: accelerating), run 1.5 s and
    coast 0.5 s at zero drive to standstill: one direction only, no rest shown at the start."""
    rng = np.random.default_rng(seed)
    records = []
    for k, level in enumerate(np.linspace(0.5, 1.1, n_records)):
        u = np.concatenate([np.full(150, level), np.zeros(50)])
        blocks = build_effects({"coulomb_friction": {"torque": torque, "smoothing": 0.5}})  # it stops, no chatter
        speed = simulate_open_loop(FOC_PLANT, u[None], dt, blocks, y0=0.0, bias=0.0).y_true[0]
        keep = slice(3, None)
        y = speed[keep] + 0.1 * rng.standard_normal(u[keep].size)
        records.append(Experiment(gains=(), t=np.arange(u[keep].size) * dt, r=u[keep].copy(), u=u[keep].copy(),
                                  y=y, index=k))
    return records


def test_coast_downs_are_found_where_the_drive_is_zero_and_the_speed_falls():
    data = Batch.from_records(coasting_records())
    assert not data.initial.pinned.any()  # the records start moving: their rest is not shown
    tol = speed_tolerance(data.y, data.mask)
    assert coast_downs(data, "speed", tol).all()
    held = Batch.from_records([r.replace(u=np.full(r.n_steps, r.u[0]), r=np.full(r.n_steps, r.u[0]))
                               for r in coasting_records(torque=0.0)])  # no coast: the drive never stops
    assert not coast_downs(held, "speed", speed_tolerance(held.y, held.mask)).any()


def test_a_coast_down_makes_coulomb_friction_observable():
    notes = excitation_notes(Batch.from_records(coasting_records()), "speed")
    assert "coulomb_friction" not in notes and "stiction" not in notes


def test_the_coast_down_deceleration_gives_a_start_of_the_coulomb_level():
    data = Batch.from_records(coasting_records())
    level = coast_down_torque(data, linear_fit(data))  # a start for the fit (0.039 here), not its result
    assert level is not None and 0.25 * TORQUE < level < 2.0 * TORQUE
    free = Batch.from_records(coasting_records(torque=0.0))  # no friction: the coast-down is the plant's decay
    assert (coast_down_torque(free, linear_fit(free)) or 0.0) < 0.25 * TORQUE


@pytest.mark.slow
def test_coulomb_friction_is_named_and_fitted_from_coast_downs():
    d = diagnose(Batch.from_records(coasting_records()), candidates=["coulomb_friction", "offset"])
    assert d.best == "coulomb_friction"
    # 0.073: the plant's friction is smoothed over 0.5 rad/s near standstill, the candidate's is not
    assert d.fits["coulomb_friction"].effect_params["coulomb_friction"]["torque"] == pytest.approx(TORQUE, rel=0.3)
    assert d.fits["coulomb_friction"].rmse < 0.6 * d.current.rmse


def test_friction_that_fades_out_near_standstill_is_fitted_with_its_ramp():
    # the belt's friction ramps below 0.2 V of tacho speed: fitted as a sign, its level comes out at 0.67 and
    # the error at 5.3x the noise (0.0091 V); with its ramp at 1.04, and 1.7x the noise
    data = Batch.from_records(belt_tacho_records())
    sign = fit_structure(data, ["input_map", "coulomb_friction"])
    smooth = fit_structure(data, ["input_map", "coulomb_friction:smooth"])
    params = smooth.effect_params["coulomb_friction"]
    assert params["torque"] == pytest.approx(BELT_FRICTION["torque"], rel=0.1)
    assert params["smoothing"] == pytest.approx(BELT_FRICTION["smoothing"], rel=0.6)
    assert smooth.rmse < 0.4 * sign.rmse


def test_the_ramp_of_friction_is_tried_only_where_the_data_coast_down():
    def variants(records):
        data = Batch.from_records(records)
        plan = candidate_plan(data, linear_fit(data), ["coulomb_friction"], skip_unexcited=False, orders=False)
        return plan.candidates[0].variants

    assert {"variant": "smooth"} in variants(coasting_records())
    driven = [r.replace(u=np.maximum(r.u, 0.3), r=np.maximum(r.r, 0.3)) for r in coasting_records()]  # never 0
    assert {"variant": "smooth"} not in variants(driven)


def test_effects_name_a_variant_after_a_colon_as_the_advice_prints_it():
    assert effect_items("input_map,coulomb_friction:smooth") == [("input_map", {}),
                                                                  ("coulomb_friction", {"variant": "smooth"})]
    with pytest.raises(ValueError, match=r"'coulomb_friction' has no variant 'rough'; its variants: "
                                         r"\['asymmetric', 'smooth'\]"):
        effect_items(["coulomb_friction:rough"])
    with pytest.raises(ValueError, match=r"^--effects: 'saturation' has no variant 'smooth'; its variants: none"):
        _check_effects("saturation:smooth")
