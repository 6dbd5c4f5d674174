"""The grey-box digital twin as a scikit-learn estimator: linear part plus catalogue effects, by simulation error."""

from __future__ import annotations

from typing import ClassVar

import numpy as np
from sklearn.utils.validation import check_is_fitted

from agents.parameters import InstanceOf, Interval, Options
from agents.thread_limits import single_thread
from agents.twin.estimator import TwinEstimator
from agents.twin.fidelity import rmse
from agents.twin.fits import fit_structure
from agents.twin.guesses import rest_command
from agents.twin.identify import check_orders, linear_constraints
from agents.twin.least_squares import fit_problems, make_problem
from agents.twin.model import GreyFit, ModelSpec, output_error
from agents.twin.records import Batch, as_batch
from agents.twin.simulation import simulate_sets
from gbo_envs.physics.effects import build_effect

__all__ = ["GreyBoxTwin"]


class GreyBoxTwin(TwinEstimator):
    r"""A linear transfer function with delay plus physical effects, all fitted by simulation error.

    The model of a record is the open-loop replay of its command ``u``
    (:mod:`agents.twin.model`): ``B(s)/A(s) e^{-s tau}`` with ``A`` monic of degree
    ``n_poles`` and an input delay of at most one sample (a longer dead time is the
    ``time_delay`` effect), the catalogue's effect blocks, and per record a rest level
    and a plant-input bias. ``fit`` starts from the SRIVC fit of the linear part
    (:func:`agents.twin.linear_fit.linear_fit`), adds the effects one at a time from
    data-based starts and refits all parameters (:func:`agents.twin.fits.fit_structure`).

    Parameters
    ----------
    effects : list of str, str or dict, default ()
        Physical effects from the catalogue (:data:`gbo_envs.physics.EFFECT_NAMES`):
        names, a comma-separated string, or ``{name: {parameter: value}}`` with
        initial values. When every fitted parameter of every effect is given, the
        linear part is profiled at those values and everything refitted from there
        (at most ``min(max_iter, 20)`` iterations); missing values are found from the
        data. ``()`` fits the linear model alone by simulation error.
    n_poles : int, default 2
        Degree ``n`` of ``A(s)``, >= 1.
    n_zeros : int, default 0
        Degree of ``B(s)``, ``0 <= n_zeros < n_poles``.
    n_integrators : int, default 0
        Known poles at ``s = 0``, ``0 <= n_integrators < n_poles``.
    output : {"speed", "position"}, default "speed"
        What ``y`` measures (friction acts on ``y`` or on ``dy/dt``).
    n_samples : int, optional
        Keep this many uniformly spaced samples per record (>= 2), each with the mean input
        over its hold interval, more where the command moves within a hold
        (:func:`agents.twin.records.decimate_records`); default the whole record.
    max_iter : int, default 25
        Trial points of each least-squares fit of the effects (:func:`agents.twin.least_squares.fit_problems`), >= 0.

    Attributes
    ----------
    plant_ : gbo_envs.ContinuousPlant
        Linear part with its delay (without the ``time_delay`` effect).
    effects_ : tuple of EffectBlock
        Fitted effect blocks, in the order the twin's loop applies them
        (:class:`agents.twin.TwinEnv`); after an actuator effect, an ``offset`` block with
        the median plant-input bias and a saturation limit raised to hold every rest level.
    effect_params_ : dict
        ``{effect: {parameter: value}}``.
    greybox_ : GreyFit
        The grey-box fit (parameters, rest levels, biases, simulated outputs).
    num_, den_, params_, param_names_, delay_
        Linear part as in :class:`agents.twin.LinearTwin`.
    rmse_ : float
        Eq. (RMSE) on the fitted data, normalised by each record's step height ``|r2 - y0|``.
        For a position output it is taken on the increments of the error
        (:func:`agents.twin.least_squares.output_error`), as the fit is: a replayed slider that
        sticks a moment earlier than the plant's stays off for the rest of the record, an
        offset the twin's closed loop, whose controller sees it, does not keep.
    rmse_abs_ : float
        The same in the units of ``y``.
    rest_levels_ : ndarray of shape (n_records, 2)
        Rest level of ``y`` and rest command of each record.
    n_records_, n_samples_ : int
        Records fitted and samples of the longest.
    dt_ : float
        Sample time in s.

    Examples
    --------
    >>> import gymnasium as gym, numpy as np, gbo_envs
    >>> env = gym.make("gbo_envs/DCMotor-v0", effects={"saturation": {"limit": 150.0}}, output_noise_std=0.05)
    >>> _ = env.reset(seed=2)
    >>> rng = np.random.default_rng(2)
    >>> records = [env.step(rng.uniform(env.action_space.low, env.action_space.high))[4] for _ in range(2)]
    >>> twin = GreyBoxTwin(effects=["saturation"]).fit(records)
    >>> bool(abs(twin.effect_params_["saturation"]["limit"] - 150.0) < 3.0)
    True
    """

    _parameter_constraints: ClassVar[dict[str, list]] = {
        "effects": [InstanceOf((list, tuple, dict, str))],
        "n_poles": linear_constraints()["n_poles"],
        "n_zeros": linear_constraints()["n_zeros"],
        "n_integrators": linear_constraints()["n_integrators"],
        "output": [Options(("speed", "position"))],
        "n_samples": linear_constraints()["n_samples"],
        "max_iter": [Interval(int, 0, None)],
    }

    def __init__(self, effects=(), *, n_poles: int = 2, n_zeros: int = 0, n_integrators: int = 0,
                 output: str = "speed", n_samples: int | None = None, max_iter: int = 25) -> None:
        self.effects = effects
        self.n_poles = n_poles
        self.n_zeros = n_zeros
        self.n_integrators = n_integrators
        self.output = output
        self.n_samples = n_samples
        self.max_iter = max_iter

    @single_thread()
    def fit(self, records, y=None) -> GreyBoxTwin:
        """Fit the linear part and the effect parameters to closed-loop records.

        Parameters
        ----------
        records : Batch, mapping, sequence of mappings or of arrays (n_steps, 4), or DataFrame
            Experiment records with ``t, r, u, y`` (see :func:`agents.twin.records.as_records`),
            or an :class:`agents.twin.records.Batch` stacked with this twin's ``n_samples``
            (:func:`agents.twin.records.as_batch`).
        y : None
            Ignored (scikit-learn signature).

        Returns
        -------
        self

        Raises
        ------
        ValueError
            A parameter outside its allowed range (named), an effect outside the catalogue, or bad records.
        """
        params = self._validate_params()
        orders = check_orders(params["n_poles"], params["n_zeros"], params["n_integrators"])
        data = self._data(records)
        spec = ModelSpec(orders.n, orders.m, orders.k, params["output"])
        self._store(data, fit_structure(data, params["effects"], spec, max_iter=params["max_iter"]))
        return self

    @classmethod
    def from_fit(cls, fit: GreyFit, data: Batch, n_samples: int | None = None, max_iter: int = 25) -> GreyBoxTwin:
        """A fitted twin from a grey-box fit already made on ``data`` (e.g. a diagnosis's), without refitting.

        Its ``effects`` are the fit's effect values, so ``clone(twin).fit(records)`` starts from them;
        ``n_samples`` and ``max_iter`` are stored as given (they apply to later ``fit`` and ``score`` calls).
        """
        spec = fit.spec
        twin = cls(effects=dict(fit.effect_params), n_poles=spec.n_poles, n_zeros=spec.n_zeros,
                   n_integrators=spec.n_integrators, output=spec.output, n_samples=n_samples, max_iter=max_iter)
        twin._store(data, fit)
        return twin

    @single_thread()
    def predict(self, records) -> list[np.ndarray]:
        """Simulated outputs of the fitted model, with only each record's rest level and bias fitted.

        Returns
        -------
        list of ndarray of shape (n_steps,)
            In the units of ``y``.
        """
        data, fit = self._refit_rest(records)
        return [fit.y_sim[k][data.mask[k]] for k in range(data.n_records)]

    @single_thread()
    def score(self, records, y=None) -> float:
        """Negative eq. (RMSE) of the fitted model on ``records``, normalised by each record's step height.

        Higher is better (scikit-learn's convention, as its ``neg_root_mean_squared_error``):
        0 is a perfect replay, ``-0.01`` an RMS error of 1 % of the step height. Only the
        records' rest levels and biases are fitted.

        Returns
        -------
        float
            Dimensionless, ``<= 0``.
        """
        data, fit = self._refit_rest(records)
        return -_normalised_rmse(data, fit)

    def _data(self, records) -> Batch:
        """The records stacked (decimated to ``n_samples``; their :attr:`~gbo_envs.Experiment.index` kept)."""
        return as_batch(records, self.n_samples)

    def _store(self, data: Batch, fit: GreyFit) -> None:
        spec = fit.spec
        nl = spec.n_linear
        nb = spec.n_zeros + 1
        self.greybox_ = fit
        self.num_ = np.asarray(fit.theta[:nb], dtype=float)
        self.den_ = np.concatenate([[1.0], fit.theta[nb:nl], np.zeros(spec.n_integrators)])
        self.params_ = np.asarray(fit.theta[:nl], dtype=float)
        self.param_names_ = tuple(spec.global_names()[:nl])
        self.delay_ = float(fit.theta[nl])
        self.plant_ = fit.plant
        blocks = fit.blocks
        rest = rest_command(fit)
        if any(b.side == "actuator" for b in blocks):  # the plant-input bias matters after a nonlinearity
            blocks = blocks + (build_effect("offset", {"value": float(np.median(fit.bias))}),)
            # the twin's loop must be able to hold the rest levels of the data: a limit below the largest
            # fitted rest command (a poorly determined rest on few or short records) is raised to it
            need = 1.02 * float(np.max(np.abs(rest)))
            blocks = tuple(build_effect("saturation", {"limit": need}) if b.name == "saturation" and b.limit < need
                           else b for b in blocks)
        self.effects_ = blocks
        self.effect_params_ = fit.effect_params
        self.rmse_abs_ = float(fit.rmse)
        self.rmse_ = _normalised_rmse(data, fit)
        self.rest_levels_ = np.column_stack([fit.y0, rest])
        self.n_records_ = data.n_records
        self.n_samples_ = int(data.u.shape[1])
        self.dt_ = float(data.dt)

    def _refit_rest(self, records) -> tuple[Batch, GreyFit]:
        """The fitted model on new records: only their rest levels and biases are fitted."""
        check_is_fitted(self)
        data = self._data(records)
        fit = self.greybox_
        rows = np.arange(data.n_records)
        y0 = data.y[:, 0].copy()
        bias = self._rest_bias_start(data, y0)
        problem = make_problem(data, fit.spec, fit.theta, y0, bias, rows, free_global=False)
        fit_problems(data, [problem], max_iter=10)
        return data, problem.fit(data)

    def _rest_bias_start(self, data: Batch, y0: np.ndarray) -> np.ndarray:
        """Each new record's starting plant-input bias: the better replay of two guesses.

        The bias that puts the linear part at equilibrium under the record's first command, or the
        median bias of the fitted records (the drive's offset, common to all experiments). After dry
        friction or a dead zone the error is flat in a bias inside the stiction band, so a
        least-squares refit keeps whichever start it is given: on LinearMotorRig-v0 the first
        guess left the fitted model's error on its own records at 5 to 10 times its ``rmse_``.
        """
        fit = self.greybox_
        rows = np.arange(data.n_records)
        at_rest = fit.plant.discretize(data.dt).equilibrium(y0)[1] - data.u[:, 0]
        starts = [at_rest, np.full(data.n_records, float(np.median(fit.bias)))]
        sims = simulate_sets(data, [(fit.spec, np.concatenate([fit.theta, y0, b]), rows) for b in starts])
        costs = [np.sum(output_error(data.y, y, data.mask, fit.spec, data.closed_loop) ** 2, axis=1) for y in sims]
        costs = [np.where(np.isfinite(c), c, np.inf) for c in costs]
        return np.where(costs[1] < costs[0], starts[1], starts[0])


def _normalised_rmse(data: Batch, fit: GreyFit) -> float:
    """Eq. (RMSE) of ``fit`` on ``data`` normalised by each record's step height ``|r2 - y0|``."""
    height = np.abs(data.r[np.arange(data.n_records), data.mask.sum(axis=1) - 1] - fit.y0)
    return rmse(output_error(data.y, fit.y_sim, data.mask, fit.spec, data.closed_loop), mask=data.mask, height=height)
