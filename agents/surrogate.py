"""Gaussian-process surrogate of the cost ``J(theta)`` (paper, subsec. BO, eqs. (gpr)-(gpr_v)).

The surrogate knows nothing about acquisition functions: it is fitted on
``(X, y)`` and answers :meth:`GPSurrogate.predict` with the posterior mean and
standard deviation. Acquisition functions (:mod:`agents.acquisition`) only
ever call that method (BoTorch's separation of model and acquisition).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from scipy.linalg import cho_solve, cholesky, get_lapack_funcs
from scipy.optimize import minimize
from sklearn.gaussian_process.kernels import ConstantKernel, Matern, WhiteKernel

from agents.thread_limits import single_thread

__all__ = ["GPSurrogate", "dimension_scale"]


@dataclass(frozen=True, eq=False)
class _Conditioned:
    """The parts of a fitted scikit-learn GP that prediction uses, for a fixed-hyperparameter fit."""

    kernel_: object
    L_: np.ndarray
    alpha_: np.ndarray

#: Candidate rows per block in :meth:`GPSurrogate.predict` (measured fastest on the 100 x 100 grid).
_PREDICT_BLOCK = 1024


def dimension_scale(dim: int) -> float:
    """``sqrt(d / 2)``: the factor of :class:`GPSurrogate`'s length scales for ``d`` inputs (1 for two gains)."""
    return float(np.sqrt(dim / 2.0))


