"""The workbench on records like issue 56's machines (generators in :mod:`benchmarks.real_like_sets`)."""

from __future__ import annotations

import numpy as np

from agents.twin.evidence import excitation_notes
from agents.twin.records import Batch
from benchmarks.real_like_sets import foc_staircase_records
from gbo_envs import Experiment


def test_foc_staircase_from_standstill_starts_at_rest_and_shows_friction():
    """Speed 0 at t = 0 with the current on from the first sample: a start at rest, so friction is observable."""
    data = Batch.from_records(foc_staircase_records())
    assert np.all(data.initial.mode == "rest")
    assert np.all(data.initial.assumed) and np.all(data.initial.u0 == 0.0)
    notes = excitation_notes(data, "speed")
    assert "coulomb_friction" not in notes and "offset" not in notes


def test_record_cut_while_moving_stays_moving():
    """The same staircase logged from its second step on (moving at the first sample) is not taken at rest."""
    cut = slice(52, None)  # 20 ms into the second stair: the speed climbs, far from zero
    records = [Experiment(gains=(), t=rec.t[cut] - rec.t[52], r=rec.r[cut], u=rec.u[cut], y=rec.y[cut], index=k)
               for k, rec in enumerate(foc_staircase_records(n_records=2))]
    data = Batch.from_records(records)
    assert np.all(data.initial.mode == "moving")
