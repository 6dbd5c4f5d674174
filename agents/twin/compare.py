"""Compare a fitted twin with measurements: fit % (NRMSE as MATLAB's ``compare``) and RMSE per experiment."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from agents.twin.fidelity import rmse
from agents.twin.model import GreyFit, ModelSpec, output_error
from agents.twin.records import Batch

__all__ = ["CompareResult", "compare", "error_figures"]


@dataclass(frozen=True, eq=False)
class CompareResult:
    """Measured against simulated output.

    Attributes
    ----------
    experiments : ndarray of int, shape (n_records,)
        Experiment numbers, counted from 1 (:attr:`Batch.numbers`).
    fit_percent, rmse : ndarray of shape (n_records,)
        ``100 (1 - ||y - y_sim|| / ||y - mean(y)||)`` (MATLAB ``compare``) and RMSE in units of ``y``, from
        one residual (:func:`error_figures`: for a closed-loop position record, on the increments).
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
    """Fit % and RMSE of ``fit`` on ``data`` per experiment and overall (:func:`error_figures`).

    ``experiments`` labels the records (default :attr:`Batch.numbers`, counted from 1).
    """
    fitp, per_record, all_fit, all_rmse = error_figures(data, fit.y_sim, fit.spec)
    ids = np.asarray(experiments if experiments is not None else data.numbers, dtype=int)
    return CompareResult(ids, fitp, per_record, all_fit, all_rmse, fit.spec.label)


def error_figures(data: Batch, y_sim: np.ndarray, spec: ModelSpec) -> tuple[np.ndarray, np.ndarray, float, float]:
    """Fit % and RMSE of the simulated output ``y_sim`` on ``data``, both from one residual.

    The residual is the error every RMSE of a grey-box fit is taken on (:func:`agents.twin.model.output_error`:
    ``y - y_sim``, on its increments for a closed-loop position record), and the fit's normaliser is the
    data's deviation from each record's mean taken the same way, so that over the same samples
    ``fit = 100 (1 - RMSE sqrt(N) / ||y - mean(y)||)``: on given data the RMSE falls exactly where the fit rises.

    Parameters
    ----------
    data : Batch
    y_sim : ndarray of shape (n_records, n_steps)
        Simulated output, units of ``y``.
    spec : ModelSpec
        The model's structure (its ``output`` says how the error is taken).

    Returns
    -------
    fit_percent, rmse : ndarray of shape (n_records,)
        Per record: ``100 (1 - ||e|| / ||d||)`` (NaN for a record without deviation) and the RMSE (units of ``y``).
    fit_percent_all, rmse_all : float
        Over all real samples of all records.
    """
    mask = data.mask
    err = output_error(data.y, y_sim, mask, spec, data.closed_loop)
    mean = np.sum(np.where(mask, data.y, 0.0), axis=1) / mask.sum(axis=1)
    dev = output_error(data.y, np.broadcast_to(mean[:, None], data.y.shape), mask, spec, data.closed_loop)
    norm_e, norm_d = np.sqrt(np.sum(err**2, axis=1)), np.sqrt(np.sum(dev**2, axis=1))
    fitp = 100.0 * (1.0 - norm_e / np.where(norm_d > 0, norm_d, np.nan))
    per_record = np.array([rmse(err[k], mask=mask[k]) for k in range(data.n_records)])
    total_e, total_d = float(np.sqrt(np.sum(norm_e**2))), float(np.sqrt(np.sum(norm_d**2)))
    return fitp, per_record, float(100.0 * (1.0 - total_e / max(total_d, 1e-300))), rmse(err, mask=mask)
