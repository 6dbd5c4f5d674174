"""The twin's correction and fidelity, learned from the plant records (multi-fidelity BO, issue 17).

Multi-fidelity BO (:class:`agents.mf_bo.MultiFidelityBO`) models the plant as
fidelity ``s = 1`` and the digital twin as ``s = s_twin < 1``. This module learns,
from the plant experiments alone, how the twin's cost maps to the plant's and how
far that mapping can be trusted:

* the correction, ``log J_plant ~ a + b log J_twin``, a least-squares line
  through the pairs (twin cost at the measured gains, measured cost);
* the fidelity ``s_twin``, the leave-one-out explained variance (predictive
  ``R^2``, "Q^2") of that line on the plant costs, clipped to
  ``[0, max_fidelity]``: the share of the plant costs' variance the corrected twin
  predicts for experiments it was not fitted on. It is 0 unless the twin's log
  cost is positively correlated with the plant's at significance ``alpha``
  (one-sided Pearson test): on four or five records a noise twin reaches a high
  ``Q^2`` by chance now and then (seen at 4 records: 0.82).

A twin whose cost is unrelated to the plant's (pure noise) predicts nothing out
of sample, so its ``s_twin`` is near 0 however many records arrive; a twin
whose cost follows the plant's up to a scale and offset gets ``s_twin`` near 1.
Costs are compared as logarithms: they span orders of magnitude (an unstable
loop's cost is large), and the line then corrects a relative bias of the twin.
"""

from __future__ import annotations

import numpy as np

from agents.parameters import Interval, validate_params

__all__ = ["TwinCorrection"]


class TwinCorrection:
    """The line ``log J_plant = a + b log J_twin`` and the twin's fidelity, from plant records.

    Parameters
    ----------
    min_records : int, default 4
        Plant records needed before a fidelity is estimated (``>= 3``); with fewer,
        ``fidelity_`` is 0 and the correction is the identity.
    max_fidelity : float, default 0.95
        Upper bound of ``fidelity_`` in ``(0, 1)``: a twin is never the plant.
    alpha : float, default 0.01
        Significance level in ``(0, 1)`` of the one-sided test that the twin's and the
        plant's log costs are positively correlated; ``fidelity_`` is 0 when it fails.

    Attributes
    ----------
    intercept_ : float
        ``a`` (log cost units).
    slope_ : float
        ``b`` (-).
    fidelity_ : float
        ``s_twin`` in ``[0, max_fidelity]``: the leave-one-out ``R^2`` of the line
        (0 when the correlation is not significantly positive).
    p_value_ : float
        One-sided p-value of the correlation test (1.0 before ``min_records``).
    n_records_ : int
        Plant records the fit used.
    """

    _parameter_constraints: dict[str, list] = {
        "min_records": [Interval(int, 3, None)],
        "max_fidelity": [Interval(float, 0.0, 1.0, closed="neither")],
        "alpha": [Interval(float, 0.0, 1.0, closed="neither")],
    }

    def __init__(self, *, min_records: int = 4, max_fidelity: float = 0.95, alpha: float = 0.01) -> None:
        self.min_records = min_records
        self.max_fidelity = max_fidelity
        self.alpha = alpha

    def fit(self, twin_costs, plant_costs) -> TwinCorrection:
        """Fit the line and estimate the fidelity.

        Parameters
        ----------
        twin_costs : array_like of shape (n,)
            The twin's cost at the gains of each plant experiment (finite, ``> 0``).
        plant_costs : array_like of shape (n,)
            The measured costs of those experiments (finite, ``> 0``).

        Returns
        -------
        TwinCorrection
            ``self``, fitted.
        """
        validate_params(self._parameter_constraints,
                        {"min_records": self.min_records, "max_fidelity": self.max_fidelity, "alpha": self.alpha})
        x, y = _log_costs(twin_costs, "twin_costs"), _log_costs(plant_costs, "plant_costs")
        if x.shape != y.shape:
            raise ValueError(f"twin_costs, plant_costs: expected the same length, got {x.size} and {y.size}")
        self.n_records_ = int(x.size)
        self.intercept_, self.slope_, self.fidelity_, self.p_value_ = 0.0, 1.0, 0.0, 1.0
        if x.size < self.min_records or np.ptp(x) == 0.0 or np.ptp(y) == 0.0:
            return self
        from scipy.stats import pearsonr
        from sklearn.linear_model import LinearRegression
        from sklearn.metrics import r2_score
        from sklearn.model_selection import LeaveOneOut, cross_val_predict

        line = LinearRegression().fit(x[:, None], y)
        self.intercept_, self.slope_ = float(line.intercept_), float(line.coef_[0])
        held_out = cross_val_predict(LinearRegression(), x[:, None], y, cv=LeaveOneOut())
        self.p_value_ = float(pearsonr(x, y, alternative="greater").pvalue)
        q2 = float(r2_score(y, held_out)) if self.p_value_ < self.alpha else 0.0
        self.fidelity_ = float(np.clip(q2, 0.0, self.max_fidelity))
        return self

    def predict_log(self, twin_costs) -> np.ndarray:
        """The corrected twin cost ``a + b log J_twin`` (log cost units), shape (n,)."""
        if not hasattr(self, "fidelity_"):
            raise ValueError("TwinCorrection: call fit(twin_costs, plant_costs) first")
        return self.intercept_ + self.slope_ * _log_costs(twin_costs, "twin_costs")


def _log_costs(costs, name: str) -> np.ndarray:
    values = np.asarray(costs, dtype=float).reshape(-1)
    if not np.all(np.isfinite(values)) or np.any(values <= 0.0):
        raise ValueError(f"{name}: costs must be finite and > 0")
    return np.log(values)
