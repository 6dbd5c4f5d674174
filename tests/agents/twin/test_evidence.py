"""The evidence texts of the diagnosis: every pair of catalogue effects gets a separating experiment."""

from __future__ import annotations

import itertools

import pytest

from agents.twin.evidence import SEPARATING_EXPERIMENTS, separating_experiment
from gbo_envs.physics import EFFECT_NAMES

PAIRS = list(itertools.combinations(EFFECT_NAMES, 2))


def test_the_catalogue_has_55_pairs():
    assert len(EFFECT_NAMES) == 11
    assert len(PAIRS) == 55


@pytest.mark.parametrize(("a", "b"), PAIRS, ids=[f"{a}-{b}" for a, b in PAIRS])
def test_separating_experiment_names_both_effects_in_either_order(a, b):
    texts = [separating_experiment(a, b), separating_experiment(b, a)]
    for text in texts:
        assert isinstance(text, str)
        assert a in text and b in text
    assert texts[0] == texts[1] or frozenset({a, b}) not in SEPARATING_EXPERIMENTS


def test_table_entries_are_catalogue_pairs():
    for key in SEPARATING_EXPERIMENTS:
        assert len(key) == 2 and key <= set(EFFECT_NAMES)