class GPSurrogate:
    """GP regression with a Matern 5/2 ARD kernel, a constant mean and Gaussian noise.

    Prior (paper, subsec. BO): ``J_hat ~ GP(mu, k)`` with

    * ``k(x, x') = s^2 Matern_{5/2}(x, x'; l_1..l_d) + sigma_n^2 delta(x, x')``
      (``ConstantKernel * Matern(nu=2.5) + WhiteKernel``; one length scale per
      input, ARD);
    * a constant mean ``mu``: costs are standardised, ``y_s = (y - m) / s_y``
      with ``m`` the sample mean and ``s_y`` the sample std of the training
      costs, so the GP's zero prior mean on ``y_s`` *is* the constant mean
      ``mu = m`` on ``J`` (the paper's "constant prior mean");
    * the posterior of eqs. (gpr_mio1), (gpr_v) with ``sigma_eps^2 I`` as the
      learned white-noise level, or fixed when ``noise_std`` is given.

    The kernel amplitude ``s^2``, the length scales and the noise level
    maximise the log marginal likelihood (scikit-learn's L-BFGS-B), started
    from the previous fit's values (warm start) and from ``n_restarts``
    random points drawn from a seeded generator (see ``restart_every``).

    Parameters
    ----------
    n_restarts : int, default 2
        Extra random starts of the likelihood optimiser per fit.
    length_scale_bounds : (float, float), default (0.05, 0.5)
        Bounds of the ARD length scales for two inputs, in units of the (unit-box) inputs. For
        ``d`` inputs they, and the prior length scale 0.3, are multiplied by ``sqrt(d / 2)``
        (:func:`dimension_scale`): the distance between points of the unit box grows as ``sqrt(d)``,
        and so do the length scales that fit a function of ``d`` inputs (Hvarfner, Hellsten and Nardi,
        "Vanilla Bayesian optimization performs great in high dimensions", ICML 2024; BoTorch's default
        length-scale prior scales with ``sqrt(d)`` for the same reason). Two gains are unchanged.
    noise_std : float, optional
        Known cost noise ``sigma_eps`` (cost units, e.g. from
        :func:`agents.cost_noise.estimate_noise`). ``None`` learns it (WhiteKernel).
    noise_bounds : (float, float), default (1e-6, 0.5)
        Bounds of the learned noise variance, in units of the standardised costs.
    warm_start : bool, default True
        Start the likelihood optimiser from the previous fit's hyperparameters.
    restart_every : int, default 5
        With ``warm_start``, the random restarts run only on every
        ``restart_every``-th fit (and on the first); the fits in between start
        from the previous optimum alone (fast when one point was added).
    min_fit_points : int, default 5
        With fewer training points the hyperparameters are not fitted (the
        likelihood of 1-4 points is flat or degenerate); the prior kernel
        (unit amplitude, length scales ``0.3 sqrt(d / 2)`` clipped to the bounds, noise
        variance 1e-2 in standardised units) is used as is.
    max_iter : int, default 60
        L-BFGS-B iterations per start.

    Attributes
    ----------
    X_train_ : ndarray of shape (n, d)
    y_train_ : ndarray of shape (n,)
        Training costs (cost units).
    y_mean_, y_scale_ : float
        Constant prior mean ``m`` and scale ``s_y`` of the standardisation.
    gp_ : object
        The conditioned posterior: ``kernel_``, ``L_`` (Cholesky factor of ``K + alpha I``) and
        ``alpha_`` (``(K + alpha I)^-1 y_s``), named as in scikit-learn's ``GaussianProcessRegressor``.
    kernel_ : sklearn kernel
        The fitted kernel (standardised units).
    """

    def __init__(self, *, n_restarts: int = 2, length_scale_bounds: tuple[float, float] = (0.05, 0.5),
                 noise_std: float | None = None, noise_bounds: tuple[float, float] = (1e-6, 0.5),
                 warm_start: bool = True, restart_every: int = 5, min_fit_points: int = 5,
                 max_iter: int = 60) -> None:
        self.n_restarts = int(n_restarts)
        self.length_scale_bounds = tuple(float(b) for b in length_scale_bounds)
        self.noise_std = None if noise_std is None else float(noise_std)
        self.noise_bounds = tuple(float(b) for b in noise_bounds)
        self.warm_start = bool(warm_start)
        self.restart_every = max(1, int(restart_every))
        self.min_fit_points = int(min_fit_points)
        self.max_iter = int(max_iter)
        self._previous_kernel = None
        self._n_fits = 0

    def _initial_kernel(self, dim: int):
        if self.warm_start and self._previous_kernel is not None and _kernel_dim(self._previous_kernel) == dim:
            return self._previous_kernel
        return self._prior_kernel(dim)

    def _prior_kernel(self, dim: int):
        scale = dimension_scale(dim)
        bounds = tuple(scale * b for b in self.length_scale_bounds)
        length_scale = float(np.clip(0.3 * scale, *bounds))
        kernel = ConstantKernel(1.0, (1e-2, 1e2)) * Matern(
            length_scale=np.full(dim, length_scale), length_scale_bounds=bounds, nu=2.5)
        if self.noise_std is None:
            kernel = kernel + WhiteKernel(float(np.clip(1e-2, *self.noise_bounds)), self.noise_bounds)
        return kernel

    def fit(self, X: np.ndarray, y: np.ndarray, seed: int | None = None, optimize: bool = True,
            scale: float | None = None) -> GPSurrogate:
        """Fit to inputs of shape (n, d) (the unit box) and costs of shape (n,).

        Parameters
        ----------
        X : ndarray of shape (n, d)
        y : ndarray of shape (n,) or (n, k)
            Costs ``J`` (cost units), finite. A 2-D ``y`` with ``k > 1`` columns fits ``k``
            outputs with one shared kernel (the same correlation, each output standardised on
            its own; the likelihood is the sum over the outputs); it needs a learned noise
            (``noise_std=None``), and :meth:`predict` then returns arrays of shape (m, k). One
            column is one output.
        seed : int, optional
            Seeds the random restarts of the likelihood optimiser.
        optimize : bool, default True
            ``False`` keeps the previous fit's hyperparameters and only conditions
            the GP on the new data (one Cholesky factorisation): guided BO's
            iterations on the twin use it.
        scale : float, optional
            The output scale (units of ``y``) by which a ``y`` that does not vary (std <= 1e-12) is standardised,
            the prior std of what the points do not show. Default (and where it is not above 1e-12) 1.

        Returns
        -------
        GPSurrogate
            ``self``.
        """
        X = np.atleast_2d(np.asarray(X, dtype=float))
        y = np.asarray(y, dtype=float)
        outputs = y.ndim == 2 and y.shape[1] > 1
        y = y if outputs else y.ravel()
        if X.shape[0] != y.shape[0] or X.shape[0] == 0:
            raise ValueError(f"X, y: need the same number (>= 1) of rows, got {X.shape} and {y.shape}")
        if not (np.all(np.isfinite(X)) and np.all(np.isfinite(y))):
            raise ValueError("X, y: must be finite")
        if outputs:
            return self._fit_outputs(X, y, seed, optimize)
        # Constant mean by standardisation: mu = mean(y) (paper, subsec. BO, constant prior mean).
        self.y_mean_ = float(np.mean(y))
        spread = float(np.std(y)) if y.size > 1 else 0.0
        fallback = 1.0 if scale is None or not scale > 1e-12 else float(scale)
        self.y_scale_ = spread if spread > 1e-12 else fallback
        y_std = (y - self.y_mean_) / self.y_scale_
        # Fixed noise: sigma_eps^2 I of eq. (gpr_mio1), in standardised units; else a small jitter.
        alpha = 1e-8 if self.noise_std is None else max((self.noise_std / self.y_scale_) ** 2, 1e-8)
        return self._fit_standardised(X, y, y_std, alpha, seed, optimize)

    def _fit_outputs(self, X: np.ndarray, y: np.ndarray, seed: int | None, optimize: bool) -> GPSurrogate:
        """:meth:`fit` of several outputs, ``y`` of shape (n, k > 1), with one shared kernel."""
        if self.noise_std is not None:
            raise ValueError("y: several outputs (2-D y) need a learned noise (noise_std=None)")
        self.y_mean_ = y.mean(axis=0)
        scale = y.std(axis=0) if y.shape[0] > 1 else np.zeros(y.shape[1])
        self.y_scale_ = np.where(scale > 1e-12, scale, 1.0)
        return self._fit_standardised(X, y, (y - self.y_mean_) / self.y_scale_, 1e-8, seed, optimize)

    def _fit_standardised(self, X: np.ndarray, y: np.ndarray, y_std: np.ndarray, alpha: float,
                          seed: int | None, optimize: bool) -> GPSurrogate:
        few = X.shape[0] < self.min_fit_points
        kernel = self._prior_kernel(X.shape[1]) if few else self._initial_kernel(X.shape[1])
        warm = kernel is self._previous_kernel
        if not optimize and warm:
            return self._condition(kernel, X, y, y_std, alpha)
        restarts = self.n_restarts if (not warm or self._n_fits % self.restart_every == 0) else 0
        if not few:
            kernel = self._maximise_likelihood(kernel, X, y_std, alpha, restarts if X.shape[0] > 1 else 0, seed)
        self._condition(kernel, X, y, y_std, alpha)
        if not few:
            self._previous_kernel = self.kernel_
        return self

    def _maximise_likelihood(self, kernel, X: np.ndarray, y_std: np.ndarray, alpha: float, restarts: int,
                             seed: int | None):
        """``kernel`` with the hyperparameters of highest log marginal likelihood (paper, subsec. BO).

        L-BFGS-B from the kernel's own hyperparameters and from ``restarts`` points drawn
        log-uniformly within the bounds (the multi-start of scikit-learn's
        ``GaussianProcessRegressor.fit``, same draws for the same seed), without the
        estimator's per-call overhead.
        """
        bounds = kernel.bounds
        draws = np.random.RandomState(None if seed is None else int(seed) % (2**32))
        starts = [kernel.theta] + [draws.uniform(bounds[:, 0], bounds[:, 1]) for _ in range(restarts)]
        # theta = log([s^2, l_1..l_d, sigma_n^2]) (sklearn's order); the objective is scikit-learn's
        # log_marginal_likelihood, evaluated by _neg_log_marginal_likelihood (about 5x faster here)
        objective = functools.partial(_neg_log_marginal_likelihood, pairwise=squared_differences(X),
                                      y=y_std, alpha=alpha, white=self.noise_std is None)
        with single_thread():
            optima = [minimize(objective, start, jac=True, method="L-BFGS-B", bounds=bounds,
                               options={"maxiter": self.max_iter}) for start in starts]
        return kernel.clone_with_theta(min(optima, key=lambda optimum: optimum.fun).x)

    def _condition(self, kernel, X: np.ndarray, y: np.ndarray, y_std: np.ndarray, alpha: float) -> GPSurrogate:
        """Posterior on ``(X, y)`` with fixed hyperparameters: ``L = chol(K + alpha I)``, ``a = K^-1 y_s``.

        The same algebra as scikit-learn's ``GaussianProcessRegressor.fit`` with
        ``optimizer=None``, without its per-call validation overhead.
        """
        with single_thread():
            gram = kernel(X)
            gram[np.diag_indices_from(gram)] += alpha
            lower = cholesky(gram, lower=True, check_finite=False)
            self.gp_ = _Conditioned(kernel_=kernel, L_=lower, alpha_=cho_solve((lower, True), y_std,
                                                                               check_finite=False))
        self._n_fits += 1
        self._store_fit(X, y)
        return self

    def _store_fit(self, X: np.ndarray, y: np.ndarray) -> None:
        """Cache what :meth:`predict` needs from the fitted ``gp_``."""
        self.kernel_ = self.gp_.kernel_
        self._amplitude = _constant(self.kernel_)
        self._length_scales = np.broadcast_to(_matern(self.kernel_).length_scale, (X.shape[1],)).astype(float)
        # inputs scaled by sqrt(5) / l_j, so that squared distances are (sqrt5 r)^2 of the Matern 5/2
        self._input_scale = np.sqrt(5.0) / self._length_scales
        train = X * self._input_scale
        self._train_cross = -2.0 * train.T
        self._train_sq = (train**2).sum(axis=1)
        self._K_inv = cho_solve((self.gp_.L_, True), np.eye(X.shape[0]), check_finite=False)
        self._scaled_alpha = self._amplitude * self.gp_.alpha_
        self._scaled_K_inv = self._amplitude**2 * self._K_inv
        self.X_train_ = X
        self.y_train_ = y

    def predict(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Posterior mean and standard deviation of ``J_hat`` (eqs. (gpr_mio1), (gpr_v)).

        Parameters
        ----------
        X : ndarray of shape (m, d)
            Unit-box inputs.

        Returns
        -------
        mean : ndarray of shape (m,)
            ``mu_n(theta)``, cost units (shape (m, k) for a GP fitted on a 2-D ``y``).
        std : ndarray of shape (m,)
            ``v_n(theta)^{1/2}`` of the noise-free cost ``J_hat`` (the learned
            white noise is excluded), cost units.
        """
        mean, std = self.predict_standardised(X)
        if mean.ndim == 2:  # several outputs: one correlation, each output's own scale
            std = std[:, None]
        return self.y_mean_ + self.y_scale_ * mean, self.y_scale_ * std

    def predict_standardised(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Posterior of the standardised outputs ``(y - y_mean_) / y_scale_`` at unit-box inputs (m, d).

        Returns the mean, of shape (m,) or (m, k) for a GP fitted on a 2-D ``y``, and the std of
        shape (m,), shared by the outputs (one kernel); the white noise is excluded.
        """
        if not hasattr(self, "gp_"):
            raise RuntimeError("GPSurrogate: call fit(X, y) first")
        X = np.atleast_2d(np.asarray(X, dtype=float))
        with single_thread():
            return self._predict_standardised(X)

    def _predict_standardised(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        # Blocks of _PREDICT_BLOCK rows keep the (rows, n) work arrays in cache and reuse their memory.
        mean, var = np.empty((X.shape[0],) + self._scaled_alpha.shape[1:]), np.empty(X.shape[0])
        scaled = X * self._input_scale
        for start in range(0, X.shape[0], _PREDICT_BLOCK):
            rows = slice(start, start + _PREDICT_BLOCK)
            mean[rows], var[rows] = self._predict_block(scaled[rows])
        return mean, np.sqrt(np.maximum(var, 1e-18))

    def _predict_block(self, scaled: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        # k_n(theta) of eq. (gpr_mio1): Matern 5/2, k = s^2 (1 + r + r^2 / 3) exp(-r), r = sqrt5 |x - x'|_l
        r = scaled @ self._train_cross  # squared distances, in place from here on
        r += np.einsum("ij,ij->i", scaled, scaled)[:, None]
        r += self._train_sq
        np.maximum(r, 0.0, out=r)
        np.sqrt(r, out=r)
        k_star = r * (1.0 / 3.0)
        k_star += 1.0
        k_star *= r
        k_star += 1.0
        np.negative(r, out=r)
        np.exp(r, out=r)
        k_star *= r  # the Matern correlation; the amplitude s^2 is in _scaled_alpha and _scaled_K_inv
        mean = k_star @ self._scaled_alpha  # eq. (gpr_mio1), standardised units
        # eq. (gpr_v) for the latent J_hat (white noise excluded): s^2 - k^T (K + sigma^2 I)^-1 k
        np.matmul(k_star, self._scaled_K_inv, out=r)
        return mean, self._amplitude - np.einsum("ij,ij->i", r, k_star)

    @property
    def noise_std_(self) -> float:
        """Noise std ``sigma_eps`` the GP uses (learned or given), cost units."""
        if self.noise_std is not None:
            return self.noise_std
        return float(np.sqrt(_white_noise_level(self.kernel_))) * self.y_scale_

    @property
    def length_scales_(self) -> np.ndarray:
        """Fitted ARD length scales, shape (d,), unit-box units."""
        return np.atleast_1d(_matern(self.kernel_).length_scale).astype(float)

    @property
    def log_marginal_likelihood_(self) -> float:
        r"""``log p(y | X)`` of the training data under the fitted GP, in nats, for ``y`` in its own units.

        ``-1/2 y_s^T (K + alpha I)^-1 y_s - sum_i log L_ii - n/2 log(2 pi) - n log s_y`` (Rasmussen &
        Williams, eq. 2.30, with the Jacobian ``1 / s_y`` of the standardisation ``y_s = (y - m) / s_y``),
        summed over the outputs of a 2-D ``y``: comparable between GPs fitted to different targets of the
        same quantity, e.g. a metric and its discrepancy from a prior mean.
        """
        standardised = (self.y_train_ - self.y_mean_) / self.y_scale_
        return float(_log_likelihood(standardised, self.gp_.alpha_, self.gp_.L_)
                     - standardised.shape[0] * np.sum(np.log(np.atleast_1d(self.y_scale_))))


def _white_noise_level(kernel) -> float:
    for part in (getattr(kernel, "k1", None), getattr(kernel, "k2", None)):
        if isinstance(part, WhiteKernel):
            return float(part.noise_level)
    return 0.0


def _matern(kernel):
    stack = [kernel]
    while stack:
        node = stack.pop()
        if isinstance(node, Matern):
            return node
        stack.extend(p for p in (getattr(node, "k1", None), getattr(node, "k2", None)) if p is not None)
    raise ValueError("kernel has no Matern part")


def _constant(kernel) -> float:
    stack = [kernel]
    while stack:
        node = stack.pop()
        if isinstance(node, ConstantKernel):
            return float(node.constant_value)
        stack.extend(p for p in (getattr(node, "k1", None), getattr(node, "k2", None)) if p is not None)
    return 1.0


def _kernel_dim(kernel) -> int:
    return np.atleast_1d(_matern(kernel).length_scale).size


def squared_differences(X: np.ndarray) -> np.ndarray:
    """``(x_a,j - x_b,j)^2`` of the rows of ``X`` (n, d), shape (d, n, n): the input of the likelihood."""
    X = np.asarray(X, dtype=float)
    return np.ascontiguousarray(((X[:, None, :] - X[None, :, :]) ** 2).transpose(2, 0, 1))


def _log_likelihood(y: np.ndarray, a: np.ndarray, lower: np.ndarray) -> float:
    """``log N(y; 0, K) = -1/2 y^T a - sum_i log L_ii - n/2 log(2 pi)`` with ``K = L L^T`` and ``a = K^-1 y``
    (Rasmussen & Williams, eq. 2.30); for ``y`` of shape (n, k), the sum over its k columns."""
    n = y.shape[0]
    if y.ndim == 1:
        return -0.5 * y @ a - np.log(np.diag(lower)).sum() - 0.5 * n * np.log(2.0 * np.pi)
    return -0.5 * np.sum(y * a) - y.shape[1] * (np.log(np.diag(lower)).sum() + 0.5 * n * np.log(2.0 * np.pi))


def _neg_log_marginal_likelihood(theta: np.ndarray, pairwise: np.ndarray, y: np.ndarray, alpha: float,
                                 white: bool) -> tuple[float, np.ndarray]:
    """``-log p(y | X, theta)`` and its gradient for ``s^2 Matern52 (+ sigma_n^2 I) + alpha I``.

    ``log p = -1/2 y^T K^-1 y - 1/2 log|K| - n/2 log(2 pi)``; ``d log p / d theta_i
    = 1/2 tr((a a^T - K^-1) dK/d theta_i)`` with ``a = K^-1 y`` (Rasmussen & Williams, eq. 5.9).
    ``theta = log([s^2, l_1, ..., l_d, sigma_n^2])`` (the last entry only if ``white``);
    ``pairwise`` is :func:`squared_differences` of the inputs, shape (d, n, n). For ``y`` of
    shape (n, k) (k outputs, one kernel): the sum of the k log likelihoods, ``inner = A A^T - k K^-1``.
    The Cholesky factor and the solve call LAPACK's ``potrf``/``potrs`` directly (what
    ``scipy.linalg.cho_factor``/``cho_solve`` call, without their per-call checks).
    """
    dim, n, _ = pairwise.shape
    amplitude = np.exp(theta[0])
    scaled = pairwise / np.exp(2.0 * theta[1:1 + dim])[:, None, None]  # d_j^2 / l_j^2
    total = scaled[0].copy()
    for j in range(1, dim):  # the sum over the inputs, in order (as scaled.sum(axis=0))
        total += scaled[j]
    r = np.sqrt(5.0 * total)  # sqrt(5) r
    decay = np.exp(-r)
    matern = (1.0 + r + r**2 / 3.0) * decay
    noise = np.exp(theta[-1]) if white else 0.0
    K = amplitude * matern
    diagonal = np.einsum("ii->i", K)  # a writable view of the diagonal
    diagonal += noise + alpha
    lower, info = _POTRF(K, lower=1, clean=0, overwrite_a=1)
    if info != 0:
        return 1e25, np.zeros_like(theta)
    K_inv = _POTRS(lower, np.eye(n), lower=1, overwrite_b=1)[0]
    a = K_inv @ y
    lml = _log_likelihood(y, a, lower)
    inner = np.outer(a, a) - K_inv if y.ndim == 1 else a @ a.T - y.shape[1] * K_inv
    grad = np.empty_like(theta)
    grad[0] = 0.5 * np.sum(inner * (amplitude * matern))  # dK/d log s^2 = s^2 M
    # dM/d log l_j = 5/3 (1 + sqrt5 r) exp(-sqrt5 r) d_j^2 / l_j^2
    weighted = inner * (amplitude * (5.0 / 3.0) * (1.0 + r) * decay)
    for j in range(dim):
        grad[1 + j] = 0.5 * np.sum(weighted * scaled[j])
    if white:
        grad[-1] = 0.5 * noise * np.trace(inner)
    return float(-lml), -grad


_POTRF, _POTRS = get_lapack_funcs(("potrf", "potrs"), (np.zeros((1, 1)),))
