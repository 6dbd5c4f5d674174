"""Compare a fitted twin with measurements: fit % (NRMSE as MATLAB's ``compare``) and RMSE per experiment."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from agents.twin.fidelity import rmse
from agents.twin.model import GreyFit
from agents.twin.records import Batch

__all__ = ["CompareResult", "compare"]


@dataclass(frozen=True, eq=False)
class CompareResult:
    """Measured against simulated output.

    Attributes
    ----------
    experiments : ndarray of int, shape (n_records,)
        Experiment numbers, counted from 1 (:attr:`Batch.numbers`).
    fit_percent, rmse : ndarray of shape (n_records,)
        ``100 (1 - ||y - y_sim|| / ||y - mean(y)||)`` (MATLAB ``compare``) and RMSE in units of ``y``.
    fit_percent_all, rmse_all : float
        Over all samples of all records (the mean removed per record).
    model : str
    """

    experiments: np.ndarray
    fit_percent: np.ndarray
    rmse: np.ndarray
    fit_percent_all: float
    rmse_all: float
    model: str

    def to_dict(self) -> dict:
        """JSON-ready dict."""
        return {"model": self.model, "fit_percent": self.fit_percent_all, "rmse": self.rmse_all,
                "experiments": [{"experiment": int(e), "fit_percent": float(f), "rmse": float(r)}
                                for e, f, r in zip(self.experiments, self.fit_percent, self.rmse)]}


def compare(data: Batch, fit: GreyFit, experiments: Sequence[int] | None = None) -> CompareResult:
    """Fit % and RMSE of ``fit`` on ``data`` per experiment and overall.

    ``experiments`` labels the records (default :attr:`Batch.numbers`, counted from 1).
    """
    every = bool(data.mask.all())

    def padded_zero(x: np.ndarray) -> np.ndarray:
        """``x`` with 0 on the padding (``x`` itself when nothing is padded: no copy of all samples)."""
        return x if every else np.where(data.mask, x, 0.0)

    # one array of all samples at a time besides the error (the sums as before, so the same values)
    err = padded_zero(data.y - fit.y_sim)
    squares = err**2
    norm_e, total_e = np.sqrt(np.sum(squares, axis=1)), np.sqrt(np.sum(squares))
    mean = np.sum(padded_zero(data.y), axis=1) / data.mask.sum(axis=1)
    squares = padded_zero(data.y - mean[:, None]) ** 2
    norm_d, total_d = np.sqrt(np.sum(squares, axis=1)), np.sqrt(np.sum(squares))
    del squares
    fitp = 100.0 * (1.0 - norm_e / np.where(norm_d > 0, norm_d, np.nan))
    per_record = np.array([rmse(err[k], mask=data.mask[k]) for k in range(data.n_records)])
    all_fit = 100.0 * (1.0 - total_e / max(total_d, 1e-300))
    ids = np.asarray(experiments if experiments is not None else data.numbers, dtype=int)
    return CompareResult(ids, fitp, per_record, float(all_fit), rmse(err, mask=None if every else data.mask),
                         fit.spec.label)
