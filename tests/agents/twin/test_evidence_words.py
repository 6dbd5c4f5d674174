"""The evidence of a candidate says nothing that contradicts itself: no inverse response that "leads", no
resonance with a damping of 2, no period without its unit."""

from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from agents.twin.evidence import effect_evidence, mode_text, zero_text
from agents.twin.fits import fit_model
from agents.twin.records import Batch
from tests.support import loop_records


@pytest.fixture(scope="module")
def data_and_current():
    data = Batch.from_records(loop_records({}, gains=np.array([[0.3, 1.0], [0.9, 1.2]]), duration=0.5, seed=0))
    return data, fit_model(data)


def _with(current, effect: str, params: dict):
    """``current`` as if ``effect`` had been fitted with ``params`` (its output unchanged)."""
    return SimpleNamespace(y_sim=current.y_sim, rmse=current.rmse, spec=current.spec, effect_params={effect: params})


def test_an_overdamped_coupling_is_not_called_a_resonance(data_and_current):
    data, current = data_and_current
    text = effect_evidence("compliance", data, current, _with(current, "compliance",
                                                                {"frequency": 157.0, "damping": 2.0}))
    assert "resonat" not in text and "overdamped (damping 2 >= 1: no resonance)" in text
    light = effect_evidence("compliance", data, current, _with(current, "compliance",
                                                                 {"frequency": 157.0, "damping": 0.05}))
    assert "a flexible coupling resonating at 157 rad/s (25 Hz) with damping 0.05" in light
    assert mode_text("a second mode", 66.7, 0.36) == "a second mode at 66.7 rad/s, damped (damping 0.36)"


def test_an_inverse_response_does_not_lead():
    inverse = zero_text(-0.0194)
    assert "lead" not in inverse and "inverse response (a right-half-plane zero of time constant 0.0194 s)" in inverse
    assert zero_text(0.02) == "the response leads the model: a zero of time constant 0.02 s"


def test_a_cogging_period_has_its_unit(data_and_current):
    data, current = data_and_current
    text = effect_evidence("cogging", data, current, _with(current, "cogging", {"period": 82.39}))
    assert "period 82.39 (units of y times s: the position of a speed loop, rad for y in rad/s)" in text
    position = replace(current, spec=replace(current.spec, output="position"))
    text = effect_evidence("cogging", data, position, _with(position, "cogging", {"period": 0.004}))
    assert "period 0.004 (units of y)" in text
