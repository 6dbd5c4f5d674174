"""The twin the data call for: the workbench's error ladder run on a tuner's records, as a fitted grey-box twin.

Guided BO with ``twin="auto"`` (:class:`agents.guided_bo.GuidedBO`) asks this
module which twin to simulate: the linear model, or the linear model plus the
physical effects the records evidence, with the same decision rule as
``gbo twin diagnose`` (:func:`agents.twin.diagnose.diagnose`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from agents.twin.greybox_twin import GreyBoxTwin
from agents.twin.ladder import error_ladder
from agents.twin.model import ModelSpec
from agents.twin.noise_floor import white_noise_floor
from agents.twin.records import Batch, as_batch
from gbo_envs.physics.effects import EFFECTS

__all__ = ["TWIN_CANDIDATES", "diagnosed_twin", "measurement_noise"]

#: Effects a tuning twin is built from: those its closed loop simulates the same at every experiment.
#: Sensor effects are left to the twin's measurement noise (a quantizer with noise in front of it is, in
#: expectation, the identity plus noise of variance ``q^2 / 12``, which the records' noise floor
#: contains), and ``drift`` to eq. (reinit_DTdataset), which restarts the twin data when the plant changes.
TWIN_CANDIDATES = tuple(name for name, cls in EFFECTS.items() if cls.side != "sensor" and name != "drift")


def diagnosed_twin(records: Batch | Sequence, spec: ModelSpec, effects: Mapping | None = None, max_effects: int = 2,
                   n_samples: int | None = 100) -> tuple[GreyBoxTwin, list[dict]]:
    """Diagnose the records and fit the twin with every effect they evidence, up to ``max_effects``.

    The workbench's error ladder (:func:`agents.twin.diagnose.error_ladder`): starting
    from ``effects`` (a previous twin's ``{effect: {parameter: value}}``, which warm-starts
    the fit), the best-ranked effect is added while :func:`~agents.twin.diagnose.diagnose`
    evidences one (held-out delta BIC, gain and effect-size tests). The candidates are
    :data:`TWIN_CANDIDATES`.

    Parameters
    ----------
    records : Batch, or sequence of Experiment or mappings
        Plant experiments with ``t, r, u, y``, or a :class:`~agents.twin.records.Batch` of them stacked with
        ``n_samples`` (:func:`agents.twin.records.as_batch`).
    spec : ModelSpec
        Orders and output kind of the linear part.
    effects : dict, optional
        Effects already in the model, with their values.
    max_effects : int, default 2
        Effects at most in the twin (the ladder's rungs beyond ``effects``).
    n_samples : int, optional
        Uniformly spaced samples kept per record (the paper's ``n~`` of eq. (Ds)), more
        where the command moves within a hold (:func:`agents.twin.records.decimate_records`).

    Returns
    -------
    twin : GreyBoxTwin
        Fitted on the records (its ``effects`` hold the fitted values).
    rungs : list of dict
        The ladder: ``{"model", "added", "rmse", "fit_percent", "heldout_rmse", "params"}`` per rung.
    """
    data = as_batch(records, n_samples)
    steps = max(int(max_effects) - len(effects or {}), 0)
    rungs, diagnoses = error_ladder(data, effects=dict(effects or {}), spec=spec, max_steps=steps,
                                    candidates=TWIN_CANDIDATES)
    return GreyBoxTwin.from_fit(diagnoses[-1].current, data, n_samples=n_samples), rungs


def measurement_noise(data: Batch) -> float:
    """White-noise floor of the measured output of a batch of records, in output units
    (:func:`agents.twin.noise_floor.white_noise_floor`: the noise a twin simulates).

    ``0.0`` when it cannot be estimated (too short, or quantized without visible noise and no common step).
    """
    floor = white_noise_floor(data)
    return float(floor) if floor is not None and np.isfinite(floor) else 0.0
