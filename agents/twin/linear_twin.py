"""The paper's linear digital twin as a scikit-learn estimator: a continuous transfer function with delay by SRIVC."""

from __future__ import annotations

from typing import ClassVar

import numpy as np
from sklearn.utils.validation import check_is_fitted

from agents.parameters import Boolean, InstanceOf, Options
from agents.thread_limits import single_thread
from agents.twin import srivc
from agents.twin.estimator import TwinEstimator
from agents.twin.identify import (
    IdentifyOptions,
    check_orders,
    checked_options,
    identify,
    prepare_signals,
    simulation_error,
)
from agents.twin.records import Batch

__all__ = ["LinearTwin"]

_OPTIONS = IdentifyOptions()  # the default identification settings (frozen)


class LinearTwin(TwinEstimator):
    r"""The DT plant ``G_tilde`` of the paper (subsec. Digital Twin): a transfer function with delay, by SRIVC.

    ``fit`` runs :func:`agents.twin.identify.identify_linear` (SRIVC at each delay of a
    grid, the best delay refined by a bounded scalar search) on closed-loop step
    records; ``predict`` replays records' inputs through the fitted plant;
    ``score`` is the negative eq. (RMSE) normalised by the step height.

    Parameters
    ----------
    options : IdentifyOptions, default IdentifyOptions()
        The model structure (``n_poles``, ``n_zeros``, ``n_integrators``, ``offset``) and the
        settings of the identification (``delay_search``, :class:`agents.twin.identify.DelaySearch`;
        ``solver``, :class:`agents.twin.identify.SrivcOptions`), as for
        :func:`agents.twin.identify.identify` (same defaults and allowed ranges, checked at ``fit``).
        Default: ``IdentifyOptions()``. As a scikit-learn parameter each setting is also
        ``options__<name>``, a group's ``options__<group>__<name>`` (``set_params(options__n_zeros=1)``,
        a grid search over ``options__n_poles`` or ``options__solver__n_samples``).
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
    >>> from agents.twin import SrivcOptions
    >>> LinearTwin(IdentifyOptions(solver=SrivcOptions(n_samples=100))).get_params()["options__solver__n_samples"]
    100
    """

    _parameter_constraints: ClassVar[dict[str, list]] = {"options": [InstanceOf((IdentifyOptions,))],
                                                          "output": [Options(("speed", "position"))],
                                                          "warm_start": [Boolean()]}

    def __init__(self, options: IdentifyOptions = _OPTIONS, *, output: str = "speed", warm_start: bool = False) -> None:
        self.options = options
        self.output = output
        self.warm_start = warm_start

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
        params, options = self._checked()
        orders = check_orders(options.n_poles, options.n_zeros, options.n_integrators)
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
        orders, signals, groups, offset = self._prepared(records)
        out: list[np.ndarray | None] = [None] * sum(rows.size for rows in groups)
        for rows, sig in zip(groups, signals):
            y_sim = srivc.simulate(orders, self._theta(orders), self.delay_, sig, offset)[0]
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
        orders, signals, _, offset = self._prepared(records)
        return -simulation_error(orders, self._theta(orders), self.delay_, signals, offset)[0]

    def _prepared(self, records):
        check_is_fitted(self)
        _, options = self._checked()
        orders = check_orders(options.n_poles, options.n_zeros, options.n_integrators)
        solver = options.solver
        _, groups, signals = prepare_signals(_batch(records), orders, solver.n_samples, solver.hold, solver.oversample,
                                             options.offset)
        return orders, signals, groups, options.offset

    def _checked(self) -> tuple[dict, IdentifyOptions]:
        """The parameters and the identification settings, checked (:mod:`agents.parameters`) and converted."""
        params = self._validate_params()
        options = params["options"]
        return params, checked_options(options.settings(), "LinearTwin")

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
