r"""The twin's correction and fidelity, learned from the plant records (multi-fidelity BO, issue 17).

Multi-fidelity BO (:class:`agents.mf_bo.MultiFidelityBO`) models the plant as
fidelity ``s = 1`` and the digital twin as ``s = s_twin < 1``. This module learns,
from the plant experiments alone, how the twin's cost maps to the plant's and how
far that mapping can be trusted:

* the correction, ``log J_plant ~ a + b log J_twin``, a least-squares line
  through the pairs (twin cost at the measured gains, measured cost), once
  ``min_records`` pairs exist (before, the identity ``a = 0, b = 1``);
* the fidelity ``s_twin`` in ``[0, max_fidelity]``, from two errors of the twin on
  the records:

  - before ``min_records`` records, the twin's *response* error: a record of a few
    hundred samples judges the twin from the first experiment on. With ``e_RMSE``
    the twin's normalised simulation error on the records (eq. (RMSE)) and ``s_n``
    their normalised noise floor (at least ``10^-3``, guided BO's floor),
    ``e_RMSE^2 ~ s_n^2 + e_model^2``, and the fidelity is the share of that error the
    measurement noise explains,

    .. math:: s_{twin} = \min\left(s_{max}, \; s_n^2 / e_{RMSE}^2\right),

    provided the twin's cost at every record's gains is within ``3 sigma_eps`` of the
    measured cost (the cost noise; guided BO's test of a missed cost). A twin whose
    response is right must also get the cost right; one that does not (a twin whose
    cost is noise) gets ``s_twin = 0``;
  - from ``min_records`` records on, the twin's *cost* error: the leave-one-out
    explained variance (predictive ``R^2``, "Q^2") of the line on the plant's log
    costs, the share of their variance the corrected twin predicts for experiments
    it was not fitted on,

    .. math:: s_{twin} = \min\left(s_{max}, \; \max\left(0, \; 1 - \frac{\sum_i (\log J_i -
              \widehat{\log J}_{-i})^2}{\sum_i (\log J_i - \overline{\log J})^2}\right)\right),

    and 0 unless the twin's log cost is positively correlated with the plant's at
    significance ``alpha`` (one-sided Pearson test): on four or five records a noise
    twin reaches a high ``Q^2`` by chance now and then (seen at 4 records: 0.82).

A twin whose cost is unrelated to the plant's (pure noise) predicts nothing out
of sample, so its ``s_twin`` is near 0 however many records arrive; a twin
whose cost follows the plant's up to a scale and offset gets ``s_twin`` near 1.
Costs are compared as logarithms: they span orders of magnitude (an unstable
loop's cost is large), and the line then corrects a relative bias of the twin.
"""

from __future__ import annotations

import numpy as np
from scipy.stats import pearsonr
from sklearn.linear_model import LinearRegression
from sklearn.metrics import r2_score
from sklearn.model_selection import LeaveOneOut, cross_val_predict

from agents.parameters import Interval, validate_params

__all__ = ["TwinCorrection"]


class TwinCorrection:
    """The line ``log J_plant = a + b log J_twin`` and the twin's fidelity, from plant records.

    Parameters
    ----------
    min_records : int, default 4
        Plant records needed before the line is fitted and the fidelity is estimated
        from the cost pairs (``>= 3``); with fewer, the correction is the identity and
        the fidelity comes from the twin's response error (0 if none is given).
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
        ``s_twin`` in ``[0, max_fidelity]``: the noise share of the response error before
        ``min_records``, then the leave-one-out ``R^2`` of the line (0 when the correlation
        is not significantly positive).
    estimate_ : {"none", "response", "costs"}
        What ``fidelity_`` was estimated from.
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

    def fit(self, twin_costs, plant_costs, *, response_rmse: float | None = None, noise_floor: float | None = None,
            cost_noise: float | None = None) -> TwinCorrection:
        """Fit the line and estimate the fidelity.

        Parameters
        ----------
        twin_costs : array_like of shape (n,)
            The twin's cost at the gains of each plant experiment (finite, ``> 0``).
        plant_costs : array_like of shape (n,)
            The measured costs of those experiments (finite, ``> 0``).
        response_rmse : float, optional
            ``e_RMSE``: the twin's simulation error on the plant records, normalised by the
            step height (``>= 0``). With ``noise_floor`` and ``cost_noise``, gives the fidelity
            before ``min_records`` (see the module doc); without, it is 0 then.
        noise_floor : float, optional
            ``s_n``: the records' measurement noise, normalised as ``response_rmse`` (``> 0``).
        cost_noise : float, optional
            ``sigma_eps``: the std of a measured cost, cost units (``> 0``).

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
        self.estimate_ = "none"
        if x.size < self.min_records:
            given = (response_rmse, noise_floor, cost_noise)
            if x.size and all(value is not None for value in given):
                self.fidelity_ = self._response_fidelity(np.exp(x), np.exp(y), *given)
                self.estimate_ = "response"
            return self
        self.estimate_ = "costs"
        if np.ptp(x) == 0.0 or np.ptp(y) == 0.0:
            return self
        line = LinearRegression().fit(x[:, None], y)
        self.intercept_, self.slope_ = float(line.intercept_), float(line.coef_[0])
        held_out = cross_val_predict(LinearRegression(), x[:, None], y, cv=LeaveOneOut())
        self.p_value_ = float(pearsonr(x, y, alternative="greater").pvalue)
        q2 = float(r2_score(y, held_out)) if self.p_value_ < self.alpha else 0.0
        self.fidelity_ = float(np.clip(q2, 0.0, self.max_fidelity))
        return self

    def _response_fidelity(self, twin: np.ndarray, plant: np.ndarray, response_rmse: float, noise_floor: float,
                           cost_noise: float) -> float:
        """``min(s_max, s_n^2 / e_RMSE^2)``, or 0 if a record's cost is more than ``3 sigma_eps`` off the twin's."""
        for name, value, low in (("response_rmse", response_rmse, 0.0), ("noise_floor", noise_floor, None),
                                 ("cost_noise", cost_noise, None)):
            if not np.isfinite(value) or value < 0.0 or (low is None and value == 0.0):
                allowed = ">= 0" if low is not None else "> 0"
                raise ValueError(f"{name}: expected a finite number {allowed}, got {value}")
        if np.any(np.abs(twin - plant) > 3.0 * cost_noise):
            return 0.0  # the twin gets a record's cost wrong beyond the cost noise
        if response_rmse <= noise_floor:
            return float(self.max_fidelity)
        return float(min(self.max_fidelity, (noise_floor / response_rmse) ** 2))

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
