"""Resonances from short records, the stop rule far from the noise floor, and friction on cascade records
(issue 56 points 3-4, issue 54's diagnosis on cascade records)."""

from __future__ import annotations

from types import SimpleNamespace

import gymnasium as gym
import numpy as np
import pytest

import gbo_envs  # noqa: F401  (registers the envs)
from agents.twin.diagnose import diagnose
from agents.twin.diagnosis_options import CandidateSearch
from agents.twin.evidence import excitation_notes, mode_text
from agents.twin.fits import fit_model, fit_structure
from agents.twin.guesses import effect_starts, residual_frequencies
from agents.twin.ladder_text import advice
from agents.twin.model import ModelSpec
from agents.twin.modes import RESONANCE_DAMPING, plant_modes
from agents.twin.noise_floor import noise_floor_estimate
from agents.twin.ranking import _failed_rule
from agents.twin.records import Batch
from agents.twin.residual_shape import residual_shape
from benchmarks.real_like_sets import FLEX_MODE, flexible_load_closed_records, flexible_load_open_records

BEAM = FLEX_MODE["frequency"]  # rad/s, 2.3 Hz


@pytest.fixture(scope="module")
def beam_open():
    """Six 1 s open-loop steps of the flexible-beam motor (4 ms) and their linear fit."""
    data = Batch.from_records(flexible_load_open_records())
    return data, fit_structure(data)


@pytest.fixture(scope="module")
def beam_closed():
    """The flexible-beam motor under PI steps and swept sines (4 s at 2 ms) and its linear fit."""
    data = Batch.from_records(flexible_load_closed_records())
    return data, fit_structure(data)


@pytest.mark.parametrize("which", ["beam_open", "beam_closed"])
def test_the_mode_is_found_in_the_plant_from_short_records(which, request):
    """Two periods of a 2.3 Hz mode per 1 s record: the periodogram's peaks are elsewhere, the plant input
    filtered through a resonance finds the mode within 3 %; in the closed loop the plant's mode (14.45 rad/s),
    not the loop's (13-14 rad/s)."""
    data, linear = request.getfixturevalue(which)
    modes = plant_modes(data, linear)
    assert modes and modes[0].frequency == pytest.approx(BEAM, rel=0.03)
    assert modes[0].share > 50.0
    assert all(abs(w / BEAM - 1.0) > 0.1 for w in residual_frequencies(data, linear, n_peaks=1))


def test_compliance_starts_at_the_mode_with_a_resonance_damping(beam_open):
    data, linear = beam_open
    starts, lower, upper, _ = effect_starts("compliance", data, linear)
    assert lower[1] == RESONANCE_DAMPING[0] and upper[1] == RESONANCE_DAMPING[1]
    assert any(abs(s[0] / BEAM - 1.0) < 0.03 for s in starts)


def test_self_contradicting_modes_are_not_named():
    """A pair with damping 0.0025 is no resonance: not called one, and a grown pole pair there fails the rules."""
    assert "resonat" not in mode_text("a second mode", 220.0, 0.0025)
    candidate = {"effect": "pole_pair", "kind": "order", "fitted": True, "delta_bic": -50.0, "rmse": 0.5,
                 "train_rmse": 0.5, "effect_rms": 1.0, "params": {"frequency": 220.0, "damping": 0.0025}}
    assert _failed_rule(candidate, 1.0, 1.0, 0.01, 6, 10.0, 0.02, 0.05).startswith("its mode is no resonance")
    candidate["params"]["damping"] = 0.05
    assert _failed_rule(candidate, 1.0, 1.0, 0.01, 6, 10.0, 0.02, 0.05) is None


def test_far_from_the_floor_the_advice_describes_the_residual(beam_open):
    """No candidate passes at 16x the noise floor: the advice gives the residual's spectral peak in Hz, the plant
    mode, its correlations with u, y and dy/dt and the general candidates tried, instead of a bare stop."""
    data, linear = beam_open
    shape = residual_shape(data, linear)
    assert shape["mode"]["hertz"] == pytest.approx(2.3, rel=0.03)
    assert all(-1.0 <= shape[k] <= 1.0 for k in ("corr_u", "corr_y", "corr_dy"))
    diagnosis = SimpleNamespace(best=None, current=linear, noise_rmse=0.2, indistinguishable=[], unobservable=[],
                                suggested_experiment=None, data_=data,
                                candidates=[{"effect": "pole_pair", "kind": "order", "share": 3.0,
                                             "verdict": "held-out gain under 2 %"},
                                            {"effect": "saturation", "kind": "effect", "share": 0.0,
                                             "verdict": "delta BIC not below -10"}])
    text = advice(diagnosis, [], "beam.csv")
    assert not text.startswith("stop")
    assert "not at the noise floor" in text and "spectrum peaks at" in text and "a mode at 2.3" in text
    assert "correlates with u (r=" in text and "dy/dt (r=" in text
    assert "general candidates tried: pole pair (held-out gain under 2 %" in text and "saturation" not in text
    near = SimpleNamespace(**{**vars(diagnosis), "noise_rmse": linear.rmse / 2.0})
    assert advice(near, [], "beam.csv").startswith("stop adding catalogue effects")


