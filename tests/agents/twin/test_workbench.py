"""Twin workbench: open-loop replay, grey-box fits and the diagnosis of a hidden effect.

Data: closed-loop step experiments of DCMotor-v0 (its PI loop and plant) with one
hidden effect from the catalogue and white sensor noise (``output_noise_std``), so
that there is a noise floor. Records are 2 s long (1001 samples) to keep the tests
quick. Friction and dead zone only show when the speed and the command change
sign, so those data step the reference from -30 to +30 rad/s through zero speed
(a custom ``ClosedLoop`` built from the env's loop); the others use the env's
245 -> 306 rad/s step.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import gbo_envs
from agents.twin.candidates import ORDER_CANDIDATES  # noqa: F401  (registers the envs)
from agents.twin.open_loop import simulate_open_loop
from agents.twin.records import Batch
from agents.twin.static_map import MAP_NAMES
from agents.twin.workbench import compare, diagnose, fit_model, noise_floor, quantization_step, residuals
from gbo_envs.physics import build_effects
from tests.support import loop_records

NOISE = 0.1  # rad/s
GAINS = np.array([[0.3, 1.0], [0.6, 1.5], [0.9, 1.2], [1.05, 2.0], [0.5, 1.9]])

#: effect, its parameters, reference step, experiments
HIDDEN = {
    "saturation": ({"limit": 150.0}, (245.0, 306.0), 4),
    "coulomb_friction": ({"torque": 8.0}, (-30.0, 30.0), 4),
    # 5 experiments: of the first 4, only the slowest loop (Kp 0.3) dwells in the dead band; a refit on the
    # other three moves the width to 0.2 at the same cost, so leave-one-out cannot credit it (a limit of
    # cross-validation over experiments, in diagnose's Notes), and the fifth (Kp 0.5) shows it a second time
    "dead_zone": ({"width": 20.0}, (-30.0, 30.0), 5),
    "time_delay": ({"delay": 0.03}, (245.0, 306.0), 4),
    "drift": ({"rate": -0.06, "parameter": "gain"}, (245.0, 306.0), 5),
}


def _data(effects, step=(245.0, 306.0), n=4, noise=NOISE, seed=0) -> Batch:
    return Batch.from_records(loop_records(effects, gains=GAINS[:n], step=step, noise=noise, seed=seed))


@pytest.fixture(scope="module", params=list(HIDDEN))
def hidden(request):
    name = request.param
    params, step, n = HIDDEN[name]
    data = _data({name: params}, step, n)
    return name, params, data, diagnose(data)


@pytest.mark.slow
def test_diagnose_names_the_hidden_effect(hidden):
    name, params, data, result = hidden
    out = result.to_dict()
    assert out["best"] == name
    assert out["candidates"][0]["effect"] == name
    base = result.current.rmse
    with_effect = result.fits[name].rmse
    noise = out["noise_rmse"]
    assert noise == pytest.approx(NOISE, rel=0.1)  # the noise floor estimate
    assert with_effect <= 0.5 * base  # the error falls by at least half ...
    assert with_effect <= 1.5 * noise  # ... to the noise floor
    assert out["candidates"][0]["rmse"] <= 1.5 * noise  # held out too
    key = next(k for k in params if k != "parameter")
    assert out["candidates"][0]["params"][key] == pytest.approx(params[key], rel=0.1)
    # the improving candidates first (by delta BIC, an effect that explains much more of the residual ahead
    # of one that explains little: agents.twin.ranking.rank), then the rest by delta BIC
    deltas = [c["delta_bic"] for c in out["candidates"] if c["delta_bic"] >= -10.0]
    assert deltas == sorted(deltas)
    assert out["candidates"][0]["delta_bic"] < -10.0
    assert out["candidates"][0]["evidence"]


@pytest.mark.slow
def test_linear_plant_gives_no_best_effect():
    data = _data(None, n=4)
    result = diagnose(data)
    out = result.to_dict()
    assert out["best"] is None
    assert out["rmse"] == pytest.approx(NOISE, rel=0.1)
    assert all(c["rmse"] >= 0.98 * out["heldout_rmse"] for c in out["candidates"])
    assert {c["effect"] for c in out["candidates"]} == set(gbo_envs.physics.EFFECT_NAMES) | set(ORDER_CANDIDATES) | \
        set(MAP_NAMES)


def test_open_loop_replay_reproduces_the_closed_loop_exactly():
    for effects in ({"saturation": {"limit": 140.0}}, {"coulomb_friction": {"torque": 5.0}},
                    {"quantization": {"step": 1.534, "mode": "floor"}}, {"backlash": {"width": 3.0}},
                    {"time_delay": {"delay": 0.013}}):
        data = _data(effects, noise=0.0, n=2)
        env = gym.make("gbo_envs/DCMotor-v0", effects=effects)
        res = simulate_open_loop(env.unwrapped.loop.plant, data.u, data.dt, build_effects(effects), y0=245.0)
        np.testing.assert_allclose(res.y, data.y, atol=1e-6)


def test_open_loop_rows_with_different_blocks_match_single_rows():
    data = _data({"saturation": {"limit": 140.0}}, noise=0.0, n=1)
    env = gym.make("gbo_envs/DCMotor-v0")
    plant = env.unwrapped.loop.plant
    chains = [build_effects({"saturation": {"limit": lim}}) for lim in (130.0, 140.0)]
    chains += [build_effects({"coulomb_friction": {"torque": t}}) for t in (1.0, 2.0)] + [()]
    u = np.repeat(data.u, len(chains), axis=0)
    batch = simulate_open_loop(plant, u, data.dt, chains, y0=245.0)
    for row, chain in enumerate(chains):
        single = simulate_open_loop(plant, data.u, data.dt, chain, y0=245.0)
        np.testing.assert_allclose(batch.y[row], single.y[0], atol=1e-9)
    np.testing.assert_allclose(batch.y[1], data.y[0], atol=1e-6)  # the true limit replays the record


def test_compare_and_residuals_report_where_the_linear_model_fails():
    data = _data({"coulomb_friction": {"torque": 8.0}}, (-30.0, 30.0), n=3)
    linear = fit_model(data)
    res = compare(data, linear)
    assert res.fit_percent.shape == (3,) and np.all(res.fit_percent < 100.0)
    manual = 100 * (1 - np.linalg.norm(data.y[0] - linear.y_sim[0]) / np.linalg.norm(data.y[0] - data.y[0].mean()))
    assert res.fit_percent[0] == pytest.approx(manual)
    ra = residuals(data, linear)
    assert ra.band == pytest.approx(2.58 / np.sqrt(data.n_samples))
    assert not ra.white  # friction leaves a coloured residual
    signs = ra.bins["velocity_sign"]
    assert set(signs["centers"]) >= {-1.0, 1.0}
    assert signs["mean"][0] * signs["mean"][-1] < 0  # the residual changes sign with the velocity
    assert len(ra.worst) == 5 and ra.worst[0]["rms"] >= ra.worst[-1]["rms"]
    fitted = fit_model(data, ["coulomb_friction"])
    assert compare(data, fitted).rmse_all < 0.5 * res.rmse_all


def test_noise_floor_and_quantization_step_from_data():
    data = _data(None, noise=0.2, n=2)
    assert noise_floor(data) == pytest.approx(0.2, rel=0.1)
    quantized = _data({"quantization": {"step": 1.534, "mode": "floor"}}, noise=0.0, n=2)
    step, share = quantization_step(quantized.y, quantized.mask)
    assert step == pytest.approx(1.534, rel=1e-3) and share > 0.95
    assert noise_floor(quantized) == pytest.approx(1.534 / np.sqrt(12), rel=1e-3)
