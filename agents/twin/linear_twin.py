"""The paper's linear digital twin as a scikit-learn estimator: a continuous transfer function with delay by SRIVC."""

from __future__ import annotations

from typing import ClassVar

import numpy as np
from sklearn.utils.validation import check_is_fitted

from agents.parameters import Boolean, Options
from agents.thread_limits import single_thread
from agents.twin import srivc
from agents.twin.estimator import TwinEstimator
from agents.twin.identify import (
    IdentifyOptions,
    check_orders,
    identify,
    linear_constraints,
    prepare_signals,
    simulation_error,
)
from agents.twin.records import Batch

__all__ = ["LinearTwin"]


class LinearTwin(TwinEstimator):
    r"""The DT plant ``G_tilde`` of the paper (subsec. Digital Twin): a transfer function with delay, by SRIVC.

    ``fit`` runs :func:`agents.twin.identify.identify_linear` (SRIVC at each delay of a
    grid, the best delay refined by a bounded scalar search) on closed-loop step
    records; ``predict`` replays records' inputs through the fitted plant;
    ``score`` is the negative eq. (RMSE) normalised by the step height.

    Parameters
    ----------
    n_poles, n_zeros, n_integrators, delay, max_delay, delay_step, refine_delay, offset, n_samples, hold, \
oversample, max_iter, tol, svf_bandwidth, polish
        As in :func:`agents.twin.identify.identify_linear` (same defaults and allowed ranges).
    output : {"speed", "position"}, default "speed"
        What ``y`` measures; copied to :attr:`plant_`.
    warm_start : bool, default False
        Refit from the previous solution: SRIVC starts at the last parameters
        and the delay grid shrinks to the last delay +- 2 grid steps (much
        faster when records are added one by one, as in guided BO).

    Attributes
    ----------
    plant_ : gbo_envs.ContinuousPlant
        Identified plant ``G_tilde(s) = num_/den_ e^{-s delay_}``.
    num_, den_ : ndarray of shape (n_zeros + 1,), (n_poles + 1,)
        Coefficients, highest power first; ``den_`` is monic.
    params_ : ndarray of shape (n_zeros + 1 + n_poles - n_integrators,)
        ``[b_0 .. b_m, a_1 .. a_{n-k}]``; for the DC motor ``(L, tau1, tau2)``.
    param_names_ : tuple of str
        Names of ``params_``.
    delay_ : float
        Input delay in s.
    rmse_ : float
        Eq. (RMSE) on the fitted data, normalised by the step height: the RMS over
        all samples of all records of ``(y - y_sim) / |r2 - y0|``, dimensionless.
    rmse_abs_ : float
        The same without normalisation, in the units of ``y``.
    rest_levels_ : ndarray of shape (n_records, 2)
        Estimated ``(y0, u0)`` of each fitted record.
    n_iter_ : int
        SRIVC iterations at the chosen delay.
    converged_ : bool
        Whether SRIVC met ``tol`` at the chosen delay.
    delay_grid_, delay_rmse_ : ndarray of shape (n_delays,)
        Delays tried (s) and their normalised RMSE.
    n_records_, n_samples_ : int
        Records fitted and samples per record used (after decimation; the longest).
    dt_ : float
        Sample time of the fitted data in s.

    Examples
    --------
    >>> import gymnasium as gym, numpy as np, gbo_envs
    >>> env = gym.make("gbo_envs/DCMotor-v0", noise=False)
    >>> _ = env.reset(seed=0)
    >>> info = env.step(np.array([0.5, 1.2]))[4]
    >>> twin = LinearTwin().fit([info])
    >>> bool(np.allclose(twin.params_, (9.544, 4.145, 4.199), rtol=1e-3))
    True
    """

    _parameter_constraints: ClassVar[dict[str, list]] = {**linear_constraints(),
                                                          "output": [Options(("speed", "position"))],
                                                          "warm_start": [Boolean()]}

    def __init__(self, *, n_poles: int = 2, n_zeros: int = 0, n_integrators: int = 0, delay: float | None = None,
                 max_delay: float | None = None, delay_step: float | None = None, refine_delay: bool = True,
                 offset: bool = True, n_samples: int | None = None, hold: str = "auto", oversample: int = 10,
                 max_iter: int = 50, tol: float = 1e-8, svf_bandwidth: float | None = None, output: str = "speed",
                 warm_start: bool = False, polish: bool = False) -> None:
        self.n_poles = n_poles
        self.n_zeros = n_zeros
        self.n_integrators = n_integrators
        self.delay = delay
        self.max_delay = max_delay
        self.delay_step = delay_step
        self.refine_delay = refine_delay
        self.offset = offset
        self.n_samples = n_samples
        self.hold = hold
        self.oversample = oversample
        self.max_iter = max_iter
        self.tol = tol
        self.svf_bandwidth = svf_bandwidth
        self.output = output
        self.warm_start = warm_start
        self.polish = polish

    def fit(self, records, y=None) -> LinearTwin:
        """Identify the plant from closed-loop step records.

        Parameters
        ----------
        records : mapping, sequence of mappings or of arrays (n_steps, 4), or DataFrame
            Experiment records with ``t, r, u, y`` (see :func:`agents.twin.records.as_records`).
        y : None
            Ignored (scikit-learn signature).

        Returns
        -------
        self

        Raises
        ------
        ValueError
            A parameter outside its allowed range (named), or bad records.
        """
        params = self._validate_params()
        orders = check_orders(params["n_poles"], params["n_zeros"], params["n_integrators"])
        options = IdentifyOptions(**{name: params[name] for name in linear_constraints()})
        with single_thread():  # tiny matrices: BLAS threads only contend
            fit = identify(_batch(records), options, start=self._warm_start_point(orders))
        self.num_ = fit.num
        self.den_ = fit.den
        self.params_ = fit.params
        self.param_names_ = fit.param_names
        self.delay_ = fit.delay
        self.plant_ = fit.plant(params["output"])
        self.rmse_ = fit.rmse
        self.rmse_abs_ = fit.rmse_abs
        self.rest_levels_ = fit.rest_levels
        self.n_iter_ = fit.n_iter
        self.converged_ = fit.converged
        self.delay_grid_ = fit.delay_grid
        self.delay_rmse_ = fit.delay_rmse
        self.n_records_ = fit.n_records
        self.n_samples_ = fit.n_samples
        self.dt_ = fit.dt
        return self

    def predict(self, records) -> list[np.ndarray]:
        """Simulated output of the fitted plant driven by each record's ``u``.

        Each record's rest levels ``(y0, u0)`` are re-estimated (``offset=True``).
        Records are decimated like the training data.

        Returns
        -------
        list of ndarray of shape (n_steps,)
            ``y_sim`` in the units of ``y`` at the (decimated) sample times.
        """
        orders, signals, groups = self._prepared(records)
        out: list[np.ndarray | None] = [None] * sum(rows.size for rows in groups)
        for rows, sig in zip(groups, signals):
            y_sim = srivc.simulate(orders, self._theta(orders), self.delay_, sig, self.offset)[0]
            for row, idx in enumerate(rows):
                out[idx] = y_sim[row]
        return out

    def score(self, records, y=None) -> float:
        """Negative eq. (RMSE) of the fitted plant on ``records``, normalised by each record's step height.

        Higher is better (scikit-learn's convention, as its ``neg_root_mean_squared_error``):
        0 is a perfect replay, ``-0.01`` an RMS error of 1 % of the step height. Each record's
        rest levels are re-estimated; ``-score(records)`` on the fitted records is ``rmse_``.

        Returns
        -------
        float
            Dimensionless, ``<= 0``.
        """
        orders, signals, _ = self._prepared(records)
        return -simulation_error(orders, self._theta(orders), self.delay_, signals, self.offset)[0]

    def _prepared(self, records):
        check_is_fitted(self)
        params = self._validate_params()
        orders = check_orders(params["n_poles"], params["n_zeros"], params["n_integrators"])
        _, groups, signals = prepare_signals(_batch(records), orders, params["n_samples"], params["hold"],
                                             params["oversample"], params["offset"])
        return orders, signals, groups

    def _theta(self, orders: srivc.Orders) -> np.ndarray:
        return np.concatenate([self.den_[1 : orders.n - orders.k + 1], self.num_])

    def _warm_start_point(self, orders: srivc.Orders) -> tuple[np.ndarray, float] | None:
        """``(theta, delay)`` of the last fit when ``warm_start`` applies, else ``None``."""
        if not self.warm_start or not hasattr(self, "plant_") or self.den_.size != orders.n + 1 \
                or self.num_.size != orders.m + 1 or np.any(self.den_[orders.n - orders.k + 1 :] != 0.0):
            return None
        return self._theta(orders), self.delay_


def _batch(records) -> Batch:
    """The records as one validated batch (:meth:`agents.twin.records.Batch.from_records`), or a batch as it is."""
    return records if isinstance(records, Batch) else Batch.from_records(records)
