"""The general structures (static maps, grown orders) are fitted only where they could be named (issue 56's speed).

Data as in ``test_diagnose_fast``: closed-loop step experiments of DCMotor-v0 (2 s, 1001 samples).
"""

from __future__ import annotations

import numpy as np
import pytest

import gbo_envs  # noqa: F401  (registers the envs)
from agents.twin.candidates import Candidate, OrderCandidate
from agents.twin.diagnose import general_needed
from agents.twin.fits import fit_model
from agents.twin.ranking import SHARE_POINTS, Ranking, heldout_rss
from agents.twin.records import Batch
from agents.twin.workbench import CandidateSearch, diagnose
from tests.support import loop_records

GAINS = np.array([[0.3, 1.0], [0.6, 1.5], [0.9, 1.2], [1.05, 2.0]])
GENERAL = [OrderCandidate("pole_pair", 2, 0), OrderCandidate("pole", 1, 0), Candidate("input_map"),
           Candidate("output_map")]


def _data(effects, n=4) -> Batch:
    return Batch.from_records(loop_records(effects, gains=GAINS[:n], step=(245.0, 306.0), noise=0.1, seed=0))


def _ranking(best: str | None, share: float) -> Ranking:
    candidates = [{"effect": "saturation", "kind": "effect", "share": share}]
    return Ranking(candidates, best, 1.0, "held-out", [], None)


@pytest.mark.parametrize(("best", "share", "needed"), [
    (None, 0.0, ["pole_pair", "pole", "input_map", "output_map"]),  # no effect selected: every structure
    ("saturation", 100.0 - SHARE_POINTS, ["input_map", "output_map"]),  # a map may still explain 10 points more
    ("saturation", 100.0 - SHARE_POINTS + 1e-9, []),  # no map can: nothing left to fit
])
def test_the_general_structures_are_needed_only_where_they_could_be_named(best, share, needed):
    assert [c.name for c in general_needed(_ranking(best, share), GENERAL)] == needed


@pytest.mark.slow
def test_an_effect_that_explains_the_residual_leaves_the_maps_and_orders_unfitted_and_changes_nothing_else():
    data = _data({"saturation": {"limit": 150.0}})
    quick = diagnose(data)
    full = diagnose(data, search=CandidateSearch(general_as_fallback=False))
    assert quick.best == full.best == "saturation"
    kinds = {c["kind"] for c in quick.candidates}
    assert kinds == {"effect"} and {"order", "map"} <= {c["kind"] for c in full.candidates}
    assert all(name in quick.not_tried for name in ("pole_pair", "input_map", "output_map"))
    assert full.not_tried is None and quick.to_dict()["not_tried"] == quick.not_tried
    # the effects' fits and ranking entries are those of the diagnosis that fits every structure
    ranked = {c["effect"]: c for c in full.candidates}
    assert all(c == ranked[c["effect"]] for c in quick.candidates)
    assert quick.heldout_rmse == full.heldout_rmse


@pytest.mark.slow
def test_without_a_selected_effect_every_structure_is_fitted_as_before():
    data = _data({"compliance": {"frequency": 15.0, "damping": 0.1}}, n=3)
    quick = diagnose(data, candidates=["offset"])  # no effect fitted (records that start moving cannot show an offset)
    full = diagnose(data, candidates=["offset"], search=CandidateSearch(general_as_fallback=False))
    assert quick.not_tried is None
    assert quick.to_dict() == full.to_dict()


def test_models_cross_validated_already_are_not_refitted_and_keep_their_values(monkeypatch):
    from agents.twin import ranking

    data = _data({"saturation": {"limit": 150.0}}, n=3)
    linear = fit_model(data)
    saturated = fit_model(data, effects={"saturation": {"limit": 150.0}})
    together = heldout_rss(data, [linear, saturated], n_folds=3, refits={})
    known: dict = {}
    first = heldout_rss(data, [linear], n_folds=3, refits={}, known=known)
    cross_validated = []
    fold_costs = ranking._fold_costs
    monkeypatch.setattr(ranking, "_fold_costs",
                        lambda d, fits, *a: cross_validated.append(fits) or fold_costs(d, fits, *a))
    second = heldout_rss(data, [linear, saturated], n_folds=3, refits={}, known=known)
    assert cross_validated == [[saturated]]  # the linear model's folds are not refitted
    assert first[0] == together[0] and np.array_equal(second, together)
    assert set(known) == {id(linear), id(saturated)}
