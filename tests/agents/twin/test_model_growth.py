"""A twin that grows beyond the catalogue (issue 36): the compliance effect, the linear part's orders as candidates,
and guided BO's twin following them on a rig with a flexible coupling.

Data: DCMotor-v0 with a flexible coupling between motor and load (``effects={"compliance": ...}``, 12 rad/s,
damping 0.08, measured at the load), eight 5 s experiments at random gains, 0.05 rad/s of sensor noise.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import gbo_envs  # noqa: F401  (registers the envs)
from agents.twin import Batch, diagnose
from agents.twin.candidates import ORDER_CANDIDATES
from agents.twin.csvio import records_from_loop
from agents.twin.diagnosis_options import CandidateSearch
from gbo_envs.physics import Compliance, ContinuousPlant, build_effect, describe_effect
from tests.support import DC_PLANT


def _coupled_records(frequency=12.0, damping=0.08, n=8, seed=0):
    env = gym.make("gbo_envs/DCMotor-v0", effects={"compliance": {"frequency": frequency, "damping": damping}},
                   output_noise_std=0.05)
    gains = np.random.default_rng(seed).uniform(env.action_space.low, env.action_space.high, size=(n, 2))
    return records_from_loop(env.unwrapped.loop, gains, rng=np.random.default_rng(seed))


# -- the compliance effect ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("measured", ["load", "motor"])
def test_compliance_adds_a_resonance_and_keeps_the_static_gain(measured):
    block = Compliance(12.0, damping=0.08, inertia_ratio=3.0, measured=measured)
    coupled = block.modify_plant(DC_PLANT, 0)
    assert len(coupled.den) == len(DC_PLANT.den) + 2 and coupled.delay == DC_PLANT.delay
    assert coupled.dc_gain == pytest.approx(DC_PLANT.dc_gain, rel=1e-12)
    poles = np.roots(coupled.den)
    pair = poles[np.argmin(np.abs(np.abs(poles) - 12.0))]
    assert abs(pair) == pytest.approx(12.0, rel=1e-9) and -pair.real / abs(pair) == pytest.approx(0.08, rel=1e-9)
    zeros = np.roots(coupled.num)
    if measured == "motor":  # the anti-resonance, w / sqrt(1 + r) = 6 rad/s
        assert np.min(np.abs(np.abs(zeros) - 6.0)) < 1e-9
    else:  # the damping's zero only, at -w / (2 zeta)
        assert zeros.size == 1 and zeros[0] == pytest.approx(-12.0 / 0.16)


def test_a_rigid_coupling_is_no_effect_and_the_catalogue_describes_it():
    assert build_effect("compliance", {"frequency": float("inf")}).modify_plant(DC_PLANT, 0) == DC_PLANT
    names = [p.name for p in describe_effect("compliance")]
    assert names == ["frequency", "damping", "inertia_ratio"]
    with pytest.raises(ValueError, match="compliance: parameter 'measured'"):
        build_effect("compliance", {"frequency": 10.0, "measured": "belt"})


def test_an_env_with_a_coupling_rings():
    rigid = gym.make("gbo_envs/DCMotor-v0", noise=False)
    coupled = gym.make("gbo_envs/DCMotor-v0", noise=False,
                       effects={"compliance": {"frequency": 12.0, "damping": 0.05}})
    gains = np.array([1.0, 2.0])
    y_rigid = rigid.unwrapped.loop.simulate(gains).y[0]
    y_coupled = coupled.unwrapped.loop.simulate(gains).y[0]
    ringing = y_coupled - y_rigid
    spectrum = np.abs(np.fft.rfft(ringing - ringing.mean()))
    peak = 2.0 * np.pi * np.fft.rfftfreq(ringing.size, 0.002)[np.argmax(spectrum[1:]) + 1]
    assert 8.0 < peak < 16.0  # the loop rings near the coupling's resonance


# -- the linear part's orders as candidates -------------------------------------------------------------------------

@pytest.mark.slow
def test_diagnose_names_the_coupling_and_says_where_the_residual_rings():
    data = Batch.from_records(_coupled_records())
    result = diagnose(data, search=CandidateSearch(general_as_fallback=False))  # the pole pair fitted too
    assert result.best in ("compliance", "pole_pair")
    ranked = {c["effect"]: c for c in result.candidates}
    assert {"compliance", *ORDER_CANDIDATES} <= set(ranked)
    best = ranked[result.best]
    assert "rings at" in best["evidence"] and "rad/s" in best["evidence"]
    frequency = best["params"]["frequency"]
    assert frequency == pytest.approx(12.0, rel=0.05)
    assert result.fits[result.best].rmse <= 1.5 * result.noise_rmse
    pair = ranked["pole_pair"]  # the bare pole pair finds the same resonance
    assert pair["kind"] == "order" and pair["params"]["frequency"] == pytest.approx(12.0, rel=0.05)
    step = result.step(result.best)
    assert "frequency" in step["text"] and "rad/s" in step["text"]


@pytest.mark.slow
def test_one_record_grows_no_order_but_two_do():
    """One experiment holds nothing out, and its training error favours the more flexible structure: the
    order candidates are ranked but none is the best; a second experiment cross-validates the pole pair (the
    one effect offered, an offset, cannot show in records that start with their excitation)."""
    one = diagnose(Batch.from_records(_coupled_records(n=1)), candidates=["offset"])
    assert one.best is None and one.validation.startswith("training error")
    assert one.candidates[0]["kind"] == "order" and one.candidates[0]["rmse"] < 0.5 * one.current.rmse
    two = diagnose(Batch.from_records(_coupled_records(n=2)), candidates=["offset"])
    assert two.best == "pole_pair"


def test_order_candidates_stop_at_six_poles():
    from agents.twin.candidates import MAX_POLES, OrderCandidate, candidate_plan
    from agents.twin.fits import fit_model
    from agents.twin.model import ModelSpec

    data = Batch.from_records(_coupled_records(n=2))
    current = fit_model(data, spec=ModelSpec(n_poles=5))
    grown = [c.name for c in candidate_plan(data, current).candidates if isinstance(c, OrderCandidate)]
    assert MAX_POLES == 6 and set(grown) == {"pole", "zero"}  # a pole pair would make 7


# -- guided BO grows its twin ---------------------------------------------------------------------------------------

@pytest.mark.slow
def test_guided_bo_grows_its_twin_on_a_rig_with_a_flexible_coupling():
    import agents
    from tests.support import flexible_coupling_env

    env = flexible_coupling_env(omega=15.0, zeta=0.1, noise_std=0.05, seed=1)
    result = agents.make("guided-bo").run(env, budget=4, seed=1)
    changes = result.info["twin_changes"]
    grown = [c for c in changes if "compliance" in c["effects"] or "p" in c["model"] and
             int(c["model"].split("(")[1].split("p")[0]) > 2]
    assert grown, [c["model"] for c in changes]
    last = grown[-1]
    if "compliance" in last["effects"]:
        assert last["effects"]["compliance"]["frequency"] == pytest.approx(15.0, rel=0.1)


def test_continuous_plant_of_a_grown_twin_is_strictly_proper():
    coupled = Compliance(20.0, damping=0.1, measured="motor").modify_plant(
        ContinuousPlant((1.0,), (1.0, 1.0)), 0)
    assert len(coupled.num) < len(coupled.den)
