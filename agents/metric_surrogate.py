"""One GP per performance metric, combined into the cost posterior (paper, abstract and eq. (J_used)).

The paper's objective "consists of performance metrics modeled by Gaussian
processes": ``J = sum_i w_i f_i / n_i`` (eq. (J_used)). :class:`MetricSurrogate`
fits one :class:`agents.surrogate.GPSurrogate` per metric on the normalised
values ``f_i / n_i`` and returns a :class:`CompositeSurrogate`, whose
``predict(X) -> (mean, std)`` is the posterior of ``J_hat``; acquisition
functions (:mod:`agents.acquisition`) use it exactly like a single GP.

Modelling assumptions
---------------------
* The metric GPs are **independent** a posteriori (no cross-covariance is
  modelled), so with ``c_i = w_i / n_i`` and ``g_i = f_i / n_i``::

      mean(J_hat) = sum_i w_i mu_i          (mu_i: posterior mean of g_i)
      var(J_hat)  = sum_i w_i^2 sigma_i^2   (sigma_i: posterior std of g_i)

  i.e. ``sum c_i mean(f_i)`` and ``sum c_i^2 var(f_i)``. Independence ignores
  the (mostly positive) correlation between e.g. rise time and ITAE, so the
  variance is, if anything, underestimated; EI only needs it up to a scale.
* **Noise.** The env's cost noise ``epsilon`` is additive on ``J`` (``J = J_hat
  + epsilon``), not on the metrics, which are computed from the measured
  response (noise-free when the env has no sensor noise). Each metric GP
  learns its own (white) noise level, which is the noise *of the metric*; the
  cost-level noise the metric GPs never see is estimated from the residual
  ``J - sum_i w_i f_i / n_i`` of the training points (:attr:`CompositeSurrogate.cost_noise_std_`).
  :meth:`CompositeSurrogate.predict` returns the posterior of the noise-free
  ``J_hat`` (as :meth:`GPSurrogate.predict` does: white noise excluded); the
  noise std of one measured cost is ``sqrt(cost_noise_std_^2 + sum_i w_i^2
  s_i^2)`` with ``s_i`` the metric GPs' learned noise (:attr:`CompositeSurrogate.noise_std_`).
  Because the metrics are not corrupted by ``epsilon``, the composite mean at a
  training point reproduces ``J_hat`` rather than the noisy ``J``.
* **Prior mean.** By default each GP has a constant prior mean (the
  standardisation of :class:`~agents.surrogate.GPSurrogate`). Given a ``prior``
  (e.g. a digital twin's metrics, :class:`agents.twin_prior.TwinMetrics`), the GP of
  metric ``i`` models the discrepancy ``d_i = T_i(f_i) - T_i(p_i)`` of the transformed
  metric (``T_i``: ``f / n_i``, or its log) from the prior's, and predicts
  ``T_i(p_i(theta)) + mu_d(theta)`` with the discrepancy's std (Kennedy and O'Hagan's
  model discrepancy; a constant discrepancy is still learned by the standardisation).
  Metric by metric, the prior mean is kept only if the discrepancy GP's log marginal
  likelihood of the measured ``T_i(f_i)`` is at least the constant-mean GP's (each with its
  hyperparameters at their maximum: type-II maximum likelihood between the two mean functions,
  Rasmussen and Williams, sec. 5.4; from ``min_fit_points`` points on, below which the GPs keep
  their prior kernel and the likelihood is no evidence); otherwise that metric's GP has the constant mean
  (:attr:`CompositeSurrogate.with_prior` lists the metrics that kept the prior). A twin that
  replays the response but not, say, its overshoot (stick-slip hunting on
  ``LinearMotorCascadeRig-v0``: the twin's overshoot is uncorrelated with the measured one) then
  guides through the metrics it predicts; as the prior of every metric it held EI in the basin
  it predicts, which the discrepancy GP corrects only where the plant was measured.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from agents.surrogate import GPSurrogate

__all__ = ["CompositeSurrogate", "GPDerivedMetric", "MetricSurrogate", "MetricPrior"]


class MetricPrior(Protocol):
    """Prior mean of the raw metrics: ``prior(X) -> f`` of shape (m, n_metrics), finite, for unit-box X (m, d)."""

    def __call__(self, X: np.ndarray) -> np.ndarray: ...


class CompositeSurrogate:
    """Posterior of ``J_hat = sum_i w_i g_i`` from independent GPs on the normalised metrics ``g_i``.

    Parameters
    ----------
    models : sequence of fitted surrogates
        Anything with ``predict(X) -> (mean, std)``, one per metric, on the normalised metric ``f_i / n_i``.
    weights : array_like of shape (n_metrics,)
        ``w_i`` of eq. (J_used).
    cost_noise_std : float, default 0
        Std of the cost-level noise the metric models do not see (see the module doc).
    derived : iterable of int, default ()
        Metrics whose model is fitted on something other than the metric's own measurements
        (the settling time from the error envelope, :mod:`agents.settling`); at a training
        point such a model predicts its own estimate, not the measurement (see
        :meth:`MetricSurrogate.observed_cost`).
    with_prior : iterable of int, default ()
        Metrics whose model has a prior mean (the twin's) rather than a constant one.
    """

    def __init__(self, models, weights, cost_noise_std: float = 0.0, derived=(), with_prior=()) -> None:
        self.models = list(models)
        self.weights = np.asarray(weights, dtype=float).ravel()
        if self.weights.size != len(self.models):
            raise ValueError(f"weights: need one per model ({len(self.models)}), got {self.weights.size}")
        self.cost_noise_std_ = float(cost_noise_std)
        self.derived = tuple(sorted(int(i) for i in derived))
        self.with_prior = tuple(sorted(int(i) for i in with_prior))

    def predict_metrics(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Posterior means and stds of every normalised metric, each of shape (m, n_metrics)."""
        X = np.atleast_2d(np.asarray(X, dtype=float))
        parts = [model.predict(X) for model in self.models]
        return np.column_stack([p[0] for p in parts]), np.column_stack([p[1] for p in parts])

    def predict(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Mean ``sum w_i mu_i`` and std ``sqrt(sum w_i^2 sigma_i^2)`` of ``J_hat`` (independent GPs), (m,) each."""
        X = np.atleast_2d(np.asarray(X, dtype=float))
        mean = np.zeros(X.shape[0])
        var = np.zeros(X.shape[0])
        for weight, model in zip(self.weights, self.models):
            mu, sigma = model.predict(X)
            mean += weight * mu
            var += weight**2 * sigma**2
        return mean, np.sqrt(var)

    @property
    def noise_std_(self) -> float:
        """Noise std of one measured cost: cost-level noise and the metric GPs' noise, independent."""
        metric = sum(w**2 * getattr(m, "noise_std_", 0.0) ** 2 for w, m in zip(self.weights, self.models))
        return float(np.sqrt(self.cost_noise_std_**2 + metric))

    @property
    def length_scales_(self) -> np.ndarray:
        """ARD length scales of every metric GP, shape (n_metrics, d)."""
        return np.vstack([m.length_scales_ for m in self.models])


class MetricSurrogate:
    """Fits one :class:`GPSurrogate` per normalised metric ``f_i / n_i`` and combines them (eq. (J_used)).

    Parameters
    ----------
    weights, normalizers : array_like of shape (n_metrics,)
        ``w`` and ``n`` of ``J = sum_i w_i f_i / n_i`` (the env's ``weights`` and ``normalizers``).
    log_metrics : sequence of int, default ()
        Indices of metrics modelled as ``log(f_i / n_i + 1e-3)``; the combination then
        uses the log-normal mean and variance of each (see :class:`_LogNormal`).
    settling : agents.settling.SettlingTimeModel, optional
        Model of the metric ``settling_index`` from the error envelopes (see
        :mod:`agents.settling`), used instead of a GP on that metric whenever :meth:`fit`
        gets ``envelopes``.
    settling_index : int, default 1
        Which metric ``settling`` models (the settling time in :data:`agents.result.METRIC_COLUMNS`).
    **gp_kwargs
        Passed to every metric's :class:`GPSurrogate` (length-scale bounds, warm start, ...).

    Attributes
    ----------
    models : list of GPSurrogate
        One per metric; warm-started from their own previous fits.
    plain_models : list of GPSurrogate
        With a prior: the constant-mean GP of each metric, the alternative to its discrepancy GP.
    """

    def __init__(self, weights, normalizers, log_metrics=(), settling=None, settling_index: int = 1,
                 **gp_kwargs) -> None:
        self.weights = np.asarray(weights, dtype=float).ravel()
        self.normalizers = np.asarray(normalizers, dtype=float).ravel()
        if self.weights.shape != self.normalizers.shape or np.any(self.normalizers <= 0):
            raise ValueError("weights, normalizers: need the same length, normalizers > 0")
        self.log_metrics = tuple(int(i) for i in log_metrics)
        self.models = [GPSurrogate(**gp_kwargs) for _ in self.weights]
        self.plain_models = [GPSurrogate(**gp_kwargs) for _ in self.weights]
        self.settling = settling
        self.settling_index = int(settling_index)

    def reconstruct(self, metrics: np.ndarray) -> np.ndarray:
        """``sum_i w_i f_i / n_i`` for metrics of shape (n, n_metrics): ``J_hat`` of the measured metrics."""
        return np.asarray(metrics, dtype=float) @ (self.weights / self.normalizers)

    def observed_cost(self, model: CompositeSurrogate, X: np.ndarray, metrics: np.ndarray) -> np.ndarray:
        """``J_hat`` of measured points on the model's footing, shape (n,): the incumbent of EI.

        ``sum_i w_i g_i`` with ``g_i = f_i / n_i`` measured, except for the model's
        :attr:`~CompositeSurrogate.derived` metrics, whose ``g_i`` is the model's mean at ``X``.
        The envelope model places a settling time at the midpoint of the interval between two
        of its envelope times (half an interval from the measured one, more where its GP
        smooths); against the measured incumbent the model could then promise an improvement at
        the incumbent's own gains, which EI proposed again and again (LinearMotor-v0, seed 57:
        the same gains 11 times in a row).

        Parameters
        ----------
        model : CompositeSurrogate
            The surrogate :meth:`fit` returned on these points.
        X : ndarray of shape (n, d)
            Unit-box inputs of the measured points.
        metrics : ndarray of shape (n, n_metrics)
            Their raw metrics ``f_i``.
        """
        scaled = np.asarray(metrics, dtype=float) / self.normalizers
        for i in model.derived:
            scaled[:, i] = model.models[i].predict(X)[0]
        return scaled @ self.weights

    def fit(self, X: np.ndarray, metrics: np.ndarray, costs: np.ndarray | None = None,
            seed: int | None = None, optimize: bool = True, envelopes: np.ndarray | None = None,
            prior: MetricPrior | None = None) -> CompositeSurrogate:
        """Fit every metric GP on ``(X, f_i / n_i)`` and return their combination.

        Parameters
        ----------
        X : ndarray of shape (n, d)
            Unit-box inputs.
        metrics : ndarray of shape (n, n_metrics)
            Raw metric values ``f_i``, finite.
        costs : ndarray of shape (n,), optional
            Measured costs ``J``: the cost-level noise is the RMS of ``J - sum w f / n``.
        seed : int, optional
            Seeds the metric GPs' restarts (metric ``i`` gets ``seed + i``).
        optimize : bool, default True
            ``False`` keeps every GP's hyperparameters (see :meth:`GPSurrogate.fit`).
        envelopes : ndarray of shape (n, k), optional
            Error envelopes of the responses (:func:`agents.settling.error_envelope`); with a
            ``settling`` model, the settling time is modelled from them instead of by a GP once
            there are the points its GP fits hyperparameters on (``settling.gp.min_fit_points``).
            Below that, the envelope GP's fixed prior kernel (noise 1e-2 on each standardised
            envelope time) spreads the settling time at the measured gains over several envelope
            intervals, and EI measured the same gains up to four times in a row (LinearMotor-v0).
        prior : MetricPrior, optional
            Prior mean of the raw metrics; the GP of a metric then models the discrepancy from it
            where that model has the higher marginal likelihood (see the module doc). The settling
            time is then always modelled by a GP.
        """
        metrics = np.atleast_2d(np.asarray(metrics, dtype=float))
        if metrics.shape != (np.shape(X)[0], self.weights.size) or not np.all(np.isfinite(metrics)):
            raise ValueError(f"metrics: need finite values of shape ({np.shape(X)[0]}, {self.weights.size})")
        target = self._transformed(metrics)
        # a discrepancy the points do not show (a twin exact there) has at most the metric's own spread;
        # without a prior the spread is the fitted target's own, which GPSurrogate.fit standardises by anyway
        scales = np.std(target, axis=0)
        plain_target = target
        if prior is not None:
            target = target - self._transformed(prior(X))  # the discrepancy d_i from the prior
        from_envelopes = self.settling is not None and envelopes is not None and prior is None \
            and np.shape(X)[0] >= self.settling.gp.min_fit_points
        models, derived, with_prior = [], [], []
        for i, model in enumerate(self.models):
            seed_i = None if seed is None else int(seed) + i
            if from_envelopes and i == self.settling_index:
                models.append(self.settling.fit(X, envelopes, seed=seed_i, optimize=optimize))
                derived.append(i)
                continue
            model.fit(X, target[:, i], seed=seed_i, optimize=optimize, scale=scales[i])
            if prior is not None and not self._plain_is_likelier(i, model, X, plain_target[:, i], seed_i, optimize,
                                                                 scales[i]):
                model = _PriorMean(model, prior, i, self._transformed)
                with_prior.append(i)
            elif prior is not None:
                model = self.plain_models[i]
            models.append(_LogNormal(model) if i in self.log_metrics else model)
        noise = 0.0
        if costs is not None and np.size(costs) > 1:
            residual = np.asarray(costs, dtype=float) - self.reconstruct(metrics)
            noise = float(np.sqrt(np.mean(residual**2)))
        return CompositeSurrogate(models, self.weights, cost_noise_std=noise, derived=derived, with_prior=with_prior)

    def _plain_is_likelier(self, i: int, model: GPSurrogate, X: np.ndarray, target: np.ndarray, seed: int | None,
                           optimize: bool, scale: float) -> bool:
        """Whether metric ``i``'s constant-mean GP, fitted here on its transformed values ``target``, has a higher
        log marginal likelihood than its discrepancy GP ``model`` (type-II maximum likelihood between the two mean
        functions, Rasmussen and Williams, sec. 5.4). Below ``min_fit_points`` points the GPs keep their prior kernel
        and the likelihood is no evidence: ``False``.

        A twin wrong on this metric would otherwise hold EI in the basin it predicts, and the discrepancy GP corrects
        it only where the plant was measured.
        """
        if len(X) < model.min_fit_points:
            return False
        plain = self.plain_models[i].fit(X, target, seed=seed, optimize=optimize, scale=scale)
        return plain.log_marginal_likelihood_ > model.log_marginal_likelihood_

    def _transformed(self, metrics: np.ndarray) -> np.ndarray:
        """``T_i(f_i)`` of raw metrics (n, n_metrics): ``f_i / n_i``, in logs for :attr:`log_metrics`."""
        scaled = np.asarray(metrics, dtype=float) / self.normalizers
        for i in self.log_metrics:
            scaled[:, i] = np.log(np.maximum(scaled[:, i], 0.0) + _LOG_OFFSET)
        return scaled


_LOG_OFFSET = 1e-3


class _PriorMean:
    """The GP of a discrepancy ``d_i = T_i(f_i) - T_i(p_i)`` seen as a model of ``T_i(f_i)``.

    Mean ``T_i(p_i(X)) + mu_d(X)``, std ``sigma_d(X)``; noise and length scales are the GP's.
    """

    def __init__(self, gp: GPSurrogate, prior: MetricPrior, index: int, transform) -> None:
        self.gp, self.prior, self.index, self.transform = gp, prior, index, transform

    def predict(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        mu, sigma = self.gp.predict(X)
        return self.transform(self.prior(X))[:, self.index] + mu, sigma

    @property
    def noise_std_(self) -> float:
        return self.gp.noise_std_

    @property
    def length_scales_(self) -> np.ndarray:
        return self.gp.length_scales_


class GPDerivedMetric:
    """Base of metric models computed from a GP (attribute ``gp``) rather than being one.

    Such a model has no noise of its own (its GP's noise is part of what it computes) and
    reports its GP's length scales.
    """

    gp: GPSurrogate

    @property
    def noise_std_(self) -> float:
        """0: the GP's learned noise is not noise of the metric."""
        return 0.0

    @property
    def length_scales_(self) -> np.ndarray:
        """The GP's ARD length scales, shape (d,)."""
        return self.gp.length_scales_


class _LogNormal(GPDerivedMetric):
    """A GP on ``z = log(g + c)`` seen as a model of ``g``: log-normal mean and std, minus ``c``."""

    def __init__(self, model: GPSurrogate) -> None:
        self.gp = model

    def predict(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        mu, sigma = self.gp.predict(X)
        var = sigma**2
        mean = np.exp(mu + 0.5 * var)
        return mean - _LOG_OFFSET, mean * np.sqrt(np.expm1(var))
