"""The evidence texts of the diagnosis: every pair of catalogue effects gets a separating experiment."""

from __future__ import annotations

import itertools

import pytest

from agents.twin.evidence import SEPARATING_EXPERIMENTS, separating_experiment
from gbo_envs.physics import EFFECT_NAMES

PAIRS = list(itertools.combinations(EFFECT_NAMES, 2))


def test_the_catalogue_has_66_pairs():
    assert len(EFFECT_NAMES) == 12
    assert len(PAIRS) == 66


@pytest.mark.parametrize(("a", "b"), PAIRS, ids=[f"{a}-{b}" for a, b in PAIRS])
def test_separating_experiment_names_both_effects_in_either_order(a, b):
    texts = [separating_experiment(a, b), separating_experiment(b, a)]
    for text in texts:
        assert isinstance(text, str)
        assert a in text and b in text
    assert texts[0] == texts[1] or frozenset({a, b}) not in SEPARATING_EXPERIMENTS


def test_table_entries_are_catalogue_pairs():
    from agents.twin.candidates import ORDER_CANDIDATES

    for key in SEPARATING_EXPERIMENTS:
        assert len(key) == 2 and key <= set(EFFECT_NAMES) | set(ORDER_CANDIDATES)


def test_backlash_is_excited_by_an_input_that_turns_back_without_a_speed_reversal():
    """A PI step response of the DC motor (245 -> 306 rad/s) never reverses the speed, but its command overshoots
    and turns back: the play opens there, so backlash is not an unobservable constant load (friction is)."""
    import gymnasium as gym
    import numpy as np

    import gbo_envs  # noqa: F401  (registers the envs)
    from agents.twin.data import GreyData
    from agents.twin.evidence import excitation_notes

    env = gym.make("gbo_envs/DCMotor-v0", noise=False)
    env.reset(seed=0)
    record = env.step(np.array([0.5, 1.2]))[4]
    notes = excitation_notes(GreyData.from_records([record]), "speed")
    assert "backlash" not in notes
    assert {"coulomb_friction", "stiction"} <= set(notes)
    flat = {**{k: record[k] for k in ("t", "r", "y")}, "u": np.linspace(100.0, 130.0, len(record["t"]))}
    assert "never turns back" in excitation_notes(GreyData.from_records([flat]), "speed")["backlash"]
