"""Checks of the records before a grey-box fit: values the fit can square, enough samples, a causal log.

* :func:`check_magnitudes`: every value of ``t, r, u, y`` within :data:`MAX_MAGNITUDE`; beyond it
  the least-squares fit squares values into overflow, and LAPACK fails ("SVD did not converge") after
  printing its own complaint on standard output.
* :func:`check_fit_size`: a model of at most :data:`MAX_POLES` poles, and records long enough for
  it: each record's block of the Jacobian (:class:`agents.twin.jacobian.RecordQR`) has one column
  per shared parameter and per parameter of the record's own, and needs as many samples.
* :func:`warn_if_non_causal`: a :class:`NonCausalRecordWarning` when the output answers the
  input within the same sample. A sampled plant driven through a zero-order hold answers
  ``u[k]`` from ``y[k+1]`` on; a log whose ``y`` was read after ``u`` was applied (one sample
  early) cannot be fitted by any causal model, and its fit is poor or biased without a word.
"""

from __future__ import annotations

import warnings

import numpy as np

__all__ = ["MAX_MAGNITUDE", "MAX_POLES", "NonCausalRecordWarning", "check_fit_size", "check_magnitudes",
           "check_poles", "warn_if_non_causal"]

#: Largest magnitude of a value of ``t, r, u, y``: the fit squares the values (1e150 fitted, 1e200 overflowed).
MAX_MAGNITUDE = 1e100
#: Most poles of the linear part: beyond about 8 the transfer function's coefficients are so ill-conditioned
#: that the fits of the DC motors' records diverge (10 poles: fit -1e12 %), and at 15 LAPACK fails.
MAX_POLES = 8
#: Lags of the input and output differences in the causality test's regression (:func:`same_sample_share`).
CAUSAL_LAGS = 4
#: Share of the causal regression's residual variance that a same-sample term must explain to be warned of.
NON_CAUSAL_SHARE = 0.75
#: Most regression rows the causality test uses (records are taken evenly up to it).
CAUSAL_ROWS = 2**16


class NonCausalRecordWarning(UserWarning):
    """The records' output answers their input within the same sample (see :func:`warn_if_non_causal`)."""


def check_magnitudes(signals: dict, numbers: np.ndarray) -> None:
    """Raise ``ValueError`` naming the experiment and the signal if a value of ``signals`` (``t, r, u, y``,
    each of shape (n_records, n_steps)) is beyond :data:`MAX_MAGNITUDE` in magnitude; ``numbers`` are the
    records' experiment numbers."""
    for name in ("t", "r", "u", "y"):
        values = signals[name]
        big = np.abs(values) > MAX_MAGNITUDE
        if big.any():
            k, i = (int(a[0]) for a in np.nonzero(big))
            raise ValueError(f"records: experiment {int(numbers[k])}, sample {i + 1}, {name} = "
                             f"{values[k, i]:.6g}: values must be within +-{MAX_MAGNITUDE:g} (the fit squares them); "
                             "rescale the data, e.g. into other units")


def check_poles(n_poles: int) -> None:
    """Raise ``ValueError`` unless ``n_poles`` is from 1 to :data:`MAX_POLES`."""
    if not 1 <= n_poles <= MAX_POLES:
        raise ValueError(f"n_poles (--poles): must be an integer from 1 to {MAX_POLES}, got {n_poles}")


def check_fit_size(data, spec, n_effect_params: int = 0) -> None:
    """Raise ``ValueError`` if ``spec`` (a :class:`~agents.twin.model.ModelSpec`) has more than
    :data:`MAX_POLES` poles, or a record of ``data`` fewer samples than the fit has parameters in its
    block: the shared ones (``spec.n_global`` plus ``n_effect_params`` of effects to add) and the
    record's own (rest level, bias and ``spec.n_start`` initial-state parameters)."""
    check_poles(spec.n_poles)
    need = spec.n_global + n_effect_params + 2 + spec.n_start
    lengths = data.mask.sum(axis=1)
    short = np.flatnonzero(lengths < need)
    if short.size:
        k = int(short[0])
        raise ValueError(f"records: experiment {int(data.numbers[k])} has {int(lengths[k])} samples; a fit of "
                         f"{spec.label} with {n_effect_params} effect parameters needs at least {need} per "
                         "experiment (one per parameter: the model's and the experiment's own rest level, bias "
                         "and initial state); record longer experiments or fit fewer poles (--poles)")


