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

__all__ = ["TWIN_CANDIDATES", "diagnosed_twin", "diagnosed_twins", "measurement_noise"]

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
    twin, rungs, _ = _ladder(records, spec, effects, max_effects, n_samples)
    return twin, rungs


def diagnosed_twins(records: Batch | Sequence, spec: ModelSpec, *, within: float, max_effects: int = 2,
                    n_samples: int | None = 100) -> tuple[GreyBoxTwin, ...]:
    """The ladder's twin (:func:`diagnosed_twin`, from the linear model), then every single-effect twin that also
    replays the records within ``within``.

    Two effects can replay the same records within the noise and still predict different closed loops: on
    LinearMotorCascadeRig-v0 the ladder adds stiction to a Coulomb friction that already replays the records, and
    that twin's cost at the optimum is 1.25 where the plant's is 0.743 (Coulomb alone: 0.737). The records cannot
    tell such twins apart; their costs at the experiments' gains can (:class:`agents.twin_keeper.TwinKeeper`).

    Parameters
    ----------
    records : Batch, or sequence of Experiment or mappings
        As :func:`diagnosed_twin`.
    spec : ModelSpec
        Orders and output kind of the linear part.
    within : float
        The normalised RMSE (of the step height) an alternative must replay the records within: the noise's.
    max_effects : int, default 2
        Effects at most in the ladder's twin.
    n_samples : int, optional
        As :func:`diagnosed_twin`.

    Returns
    -------
    tuple of GreyBoxTwin
        The ladder's twin first; no alternative when the ladder adds no effect (the records evidence none).
    """
    data = as_batch(records, n_samples)
    twin, _, diagnoses = _ladder(data, spec, None, max_effects, n_samples)
    first = diagnoses[0]
    if first.best is None:
        return (twin,)
    alternatives = []
    for name, fit in first.fits.items():
        if name not in TWIN_CANDIDATES or {name} == set(twin.effect_params_ or {}):
            continue
        alternative = GreyBoxTwin.from_fit(fit, data, n_samples=n_samples)
        if alternative.rmse_ <= within:
            alternatives.append(alternative)
    return (twin, *alternatives)


def _ladder(records, spec, effects, max_effects, n_samples):
    """``(twin, rungs, diagnoses)`` of the error ladder on ``records`` from ``effects``."""
    data = as_batch(records, n_samples)
    steps = max(int(max_effects) - len(effects or {}), 0)
    rungs, diagnoses = error_ladder(data, effects=dict(effects or {}), spec=spec, max_steps=steps,
                                    candidates=TWIN_CANDIDATES)
    return GreyBoxTwin.from_fit(diagnoses[-1].current, data, n_samples=n_samples), rungs, diagnoses


def measurement_noise(data: Batch) -> float:
    """White-noise floor of the measured output of a batch of records, in output units
    (:func:`agents.twin.noise_floor.white_noise_floor`: the noise a twin simulates).

    ``0.0`` when it cannot be estimated (too short, or quantized without visible noise and no common step).
    """
    floor = white_noise_floor(data)
    return float(floor) if floor is not None and np.isfinite(floor) else 0.0
