"""The digital-twin plant estimator (scikit-learn conventions).

:class:`TwinEstimator` identifies the DT plant ``G_tilde`` of the paper
(subsec. Digital Twin) from closed-loop step records with SRIVC
(:mod:`agents.twin.srivc`) and a search over the input delay, and reports the
fidelity ``e_RMSE`` of eq. (RMSE) normalised by the step height.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares, minimize_scalar
from sklearn.base import BaseEstimator
from sklearn.exceptions import NotFittedError

from agents.thread_limits import single_thread
from agents.twin import srivc as _srivc
from agents.twin.records import as_records, decimate, make_batches
from gbo_envs import ContinuousPlant

__all__ = ["TwinEstimator"]

_HOLDS = ("auto", "zoh", "foh")
_SCAN_ITER = 8  # SRIVC iterations per delay while scanning the delay grid


class TwinEstimator(BaseEstimator):
    r"""Continuous-time transfer function with input delay, identified by SRIVC from closed-loop records.

    Model (:mod:`agents.twin.srivc`): ``y = y0 + B(s)/A(s) e^{-s tau} (u - u0)``
    with ``A`` monic of degree ``n_poles`` (``n_integrators`` of its roots at 0)
    and ``B`` of degree ``n_zeros``. ``(A, B)`` come from SRIVC iterations
    (S1)-(S4), started from a least-squares state-variable-filter fit; ``tau``
    minimises the simulation-error RMSE over a grid of delays, refined by a
    bounded scalar search between the neighbours of the best grid point.

    Parameters
    ----------
    n_poles : int, default 2
        Degree ``n`` of ``A(s)``.
    n_zeros : int, default 0
        Degree ``m < n`` of ``B(s)``.
    n_integrators : int, default 0
        Known poles at ``s = 0`` (1 for a position loop such as the linear motor).
    delay : float, optional
        Known input delay in s; ``None`` searches it.
    max_delay : float, optional
        Upper end of the delay search in s (default: 20 samples of the fitted
        data, at most 20 % of the shortest record).
    delay_step : float, optional
        Spacing of the delay grid in s (default: one sample of the fitted data).
    refine_delay : bool, default True
        Refine the best grid delay by a bounded scalar search (fractional delays).
    offset : bool, default True
        Estimate each record's rest levels ``(y0, u0)`` (the pre-step equilibrium);
        ``False`` takes ``y0 = y[0]`` and ``u0 = 0`` (records already in deviations).
    n_samples : int, optional
        Keep this many uniformly spaced samples per record, the paper's sampling
        length ``n_tilde`` of eq. (Ds) (paper: 100). Default ``None`` uses the
        whole record: the loop's input is held between samples, so at the full
        rate the filters are exact and the fit is best.
    hold : {"auto", "zoh", "foh"}, default "auto"
        Intersample behaviour of ``u`` and ``y`` in the prefilters: zero-order
        hold (exact for a digital loop sampled at the record rate) or
        first-order hold (linear interpolation, for decimated records). "auto"
        is "zoh" for full records and "foh" when ``n_samples`` decimates.
    oversample : int, default 10
        Filter-grid refinement for ``hold="foh"``.
    max_iter : int, default 50
        Maximum SRIVC iterations per delay.
    tol : float, default 1e-8
        Convergence tolerance on the relative parameter change.
    svf_bandwidth : float, optional
        Bandwidth ``lambda`` in rad/s of the initial state-variable filter
        ``1/(s + lambda)^n`` (default: ``10 / T`` with ``T`` the record length).
    output : {"speed", "position"}, default "speed"
        What ``y`` measures; copied to :attr:`plant_`.
    warm_start : bool, default False
        Refit from the previous solution: SRIVC starts at the last parameters
        and the delay grid shrinks to the last delay +- 2 grid steps (much
        faster when records are added one by one, as in guided BO).
    polish : bool, default False
        Safeguard: refine ``(theta, tau)`` by minimising the simulation error
        (``scipy.optimize.least_squares``) from the SRIVC estimate and keep the
        result only if it lowers ``rmse_`` (it matters on short, noisy,
        decimated records; on full records SRIVC is already at the minimum).
    effects : list of str or dict, optional
        Physical effects from the catalogue (:data:`gbo_envs.physics.EFFECT_NAMES`)
        added to the linear part: names, or ``{name: {parameter: value}}`` with
        initial values. ``fit`` then estimates the linear part and the effect
        parameters together by minimising the simulation error
        (:func:`agents.twin.effect_estimator.fit_twin_effects`) and sets ``effects_``
        (the fitted blocks, used by :class:`agents.twin.TwinEnv`) and
        ``effect_params_``; ``predict`` and ``rmse`` simulate with them.

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
    >>> twin = TwinEstimator().fit([info])
    >>> bool(np.allclose(twin.params_, (9.544, 4.145, 4.199), rtol=1e-3))
    True
    """

    def __init__(
        self,
        n_poles: int = 2,
        n_zeros: int = 0,
        n_integrators: int = 0,
        delay: float | None = None,
        max_delay: float | None = None,
        delay_step: float | None = None,
        refine_delay: bool = True,
        offset: bool = True,
        n_samples: int | None = None,
        hold: str = "auto",
        oversample: int = 10,
        max_iter: int = 50,
        tol: float = 1e-8,
        svf_bandwidth: float | None = None,
        output: str = "speed",
        warm_start: bool = False,
        polish: bool = False,
        effects=None,
    ) -> None:
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
        self.effects = effects

    # -- fitting ---------------------------------------------------------------------------------
    def fit(self, records, y=None) -> TwinEstimator:
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
        """
        if self.effects:  # grey-box: linear part and effect parameters by simulation error
            from agents.twin.effect_estimator import fit_twin_effects

            return fit_twin_effects(self, records)
        self.__dict__.pop("effects_", None)
        with single_thread():  # tiny matrices: BLAS threads only contend
            return self._fit(records)

    def _fit(self, records) -> TwinEstimator:
        orders = self._check_params()
        data, batches, signals = self._prepare(records, orders)
        dt = min(rec.dt for rec in data)
        horizon = min(rec.t[-1] - rec.t[0] for rec in data)

        bandwidth = self.svf_bandwidth if self.svf_bandwidth is not None else 10.0 / horizon
        theta0 = None
        if self.delay is not None:
            grid = np.array([float(self.delay)])
        else:
            step = float(self.delay_step) if self.delay_step is not None else dt
            top = float(self.max_delay) if self.max_delay is not None else min(20 * dt, 0.2 * horizon)
            if step <= 0.0 or top < 0.0:
                raise ValueError(f"delay_step must be > 0 and max_delay >= 0, got {step} and {top}")
            grid = np.arange(0.0, top + 0.5 * step, step)
        previous = self._previous_fit(orders)
        if previous is not None:  # warm start: SRIVC from the last fit, delays next to the last delay
            theta0 = previous[0]
            near = np.abs(grid - previous[1]) <= 2.0 * (grid[1] - grid[0] if grid.size > 1 else 0.0) + 1e-12
            grid = grid[near] if near.any() else grid

        cache: dict[float, tuple[float, _srivc.SrivcResult]] = {}

        def evaluate(tau: float, start: np.ndarray | None, max_iter: int) -> float:
            if start is None:
                start = _srivc.lssvf(orders, signals, tau, bandwidth, self.offset)
            result = _srivc.srivc(orders, signals, tau, start, max_iter, self.tol, self.offset)
            score = self._rmse(orders, result.theta, tau, signals)[0]
            if not np.isfinite(score):
                score = np.inf
            cache[float(tau)] = (score, result)
            return score

        scores = []
        scan_iter = self.max_iter if grid.size == 1 else min(self.max_iter, _SCAN_ITER)
        for tau in grid:  # the grid scan ranks delays after a few warm-started iterations
            scores.append(evaluate(tau, theta0, scan_iter))
            theta0 = cache[float(tau)][1].theta if np.isfinite(scores[-1]) else None
        scores = np.array(scores)
        best = int(np.argmin(scores))
        if self.delay is None and self.refine_delay and grid.size > 1:
            lo = grid[max(best - 1, 0)]
            hi = grid[min(best + 1, grid.size - 1)]
            warm = cache[float(grid[best])][1].theta
            minimize_scalar(lambda tau: evaluate(tau, warm, self.max_iter), bounds=(lo, hi), method="bounded",
                            options={"xatol": 1e-3 * dt})
        tau_best = min(cache, key=lambda tau: cache[tau][0])
        if not cache[tau_best][1].converged and grid.size > 1:  # finish the iterations at the chosen delay
            evaluate(tau_best, cache[tau_best][1].theta, self.max_iter)
        score, result = cache[tau_best]
        if not np.isfinite(score):
            raise RuntimeError("TwinEstimator: SRIVC diverged at every delay; check the data or the model orders")

        theta = result.theta
        if self.polish:
            bounds = (float(grid[0]), float(grid[-1])) if self.delay is None else None
            theta, tau_best = self._polish(orders, theta, tau_best, signals, score, bounds)
        rmse, rmse_abs, levels = self._rmse(orders, theta, tau_best, signals, details=True)
        rest = np.empty((len(data), 2))
        rest[np.concatenate([b.index for b in batches])] = levels
        self.num_ = orders.num(theta)
        self.den_ = orders.den(theta)
        self.params_ = np.concatenate([self.num_, self.den_[1 : orders.n - orders.k + 1]])
        self.param_names_ = tuple(f"b{j}" for j in range(orders.m + 1)) + tuple(
            f"a{i}" for i in range(1, orders.n - orders.k + 1))
        self.delay_ = float(tau_best)
        self.plant_ = ContinuousPlant(num=tuple(self.num_), den=tuple(self.den_), delay=self.delay_,
                                      output=self.output)
        self.rmse_ = float(rmse)
        self.rmse_abs_ = float(rmse_abs)
        self.rest_levels_ = rest
        self.n_iter_ = int(result.n_iter)
        self.converged_ = bool(result.converged)
        order = np.argsort(list(cache))
        self.delay_grid_ = np.array(list(cache))[order]
        self.delay_rmse_ = np.array([cache[tau][0] for tau in cache])[order]
        self.n_records_ = len(data)
        self.n_samples_ = max(rec.n_steps for rec in data)
        self.dt_ = float(dt)
        return self

    # -- prediction ------------------------------------------------------------------------------
    def predict(self, records) -> list[np.ndarray]:
        """Simulated output of the fitted plant driven by each record's ``u``.

        Each record's rest levels ``(y0, u0)`` are re-estimated (``offset=True``).
        Records are decimated like the training data.

        Returns
        -------
        list of ndarray of shape (n_steps,)
            ``y_sim`` in the units of ``y`` at the (decimated) sample times.
        """
        self._check_fitted()
        if self.effects and hasattr(self, "effects_"):
            from agents.twin.effect_estimator import predict_twin_effects

            return predict_twin_effects(self, records)
        orders = self._check_params()
        data, batches, signals = self._prepare(records, orders)
        out: list[np.ndarray | None] = [None] * len(data)
        for batch, sig in zip(batches, signals):
            y_sim = _srivc.simulate(orders, self._theta(orders), self.delay_, sig, self.offset)[0]
            for row, idx in enumerate(batch.index):
                out[idx] = y_sim[row]
        return out

    def rmse(self, records, normalize: bool = True) -> float:
        """Eq. (RMSE) of the fitted plant on ``records`` (normalised by the step height by default)."""
        self._check_fitted()
        if self.effects and hasattr(self, "effects_"):
            from agents.twin.effect_estimator import rmse_twin_effects

            return rmse_twin_effects(self, records, normalize)
        orders = self._check_params()
        signals = self._prepare(records, orders)[2]
        rmse, rmse_abs = self._rmse(orders, self._theta(orders), self.delay_, signals)[:2]
        return float(rmse if normalize else rmse_abs)

    # -- helpers ---------------------------------------------------------------------------------
    def _theta(self, orders: _srivc.Orders) -> np.ndarray:
        return np.concatenate([self.den_[1 : orders.n - orders.k + 1], self.num_])

    def _polish(self, orders, theta, tau, signals, score, delay_bounds):
        """Output-error safeguard: minimise the eq. (RMSE) simulation error from the SRIVC estimate.

        SRIVC's fixed point coincides with the simulation-error minimum for long,
        informative records; on short noisy (e.g. decimated) records it can stall
        away from it. A Gauss-Newton/trust-region search (``scipy.optimize.least_squares``)
        over ``(theta, tau)`` from the SRIVC solution is kept only if it lowers the RMSE.
        """
        free_delay = delay_bounds is not None and delay_bounds[1] > delay_bounds[0]

        def residuals(x):
            th, ta = (x[:-1], x[-1]) if free_delay else (x, tau)
            th = _srivc._stabilised(orders, th)
            parts = []
            for sig in signals:
                y_sim, y0 = _srivc.simulate(orders, th, float(ta), sig, self.offset)[:2]
                height = np.maximum(np.abs(sig.r2 - y0), 1e-12)
                parts.append((((sig.y + sig.y_ref[:, None]) - y_sim) / height[:, None]).ravel())
            res = np.concatenate(parts)
            return res if np.all(np.isfinite(res)) else np.full(res.size, 1e6)

        x0 = np.append(theta, tau) if free_delay else theta.copy()
        lower = np.full(x0.size, -np.inf)
        upper = np.full(x0.size, np.inf)
        if free_delay:
            lower[-1], upper[-1] = delay_bounds
            x0[-1] = np.clip(x0[-1], *delay_bounds)
        try:
            sol = least_squares(residuals, x0, bounds=(lower, upper), x_scale="jac", max_nfev=100 * x0.size)
        except (ValueError, np.linalg.LinAlgError):
            return theta, tau
        new_theta = _srivc._stabilised(orders, sol.x[:-1] if free_delay else sol.x)
        new_tau = float(sol.x[-1]) if free_delay else tau
        new_score = self._rmse(orders, new_theta, new_tau, signals)[0]
        if np.isfinite(new_score) and new_score < score * (1.0 - 1e-9):
            return new_theta, new_tau
        return theta, tau

    def _previous_fit(self, orders: _srivc.Orders):
        """``(theta, delay)`` of the last fit when ``warm_start`` applies, else ``None``."""
        if not self.warm_start or not hasattr(self, "plant_") or self.den_.size != orders.n + 1 \
                or self.num_.size != orders.m + 1 or np.any(self.den_[orders.n - orders.k + 1 :] != 0.0):
            return None
        return self._theta(orders), self.delay_

    def _check_fitted(self) -> None:
        if not hasattr(self, "plant_"):
            raise NotFittedError(f"This {type(self).__name__} instance is not fitted yet; call 'fit' with "
                                 "experiment records first.")

    def __sklearn_is_fitted__(self) -> bool:
        return hasattr(self, "plant_")

    def _check_params(self) -> _srivc.Orders:
        n, m, k = self.n_poles, self.n_zeros, self.n_integrators
        if not (isinstance(n, (int, np.integer)) and n >= 1):
            raise ValueError(f"n_poles: must be an integer >= 1, got {n!r}")
        if not (isinstance(m, (int, np.integer)) and 0 <= m < n):
            raise ValueError(f"n_zeros: must be an integer with 0 <= n_zeros < n_poles = {n}, got {m!r}")
        if not (isinstance(k, (int, np.integer)) and 0 <= k < n):
            raise ValueError(f"n_integrators: must be an integer with 0 <= n_integrators < n_poles = {n}, got {k!r}")
        if self.delay is not None and (not np.isfinite(self.delay) or self.delay < 0.0):
            raise ValueError(f"delay: must be None or a finite number of seconds >= 0, got {self.delay!r}")
        if self.hold not in _HOLDS:
            raise ValueError(f"hold: must be one of {_HOLDS}, got {self.hold!r}")
        if self.n_samples is not None and (not isinstance(self.n_samples, (int, np.integer)) or self.n_samples < 2):
            raise ValueError(f"n_samples: must be None or an integer >= 2, got {self.n_samples!r}")
        if not (isinstance(self.oversample, (int, np.integer)) and self.oversample >= 1):
            raise ValueError(f"oversample: must be an integer >= 1, got {self.oversample!r}")
        if self.output not in ("speed", "position"):
            raise ValueError(f"output: must be 'speed' or 'position', got {self.output!r}")
        if not (self.max_iter >= 1 and self.tol > 0):
            raise ValueError(f"max_iter must be >= 1 and tol > 0, got {self.max_iter!r} and {self.tol!r}")
        return _srivc.Orders(int(n), int(m), int(k))

    def _prepare(self, records, orders: _srivc.Orders):
        """Validate, decimate (``n_samples``), batch and lay the records on the filter grid."""
        raw = as_records(records, min_steps=3)
        data = [decimate(rec, self.n_samples) for rec in raw]
        total = sum(rec.n_steps for rec in data)
        if total < orders.n_params + 3:
            raise ValueError(f"records: {total} samples in all are too few for {orders.n_params} parameters")
        hold = self.hold
        if hold == "auto":
            hold = "foh" if any(d.n_steps < r.n_steps for d, r in zip(data, raw)) else "zoh"
        batches = make_batches(data)
        signals = [_srivc.prepare(b.dt, b.u, b.y, b.r2, self.offset, hold, int(self.oversample)) for b in batches]
        return data, batches, signals

    def _rmse(self, orders, theta, tau, signals, details: bool = False):
        """Eq. (RMSE): normalised by each record's step height ``|r2 - y0|``, and in units of ``y``."""
        sq_norm, sq_abs, count, levels = 0.0, 0.0, 0, []
        for sig in signals:
            y_sim, y0, u0 = _srivc.simulate(orders, theta, tau, sig, self.offset)
            err = (sig.y + sig.y_ref[:, None]) - y_sim
            height = np.abs(sig.r2 - y0)
            height = np.where(height > 0.0, height, np.nan)
            sq_norm += float(np.sum((err / height[:, None]) ** 2))
            sq_abs += float(np.sum(err**2))
            count += err.size
            levels.append(np.column_stack([y0, u0]))
        rmse, rmse_abs = np.sqrt(sq_norm / count), np.sqrt(sq_abs / count)
        if not details:
            return rmse, rmse_abs
        return rmse, rmse_abs, np.concatenate(levels)