def same_sample_share(u: np.ndarray, y: np.ndarray, mask: np.ndarray, lags: int = CAUSAL_LAGS,
                      max_rows: int = CAUSAL_ROWS) -> tuple[float, float]:
    """How much a same-sample term ``du[k] -> dy[k]`` adds to a causal regression of the output's changes.

    The causal regression (ARX in differences, by least squares over the records):
    ``dy[k] ~ dy[k-1..k-L] + du[k-1..k-L]``; the other adds ``du[k]``. ``du, dy`` are the
    sample-to-sample changes of ``u`` and ``y`` within each record (its real samples).

    Returns
    -------
    share : float
        Share of the causal regression's residual variance the same-sample term explains, 0 to 1
        (0 without enough samples or excitation).
    gain : float
        Its coefficient (units of y per unit of u).
    """
    rows, targets = [], []
    n_rows = 0
    records = np.arange(u.shape[0])
    per = max(1, int(mask.sum(axis=1).max()) - lags - 1) if records.size else 1
    step = max(1, int(np.ceil(records.size * per / max_rows)))
    for k in records[::step]:
        m = int(mask[k].sum())
        if m < 3 * lags:
            continue
        du, dy = np.diff(u[k, :m]), np.diff(y[k, :m])
        window = np.lib.stride_tricks.sliding_window_view
        past_y, past_u = window(dy[:-1], lags)[:, ::-1], window(du[:-1], lags)[:, ::-1]
        rows.append(np.column_stack([past_y, past_u, du[lags:]]))
        targets.append(dy[lags:])
        n_rows += targets[-1].size
    if n_rows < 10 * (2 * lags + 1):
        return 0.0, 0.0
    a, b = np.concatenate(rows), np.concatenate(targets)
    scale = np.abs(a).max(axis=0)
    scale[scale == 0.0] = 1.0
    a = a / scale
    causal = b - a[:, :-1] @ np.linalg.lstsq(a[:, :-1], b, rcond=None)[0]
    coef = np.linalg.lstsq(a, b, rcond=None)[0]
    both = b - a @ coef
    left = float(causal @ causal)
    if left <= 0.0:
        return 0.0, 0.0
    return max(0.0, 1.0 - float(both @ both) / left), float(coef[-1] / scale[-1])


def warn_if_non_causal(data) -> None:
    """Warn (:class:`NonCausalRecordWarning`) if the output of the open-loop records of ``data`` (a
    :class:`~agents.twin.records.Batch`) answers the input within the same sample.

    A same-sample term (:func:`same_sample_share`) that explains more than :data:`NON_CAUSAL_SHARE`
    of what the causal regression leaves is warned of, at either sign. Only the open-loop records
    (``r`` equal to ``u``) are tested: in a closed loop the digital controller reads ``y[k]`` to compute
    ``u[k]``, so ``u`` and ``y`` are tied within the sample whatever the log's timing, and the test
    cannot tell a one-sample-early log from the controller (simulated closed loops of DCMotorStep-v0
    gave shares above 0.9 at either sign).
    """
    rows = np.flatnonzero(~np.asarray(data.closed_loop))
    if rows.size:
        share, _ = same_sample_share(data.u[rows], data.y[rows], data.mask[rows])
        if share > NON_CAUSAL_SHARE:
            warnings.warn(
                f"records: the output y answers the input u within the same sample (a term u[k] -> y[k] explains "
                f"{100 * share:.0f} % of what a causal model of the open-loop "
                "experiments leaves); a sampled plant answers u[k] from y[k+1] on, so y was probably logged one "
                "sample early (read after u was applied), and no causal model fits it: move y one sample later "
                "(in the CSV, the y column down one row within each experiment) and load the data again",
                NonCausalRecordWarning, stacklevel=3)
