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
    from agents.twin.evidence import excitation_notes
    from agents.twin.records import Batch

    env = gym.make("gbo_envs/DCMotor-v0", noise=False)
    env.reset(seed=0)
    record = env.step(np.array([0.5, 1.2]))[4]
    notes = excitation_notes(Batch.from_records([record]), "speed")
    assert "backlash" not in notes
    assert {"coulomb_friction", "stiction"} <= set(notes)
    flat = {**{k: record[k] for k in ("t", "r", "y")}, "u": np.linspace(100.0, 130.0, len(record["t"]))}
    assert "never turns back" in excitation_notes(Batch.from_records([flat]), "speed")["backlash"]


def test_a_saturation_that_clips_nothing_says_so_without_a_nan_ratio():
    """A drive limit above every command: no sample on the clipped side, no ratio of errors to give (the
    evidence printed "(nanx the rms elsewhere" on a flexible-coupling rig)."""
    import numpy as np

    from agents.twin.evidence import effect_evidence
    from agents.twin.fits import fit_model
    from agents.twin.records import Batch
    from tests.support import loop_records

    data = Batch.from_records(loop_records({}, gains=np.array([[0.3, 1.0], [0.6, 1.5], [0.9, 1.2]]), noise=0.1,
                                              seed=0))
    current = fit_model(data)
    fit = fit_model(data, {"saturation": {"limit": 1e5}})
    assert fit.effect_params["saturation"]["limit"] > np.abs(data.u).max()
    text = effect_evidence("saturation", data, current, fit)
    assert "nan" not in text and text.startswith("the command never exceeds the fitted limit")
