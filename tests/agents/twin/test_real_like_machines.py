"""The workbench on records like issue 56's machines (generators in :mod:`benchmarks.real_like_sets`)."""

from __future__ import annotations

import numpy as np
import pytest

from agents.twin import ranking
from agents.twin.diagnose import diagnose
from agents.twin.evidence import excitation_notes
from agents.twin.fits import fit_structure
from agents.twin.noise_floor import noise_floor_estimate, quantization_step
from agents.twin.ranking import heldout_rss
from agents.twin.records import Batch
from benchmarks.real_like_sets import RIG_QUANTUM, foc_staircase_records, speed_rig_records
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


@pytest.fixture(scope="module")
def speed_rig():
    """The speed rig (25 rpm quantum, 40 ms dead time, PID steps) and its linear and dead-time fits."""
    data = Batch.from_records(speed_rig_records())
    return data, fit_structure(data), fit_structure(data, "time_delay")


def test_speed_rig_noise_floor_takes_the_quantum(speed_rig):
    """A quantized output whose levels jitter with the logger's timer: the floor is at least q / sqrt(12)."""
    data = speed_rig[0]
    noise = noise_floor_estimate(data)
    assert noise.quantum == pytest.approx(RIG_QUANTUM, rel=0.03)
    assert noise.rmse >= noise.quantum / np.sqrt(12.0)
    assert noise.method == "quantization"


def test_continuous_noise_is_not_a_quantum():
    """A smooth signal with white noise has no quantum (the jitter rule wants an empty gap below the step)."""
    rng = np.random.default_rng(3)
    y = np.cumsum(rng.standard_normal((4, 500)), axis=1) + 0.3 * rng.standard_normal((4, 500))
    assert quantization_step(y, jitter=True)[0] is None


def test_failed_fold_refit_is_redone_from_the_all_data_parameters(speed_rig, monkeypatch):
    """A dead time that explains most of the residual but whose refit on a fold slid away (here: pushed to
    0 s) is predicted on that fold from its all-data parameters, and the ranking's data say so."""
    data, linear, delayed = speed_rig
    assert 100.0 * (1.0 - delayed.rmse**2 / linear.rmse**2) > ranking.REFIT_SHARE
    keep = ranking._keep_undetermined

    def failing(data_, train, fits):
        keep(data_, train, fits)
        for p in train:
            if p.tag == (1, 0):  # the dead-time model's refit without fold 0's experiments
                p.theta[p.spec.n_linear + 1] = 0.0
    monkeypatch.setattr(ranking, "_keep_undetermined", failing)
    silent = heldout_rss(data, [linear, delayed])
    refits = {}
    guarded = heldout_rss(data, [linear, delayed], refits=refits)
    assert [f for f, *_ in refits[1]] == [0] and 0 not in refits
    failed, redone, reference = refits[1][0][1:]
    assert failed > ranking.REFIT_RATIO * reference and redone < failed
    assert guarded[1] < silent[1] and guarded[0] == silent[0]
    assert guarded[1] < guarded[0]  # the dead time predicts the held-out experiments better than the linear model
    note = ranking._refit_note(refits[1], 4)
    assert "fold 1 of 4 refitted from the all-data parameters" in note


def test_speed_rig_dead_time_named_with_the_refit_note(speed_rig, monkeypatch):
    """End to end: with the dead time's refit on one fold failing, the diagnosis still names the dead time,
    and its row in the ranking says that fold was refitted from the all-data parameters."""
    keep = ranking._keep_undetermined

    def failing(data_, train, fits):
        keep(data_, train, fits)
        for p in train:
            if p.tag[1] == 0 and "time_delay" in p.spec.effect_names:  # the dead time's refit without fold 1
                p.theta[p.spec.n_linear + 1] = 0.0
    monkeypatch.setattr(ranking, "_keep_undetermined", failing)
    diagnosis = diagnose(speed_rig[0], candidates=["time_delay", "compliance"])
    assert diagnosis.best == "time_delay"
    row = next(c for c in diagnosis.candidates if c["effect"] == "time_delay")
    assert "fold 1 of 4 refitted from the all-data parameters" in row["note"]
