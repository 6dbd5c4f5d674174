"""Behaviour fingerprints (:mod:`evaluation.behaviour`): what a plant and a tuner do, blind to the last bits.

A reference is stale when its plant or tuner changed what it does (:mod:`evaluation.references`): the
fingerprint must stay the same for the same numbers (also through a change of their last bits, as a
sum taken in another order makes), and change when the responses or the proposals change.
"""

from __future__ import annotations

import numpy as np
import pytest

from agents.baselines import RandomSearch
from evaluation import behaviour
from gbo_envs.closed_loop import ClosedLoop


@pytest.fixture(autouse=True)
def _fresh():
    behaviour.forget()
    yield
    behaviour.forget()


def _scaled_responses(monkeypatch, factor: float) -> None:
    """Every closed-loop response of the envs multiplied by ``factor``."""
    simulate = ClosedLoop.simulate

    def scaled(self, *args, **kwargs):
        response = simulate(self, *args, **kwargs)
        response.y[...] *= factor
        return response

    monkeypatch.setattr(ClosedLoop, "simulate", scaled)


def test_a_plant_keeps_its_fingerprint_through_its_last_bits_and_loses_it_when_it_responds_otherwise(monkeypatch):
    plain = behaviour.plant_behaviour("gbo_envs/DCMotor-v0")
    assert behaviour.plant_behaviour("gbo_envs/DCMotor-v0", {}) == plain  # computed once, the same
    assert behaviour.plant_behaviour("gbo_envs/DCMotor-v0", {"effects": {"saturation": {"limit": 138.0}}}) != plain
    behaviour.forget()
    _scaled_responses(monkeypatch, 1.0 + 4e-16)  # the last bit of some samples
    assert behaviour.plant_behaviour("gbo_envs/DCMotor-v0") == plain
    behaviour.forget()
    _scaled_responses(monkeypatch, 1.0 + 1e-6)  # another plant
    assert behaviour.plant_behaviour("gbo_envs/DCMotor-v0") != plain


def test_a_time_varying_plant_is_probed_after_its_change(monkeypatch):
    """A step env's change at experiment 15 is within the probe (its first seed runs its whole episode)."""
    before = behaviour.plant_behaviour("gbo_envs/DCMotorStep-v0")
    assert behaviour.plant_behaviour("gbo_envs/DCMotorStep-v0", {"new_params": {"gain": 8.0}}) != before


def test_a_tuner_keeps_its_fingerprint_while_it_proposes_the_same_and_loses_it_when_it_does_not(monkeypatch):
    first = behaviour.tuner_behaviour("random")
    behaviour.forget()
    assert behaviour.tuner_behaviour("random", {}) == first  # the same seed, the same proposals
    ask = RandomSearch.ask

    def every_other(self):
        ask(self)
        return ask(self)

    monkeypatch.setattr(RandomSearch, "ask", every_other)
    behaviour.forget()
    assert behaviour.tuner_behaviour("random") != first


def test_numbers_are_hashed_to_nine_significant_digits():
    assert behaviour._digits([1.0, -2.5e-7, np.inf, np.nan]) == b"1.00000000e+00 -2.50000000e-07 inf nan"
    assert behaviour._digits([1.0 + 1e-15]) == behaviour._digits([1.0])
    assert behaviour._digits([1.0 + 1e-8]) != behaviour._digits([1.0])