def test_the_beam_is_fitted_from_short_open_loop_steps(beam_open):
    """Six 1 s steps: the coupling started at the plant's mode with the linear part profiled under it reaches the
    noise floor (from the 2-pole fit's linear part it stopped at twice the floor, damping 0.014 for 0.03)."""
    data, linear = beam_open
    fit = fit_model(data, {"compliance": {"measured": "motor"}}, base=linear)
    params = fit.effect_params["compliance"]
    assert params["frequency"] == pytest.approx(BEAM, rel=0.03)
    assert params["damping"] == pytest.approx(FLEX_MODE["damping"], rel=0.3)
    assert fit.rmse <= 0.6 * linear.rmse and fit.rmse <= 1.5 * noise_floor_estimate(data).rmse


@pytest.mark.slow
def test_the_beam_is_named_from_closed_loop_records(beam_closed):
    """Closed-loop steps and sines: the coupling seen from the motor, at the plant's 2.3 Hz, cuts the RMSE by at
    least 40 % to within 1.5 noise floors."""
    data, linear = beam_closed
    d = diagnose(data, current=linear, candidates=["compliance", "time_delay", "saturation"])
    assert d.best == "compliance"
    fit = d.fits["compliance"]
    assert fit.effect_params["compliance"]["frequency"] == pytest.approx(BEAM, rel=0.03)
    assert fit.rmse <= 0.6 * linear.rmse and fit.rmse <= 1.5 * d.noise_rmse


def _cascade_rig_data(n: int = 8) -> Batch:
    env = gym.make("gbo_envs/LinearMotorCascadeRig-v0")
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    gains = rng.uniform(env.action_space.low, env.action_space.high, size=(n, 4))
    return Batch.from_records([env.step(g)[4]["experiment"] for g in gains])


def test_friction_on_cascade_records_is_named():
    """LinearMotorCascadeRig-v0 (position P, speed PI, velocity feed-forward; 0.5 A guide friction): the slider
    sticks short of its target, so friction is observable although no record reverses or shows its rest, and
    it is named with its level, where a 0.97 A dead zone of the current was named before."""
    data = _cascade_rig_data()
    assert "coulomb_friction" not in excitation_notes(data, "position")
    d = diagnose(data, spec=ModelSpec(2, 0, 1, "position"), candidates=["coulomb_friction", "dead_zone"],
                 search=CandidateSearch(orders=False))
    assert d.best == "coulomb_friction"
    assert d.fits["coulomb_friction"].effect_params["coulomb_friction"]["torque"] == pytest.approx(0.5, rel=0.05)
    assert d.fits["coulomb_friction"].rmse < 0.2 * d.current.rmse


def test_a_diagnosis_scans_each_model_for_modes_once(monkeypatch):
    """The candidates' variants and starts, their evidence and the stop advice read the plant's modes of one
    model: each model a diagnosis looks at is scanned once (:func:`plant_modes` wherever it is imported), and the
    modes the diagnosis keeps are its current model's."""
    import sys

    from agents.twin import modes as modes_module
    from tests.support import loop_records

    scanned = []

    def counted(data, fit, *args, **kwargs):
        scanned.append(fit.y_sim.tobytes())
        return original(data, fit, *args, **kwargs)

    original = modes_module.plant_modes
    for module in [m for name, m in sys.modules.items() if name.startswith("agents.")]:
        if getattr(module, "plant_modes", None) is original:
            monkeypatch.setattr(module, "plant_modes", counted)
    records = loop_records({"compliance": {"frequency": 15.0, "damping": 0.1}}, gains=[[0.3, 1.0], [0.6, 1.5],
                                                                                        [0.9, 1.2]], duration=1.0)
    data = Batch.from_records(records)
    d = diagnose(data, candidates=["compliance", "offset"])
    advice(d, d.current.spec.effect_names, "data.csv")
    assert scanned and len(scanned) == len(set(scanned))  # no model scanned twice
    assert d.modes == tuple(original(data, d.current))


def test_the_mode_scan_filters_as_scipy_does_without_importing_scipy_signal():
    """The mode scan's Tustin filters give ``scipy.signal.lfilter``'s numbers bit for bit, and the scan (run
    in the parent before the workers fork) does not import scipy.signal, 0.5 s of every diagnosis."""
    import subprocess
    import sys

    code = ("import sys, numpy as np; from agents.twin.diagnose import diagnose; from agents.twin.modes import "
            "_mode_response; _mode_response(np.ones((2, 50)), 10.0, 0.1, 0.01); print('scipy.signal' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
    from scipy.signal import lfilter

    from agents.twin.modes import _mode_response

    u = np.random.default_rng(0).normal(size=(3, 400)).cumsum(axis=1)
    w, zeta, dt = 14.5, 0.03, 0.004
    c = w / np.tan(w * dt / 2.0)
    den = np.array([c * c + 2 * zeta * w * c + w * w, 2 * (w * w - c * c), c * c - 2 * zeta * w * c + w * w])
    low, band = _mode_response(u, w, zeta, dt)
    np.testing.assert_array_equal(low, lfilter(w * w * np.array([1.0, 2.0, 1.0]) / den[0], den / den[0], u, axis=1))
    np.testing.assert_array_equal(band, lfilter(w * c * np.array([1.0, 0.0, -1.0]) / den[0], den / den[0], u, axis=1))
