"""Compare a fitted twin with measurements: fit % (NRMSE as MATLAB's ``compare``) and RMSE per experiment."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from agents.twin.fidelity import rmse
from agents.twin.greybox import GreyData, GreyFit

__all__ = ["CompareResult", "compare"]


@dataclass(frozen=True, eq=False)
class CompareResult:
    """Measured against simulated output.

    Attributes
    ----------
    experiments : ndarray of int, shape (n_records,)
        Experiment numbers, counted from 1 (:attr:`GreyData.numbers`).
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


def compare(data: GreyData, fit: GreyFit, experiments: Sequence[int] | None = None) -> CompareResult:
    """Fit % and RMSE of ``fit`` on ``data`` per experiment and overall.

    ``experiments`` labels the records (default :attr:`GreyData.numbers`, counted from 1).
    """
    err = np.where(data.mask, data.y - fit.y_sim, 0.0)
    mean = np.sum(np.where(data.mask, data.y, 0.0), axis=1) / data.mask.sum(axis=1)
    dev = np.where(data.mask, data.y - mean[:, None], 0.0)
    norm_e = np.sqrt(np.sum(err**2, axis=1))
    norm_d = np.sqrt(np.sum(dev**2, axis=1))
    fitp = 100.0 * (1.0 - norm_e / np.where(norm_d > 0, norm_d, np.nan))
    per_record = np.array([rmse(err[k], mask=data.mask[k]) for k in range(data.n_records)])
    all_fit = 100.0 * (1.0 - np.sqrt(np.sum(err**2)) / max(np.sqrt(np.sum(dev**2)), 1e-300))
    ids = np.asarray(experiments if experiments is not None else data.numbers, dtype=int)
    return CompareResult(ids, fitp, per_record, float(all_fit), rmse(err, mask=data.mask), fit.spec.label)
