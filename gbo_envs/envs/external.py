"""Bring your own plant: a Gymnasium env around a function that runs one experiment on your rig."""

from __future__ import annotations

import dataclasses
import logging
import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from gbo_envs.closed_loop import UNSTABLE_LIMIT, ClosedLoop
from gbo_envs.controllers import Controller
from gbo_envs.envs.base import NORMALIZER_FLOOR, ControllerTuningEnv
from gbo_envs.envs.cost_spec import CostSpec
from gbo_envs.envs.rig_options import FAILURE_POLICIES, FailurePolicy, StepExperiment
from gbo_envs.experiment import SIGNALS, Experiment, validate_signals
from gbo_envs.metrics import METRIC_NAMES, step_metrics

__all__ = ["ExperimentFailed", "ExternalLoop", "ExternalPlantEnv", "FAILURE_POLICIES", "PlantStructure"]

_COST, _FAILURE_POLICY = CostSpec(), FailurePolicy()  # defaults of ExternalPlantEnv (frozen)

_log = logging.getLogger(__name__)


class ExperimentFailed(RuntimeError):
    """An experiment on the external plant failed (``on_failure="stop"`` or ``"skip"``).

    Attributes
    ----------
    reason : str
        What went wrong (the exception raised, the timeout, the malformed array).
    record : dict
        The failed experiment's record (``gains``, ``failed=True``,
        ``failure_reason``, ``experiment_index``, and the arrays when usable).
    policy : str
        ``"stop"`` (end the session) or ``"skip"`` (propose again without telling the tuner).
    """

    def __init__(self, reason: str, record: dict, policy: str) -> None:
        number = record.get("experiment_index")
        number = number + 1 if isinstance(number, int) else number  # counted from 1, as everywhere a person reads it
        super().__init__(f"experiment {number} at gains {list(record.get('gains', []))} "
                         f"failed: {reason} (on_failure={policy!r})")
        self.reason = reason
        self.record = record
        self.policy = policy


@dataclass(frozen=True)
class PlantStructure:
    """What a twin must know of an unknown plant: what ``y`` measures and its poles at ``s = 0``.

    Parameters
    ----------
    output : {"speed", "position"}, default "speed"
        What the measured output ``y`` is.
    n_integrators : int, default 0
        Known poles at ``s = 0``, ``>= 0`` (1 for a position loop driven by a force or current).

    Stands in ``ExternalLoop.plant`` for a :class:`~gbo_envs.physics.lti.ContinuousPlant`
    (same ``output``, and ``num``/``den`` that carry only the integrators).
    """

    output: str = "speed"
    n_integrators: int = 0

    def __post_init__(self) -> None:
        if self.output not in ("speed", "position") or isinstance(self.n_integrators, bool) \
                or int(self.n_integrators) != self.n_integrators or self.n_integrators < 0:
            raise ValueError(f"output, n_integrators: expected 'speed' or 'position' and an integer >= 0, got "
                             f"{self.output!r}, {self.n_integrators!r}")
        object.__setattr__(self, "n_integrators", int(self.n_integrators))

    @property
    def num(self) -> tuple[float, ...]:
        """``(1.0,)``: the gain is unknown."""
        return (1.0,)

    @property
    def den(self) -> tuple[float, ...]:
        """``(1, 0, ..., 0)`` with ``n_integrators`` zeros: only the poles at ``s = 0`` are known."""
        return (1.0,) + (0.0,) * self.n_integrators


@dataclass(frozen=True, eq=False)
class ExternalLoop:
    """What is known of an external loop: controller, sampling and the step experiment, but no plant model.

    It stands where a built-in env has its :class:`~gbo_envs.closed_loop.ClosedLoop`
    (``env.unwrapped.loop``), so that code reading ``controller``, ``dt``,
    ``duration``, ``r1``, ``r2``, ``plant.output`` works unchanged, and ``replace(plant=model)``
    returns a simulatable :class:`ClosedLoop` of the same controller and
    experiment around an identified model: that is how a digital twin is built.
    It needs ``controller`` (a :class:`~gbo_envs.controllers.PIController` or
    :class:`~gbo_envs.controllers.PDT1Controller`), ``dt`` and ``duration``.
    """

    controller: Controller
    dt: float | None
    duration: float | None
    r1: float
    r2: float
    plant: PlantStructure = PlantStructure()
    effects: tuple = ()
    output_noise_std: float = 0.0
    experiment_index: int = 0

    @property
    def can_simulate(self) -> bool:
        """Whether a model loop can be built (a concrete controller, ``dt`` and ``duration`` known)."""
        return type(self.controller) is not Controller and self.dt is not None and self.duration is not None

    @property
    def n_steps(self) -> int:
        """Samples per experiment, ``round(duration / dt) + 1``."""
        if self.dt is None or self.duration is None:
            raise ValueError("ExternalPlantEnv: pass dt and duration to know the number of samples")
        return int(round(self.duration / self.dt)) + 1

    @property
    def time(self) -> np.ndarray:
        """Nominal sample times of shape (n_steps,) in s."""
        return np.arange(self.n_steps) * float(self.dt)

    @property
    def step_height(self) -> float:
        """``r2 - r1`` in output units."""
        return self.r2 - self.r1

    def metrics(self, response) -> np.ndarray:
        """Metrics of shape (batch, 4) of a response, as :meth:`ClosedLoop.metrics`."""
        return response.metrics(self.r1, self.r2)

    def at_experiment(self, index: int) -> ExternalLoop:
        """The loop at experiment ``index`` (the real plant changes by itself: no model to update)."""
        return self

    def replace(self, **changes) -> ExternalLoop | ClosedLoop:
        """Copy with fields replaced; with ``plant=model`` a :class:`ClosedLoop` around that model.

        Raises
        ------
        ValueError
            If a plant is given but the controller, ``dt`` or ``duration`` is unknown.
        """
        plant = changes.pop("plant", None)
        if plant is None or isinstance(plant, PlantStructure):
            return dataclasses.replace(self, **changes, **({} if plant is None else {"plant": plant}))
        if not self.can_simulate:
            raise ValueError("ExternalPlantEnv: a model loop (digital twin) needs controller=PIController() or "
                             "PDT1Controller(...), dt and duration")
        fields = {"controller": self.controller, "dt": float(self.dt), "duration": float(self.duration),
                  "r1": self.r1, "r2": self.r2, "effects": self.effects, "output_noise_std": self.output_noise_std,
                  "experiment_index": self.experiment_index}
        fields.update(changes)
        return ClosedLoop(plant=plant, **fields)


class ExternalPlantEnv(ControllerTuningEnv):
    """A tuning session on your own hardware: one ``step`` calls your function for one step experiment.

    ## Description

    ``run_experiment(gains) -> (t, r, u, y)`` sets the controller gains on the
    rig, runs one step experiment and returns its record (docs/design.md,
    "The experiment record"): equal-length 1-D arrays with ``t`` the time since the
    reference step in s (starting at 0, increasing), ``r`` the reference
    (ending at ``r2``), ``u`` the commanded plant input and ``y`` the measured
    output. A mapping with keys ``t, r, u, y`` is accepted too. The env checks
    the record and computes the metrics and the cost exactly as the built-in
    envs do (:func:`~gbo_envs.metrics.step_metrics`, then
    :meth:`ControllerTuningEnv.cost`), so every tuner runs on it unchanged.
    No noise is added: the rig's own noise is in the data.

    ## Action Space

    ``Box(low, high)`` from ``gain_bounds``, in the units of your controller.

    ## Observation Space, Rewards, Episode End

    As :class:`ControllerTuningEnv`: reward ``-J``; ``info`` holds the record
    plus ``gains``, ``metrics``, ``cost``, ``unstable``, ``experiment_index``
    and ``failed`` (no ``true_cost``: the noise-free cost of a real plant is
    unknown), and ``info["experiment"]``, the same as one
    :class:`~gbo_envs.experiment.Experiment`. The record of a failed experiment has no ``t, r, u, y`` (so a
    twin never fits on it) but ``failure_reason``. A response leaving ``r2 +- 100 |r2 - r1|`` is ``unstable`` and
    costs ``unstable_cost``, as in the built-in envs.

    ## Faults

    An experiment fails when the function raises, exceeds ``timeout_s``, or
    returns a malformed record (not four arrays, unequal lengths, fewer than
    3 samples, NaN/inf, ``t`` not increasing or not starting at 0, a sample
    time more than ``dt_rtol`` off ``dt``, a length more than one sample off
    ``duration``, ``r`` not ending at ``r2``). The failure is logged (warning),
    appended to :attr:`failures`, and handled by ``on_failure``:

    * ``"penalize"`` (default): ``step`` returns ``cost = failure_cost`` with
      ``info["failed"] = True`` and ``info["failure_reason"]``; the tuner learns
      the penalty and the session goes on.
    * ``"stop"``: ``step`` raises :class:`ExperimentFailed` (carrying the record);
      the tuning loop (:meth:`agents.Tuner.run`, a ``gbo tune`` session) records it and stops.
    * ``"skip"``: ``step`` raises :class:`ExperimentFailed` with
      ``policy="skip"``; the tuning loop records it and asks the tuner again
      without telling it.

    The experiment counter counts every attempt, failed ones included.

    **Timeouts.** With ``timeout_s`` the function runs in a daemon worker
    thread. A Python thread cannot be killed: after a timeout the call keeps
    running in the background until it returns by itself, so the rig may
    still be moving. The next ``step`` therefore waits up to ``timeout_s`` for
    it and, if it is still running, fails without touching the rig ("rig
    busy"). Make the hardware call itself abort on its own deadline if you
    can. Without ``timeout_s`` the function runs in the calling thread.

    ## Arguments

    * ``run_experiment``: the callable above; it receives the gains as a float
      array of shape (n_gains,) in :attr:`gain_names` order.
    * ``gain_bounds``: ``{"Kp": (lo, hi), ...}`` (the keys name the gains) or an array of
      shape (n_gains, 2) (the gains named by ``controller``, else ``gain_0, gain_1, ...``).
    * ``experiment``: the step experiment, a :class:`~gbo_envs.envs.rig_options.StepExperiment`:
      ``reference=(r1, r2)``, the reference before and after the step, and ``dt``, ``duration``,
      the sample time and experiment length in s. ``dt`` and ``duration`` are optional for
      tuning; a digital twin (guided BO, the twin workbench) needs them, and ``controller``,
      to simulate the loop, via ``env.unwrapped.loop.replace(plant=model)`` (:class:`ExternalLoop`).
      They also enable the record checks above.
    * ``controller``: the controller structure (:class:`~gbo_envs.controllers.PIController`,
      :class:`~gbo_envs.controllers.PDT1Controller`); optional for tuning.
    * ``gain_units``: the units of the gains when there is no ``controller`` (default ``"-"``).
    * ``cost``: the cost of eq. (J_used), a :class:`~gbo_envs.envs.cost_spec.CostSpec`:
      ``weights`` (default: the paper's DC motor 0.44, 0.22, 0.22, 0.11), ``unstable_cost``,
      and the metric normalisers ``n_i`` (``normalizers``).
    * ``reference_gains``: without ``cost.normalizers``, gains of shape (n_ref, n_gains) at
      which the normalisers are *measured* as the mean metrics of one experiment per row, run
      on the plant when the env is built. That costs n_ref real experiments (kept in
      :attr:`reference_records`) every time the env is built, and their noise makes the cost
      scale differ between builds: measure once, then pass the printed ``env.normalizers`` as
      ``cost=CostSpec(normalizers=...)`` (a resumed session requires the same normalisers).
    * ``failure_policy``: when an experiment has failed and what follows, a
      :class:`~gbo_envs.envs.rig_options.FailurePolicy`: ``on_failure`` (``"penalize"``,
      ``"stop"`` or ``"skip"``), ``failure_cost`` (reported under ``"penalize"``, default
      the ``unstable_cost``), ``timeout_s`` (wall-time limit of one experiment in s, None: no
      limit) and ``dt_rtol`` (allowed relative error of the median sample time, default 0.05).
    * ``plant``: what ``y`` measures (``"speed"`` or ``"position"``) and the plant's known
      poles at ``s = 0`` (1 for a position loop driven by a force or current), for the
      twin's model structure (:class:`PlantStructure`).
    * ``max_experiments``, ``out_of_bounds``: as in :class:`ControllerTuningEnv`.

    The machine's limits are set after construction, ``env.constraints = {"overshoot_pct": 2.0,
    "peak_u": 140.0}`` (:attr:`ControllerTuningEnv.constraints`); every step then reports
    ``info["constraints"]`` and ``info["feasible"]``, and a failed experiment is infeasible (its
    values are NaN).

    Examples
    --------
    >>> import numpy as np
    >>> from gbo_envs import CostSpec, ExternalPlantEnv, FailurePolicy, PIController, StepExperiment
    >>> def rig(gains):  # a stand-in for the hardware: a first-order response to the step 0 -> 1
    ...     t = np.arange(501) * 0.01
    ...     return t, np.ones_like(t), np.ones_like(t), 1.0 - np.exp(-t * gains[0])
    >>> env = ExternalPlantEnv(rig, {"Kp": (1.0, 5.0), "Ki": (0.5, 2.0)}, controller=PIController(),
    ...                        experiment=StepExperiment((0.0, 1.0), dt=0.01, duration=5.0),
    ...                        cost=CostSpec(normalizers=(1.0, 1.0, 1.0, 1.0)),
    ...                        failure_policy=FailurePolicy(on_failure="stop", timeout_s=10.0))
    >>> info = env.step(np.array([2.0, 1.0]))[4]
    >>> info["failed"], round(info["metrics"]["rise_time"], 2)
    (False, 0.41)

    ## Version History

    * v0: initial version (not registered: build it directly, or register it
      with ``gymnasium.register`` in your own module).
    """

    metadata = {"render_modes": [], "render_fps": 1}

    def __init__(
        self,
        run_experiment: Callable[[np.ndarray], Any],
        gain_bounds,
        *,
        experiment: StepExperiment,
        controller: Controller | None = None,
        gain_units=None,
        cost: CostSpec = _COST,
        reference_gains=None,
        failure_policy: FailurePolicy = _FAILURE_POLICY,
        plant: PlantStructure = PlantStructure(),
        max_experiments: int = 35,
        out_of_bounds: str = "raise",
        render_mode: str | None = None,
    ) -> None:
        if not callable(run_experiment):
            raise TypeError(f"run_experiment: expected a callable (gains) -> (t, r, u, y), got {run_experiment!r}")
        for name, value, kind in (("experiment", experiment, StepExperiment), ("cost", cost, CostSpec),
                                  ("failure_policy", failure_policy, FailurePolicy), ("plant", plant, PlantStructure)):
            if not isinstance(value, kind):
                raise TypeError(f"{name}: expected a {kind.__name__}, got {value!r}")
        self.run_experiment = run_experiment
        names, low, high = _bounds(gain_bounds, controller)
        if controller is None:
            units = tuple(gain_units) if gain_units is not None else ("-",) * len(names)
            controller = Controller(gain_names=names, gain_units=units)
        elif tuple(controller.gain_names) != names:
            raise ValueError(f"gain_bounds: the gains {names} differ from the controller's "
                             f"{tuple(controller.gain_names)}")
        self.timeout_s = failure_policy.timeout_s
        self.on_failure = failure_policy.on_failure
        self.failure_cost = cost.unstable_cost if failure_policy.failure_cost is None else failure_policy.failure_cost
        self.dt_rtol = failure_policy.dt_rtol
        #: Failed experiments: dicts with ``experiment_index``, ``gains``, ``reason``.
        self.failures: list[dict] = []
        #: Records of the experiments run to measure the normalisers (empty if ``normalizers`` was given).
        self.reference_records: list[dict] = []
        self._busy: threading.Thread | None = None
        self._busy_index: int | None = None
        self.experiment_index = 0
        loop = ExternalLoop(controller=controller, dt=experiment.dt, duration=experiment.duration,
                            r1=experiment.reference[0], r2=experiment.reference[1], plant=plant)
        self.loop = loop
        if cost.normalizers is None:
            cost = dataclasses.replace(cost, normalizers=self._measure_normalizers(reference_gains, low, high))
        super().__init__(loop=loop, gain_low=low, gain_high=high, cost=cost, max_experiments=max_experiments,
                         out_of_bounds=out_of_bounds, render_mode=render_mode)

    # -- Gymnasium API ---------------------------------------------------------------------------
    def step(self, action):
        """Run one experiment on the external plant at the gains ``action``."""
        gains = self.validate_gains(action)
        index = self.experiment_index
        self.experiment_index += 1
        arrays, reason = self._attempt(gains, index)
        if reason is None:
            metrics, cost, unstable = self.assess(arrays)
            info = {**arrays, "gains": gains.copy(), "metrics": dict(zip(METRIC_NAMES, map(float, metrics))),
                    "cost": cost, "unstable": unstable, "experiment_index": index, "failed": False}
        else:
            self.failures.append({"experiment_index": index, "gains": gains.copy(), "reason": reason})
            _log.warning("external plant: experiment_index=%d at gains %s failed (on_failure=%s): %s", index,
                         gains.tolist(), self.on_failure, reason)
            info = {"gains": gains.copy(), "metrics": {name: float("nan") for name in METRIC_NAMES},
                    "unstable": False, "experiment_index": index, "failed": True, "failure_reason": reason}
            if self.on_failure != "penalize":
                info["experiment"] = Experiment.from_mapping(info, source=self.experiment_source)
                raise ExperimentFailed(reason, info, self.on_failure)
            metrics, cost = np.zeros(len(METRIC_NAMES)), self.failure_cost
            info["cost"] = cost
        info["experiment"] = Experiment.from_mapping(info, source=self.experiment_source)
        info.update(self.constraints.judge(None if info["failed"] else info["experiment"], info["unstable"]))
        self.best_cost = min(self.best_cost, cost)
        self._last_obs = self._observation(gains, metrics, cost)
        return self._last_obs.copy(), -cost, False, False, info

    def render(self):
        """Nothing to render (the record is in ``info``)."""
        return None

    # -- experiment helpers ----------------------------------------------------------------------
    def assess(self, arrays: Mapping[str, np.ndarray]) -> tuple[np.ndarray, float, bool]:
        """Metrics, cost and instability flag of a validated record, as the built-in envs compute them.

        Returns
        -------
        metrics : ndarray of shape (4,)
        cost : float
            ``J`` of eq. (J_used), or ``unstable_cost`` for a diverged response.
        unstable : bool
        """
        loop = self.loop
        y = arrays["y"]
        metrics = step_metrics(arrays["t"], y[None, :], loop.r1, loop.r2)[0]
        unstable = not bool(np.max(np.abs(y - loop.r2)) <= UNSTABLE_LIMIT * abs(loop.step_height))
        cost = self.unstable_cost if unstable else float(self.cost(metrics))
        return metrics, cost, unstable

    def evaluate(self, gains, experiment_index=None):
        """Not available: an external plant has no noise-free model (use a digital twin)."""
        raise NotImplementedError("ExternalPlantEnv.evaluate: a real plant has no noise-free model; "
                                  "identify a digital twin from its records instead")

    def check_record(self, output) -> dict[str, np.ndarray]:
        """Validate what ``run_experiment`` returned.

        Returns
        -------
        dict
            ``t, r, u, y`` as float arrays of shape (n_steps,).

        Raises
        ------
        ValueError
            Naming what is malformed: the generic rules of
            :func:`~gbo_envs.experiment.validate_signals`, then this rig's
            (``t`` starts at 0, sample time ``dt``, ``duration``, ``r`` ends at ``r2``).
        """
        if isinstance(output, Mapping):
            missing = [k for k in SIGNALS if k not in output]
            if missing:
                raise ValueError(f"the record lacks {', '.join(missing)}")
            parts = [output[k] for k in SIGNALS]
        else:
            try:
                parts = list(output)
            except TypeError:
                raise ValueError(f"expected (t, r, u, y), got {type(output).__name__}") from None
            if len(parts) != 4:
                raise ValueError(f"expected 4 arrays (t, r, u, y), got {len(parts)}")
        # copies: the rig's code may reuse its buffers for the next experiment
        arrays = {name: np.array(values) for name, values in validate_signals(*parts).items()}
        t = arrays["t"]
        steps = np.diff(t)
        spacing = float(np.median(steps))
        if abs(t[0]) > 0.5 * spacing:
            raise ValueError(f"t must start at the step (t[0] = 0), got t[0] = {t[0]:g} s")
        loop = self.loop
        if loop.dt is not None and abs(spacing - loop.dt) > self.dt_rtol * loop.dt:
            raise ValueError(f"sample time {spacing:g} s differs from dt = {loop.dt:g} s by more than "
                             f"{100 * self.dt_rtol:g} %")
        if loop.duration is not None and abs(t[-1] - loop.duration) > spacing * (1 + self.dt_rtol):
            raise ValueError(f"the record ends at {t[-1]:g} s, expected duration {loop.duration:g} s")
        r_end = arrays["r"][-1]
        if abs(r_end - loop.r2) > 0.01 * abs(loop.step_height):
            raise ValueError(f"r ends at {r_end:g}, expected the reference r2 = {loop.r2:g}")
        return arrays

    def _attempt(self, gains: np.ndarray, index: int) -> tuple[dict | None, str | None]:
        """Call ``run_experiment`` (in a worker thread under ``timeout_s``); return (arrays, None) or (None, reason)."""
        if self._busy is not None:
            self._busy.join(self.timeout_s)
            if self._busy.is_alive():
                return None, (f"rig busy: experiment {self._busy_index} timed out and its call has not returned; "
                              "not started")
            self._busy = self._busy_index = None
        holder: dict[str, Any] = {}
        argument = gains.copy()
        if self.timeout_s is None:
            try:
                holder["out"] = self.run_experiment(argument)
            except Exception as exc:  # noqa: BLE001 - any error of the user's rig code is a failed experiment
                holder["exc"] = exc
        else:
            def target() -> None:
                try:
                    holder["out"] = self.run_experiment(argument)
                except BaseException as exc:  # noqa: BLE001 - reported to the caller's thread
                    holder["exc"] = exc

            worker = threading.Thread(target=target, name=f"gbo-experiment-{index}", daemon=True)
            worker.start()
            worker.join(self.timeout_s)
            if worker.is_alive():
                self._busy, self._busy_index = worker, index
                return None, f"timed out after {self.timeout_s:g} s (the call keeps running in the background)"
        if "exc" in holder:
            exc = holder["exc"]
            return None, f"run_experiment raised {type(exc).__name__}: {exc}"
        try:
            return self.check_record(holder["out"]), None
        except ValueError as exc:
            return None, f"malformed record: {exc}"

    def _measure_normalizers(self, reference_gains, low: np.ndarray, high: np.ndarray) -> np.ndarray:
        """Mean metrics over one plant experiment per row of ``reference_gains``."""
        if reference_gains is None:
            raise ValueError("ExternalPlantEnv: pass cost=CostSpec(normalizers=(n1, n2, n3, n4)), or reference_gains "
                             "to measure them on the plant (one experiment per row, e.g. np.linspace(low, high, 5))")
        reference = np.atleast_2d(np.asarray(reference_gains, dtype=float))
        if reference.shape[1] != low.size:
            raise ValueError(f"reference_gains: expected shape (n_ref, {low.size}), got {reference.shape}")
        metrics = []
        for i, gains in enumerate(reference):
            arrays, reason = self._attempt(gains, -1 - i)
            if reason is not None:
                raise ValueError(f"reference_gains: the experiment at {gains.tolist()} failed ({reason}); "
                                 "the normalisers cannot be measured")
            self.reference_records.append({**arrays, "gains": gains.copy()})
            r1, r2 = self.loop.r1, self.loop.r2
            metrics.append(step_metrics(arrays["t"], arrays["y"][None, :], r1, r2)[0])
        return np.maximum(np.mean(metrics, axis=0), NORMALIZER_FLOOR)  # a metric never shown still normalises


def _bounds(gain_bounds, controller) -> tuple[tuple[str, ...], np.ndarray, np.ndarray]:
    """Gain names and bounds from a mapping or an (n_gains, 2) array."""
    if isinstance(gain_bounds, Mapping):
        names = tuple(gain_bounds)
        pairs = [gain_bounds[name] for name in names]
    else:
        pairs = gain_bounds
        names = None
    bounds = np.asarray(pairs, dtype=float)
    if bounds.ndim != 2 or bounds.shape[1] != 2:
        raise ValueError(f"gain_bounds: expected (low, high) per gain, got {gain_bounds!r}")
    if names is None:
        if controller is not None:
            names = tuple(controller.gain_names)
        else:
            names = tuple(f"gain_{i}" for i in range(bounds.shape[0]))
    if len(names) != bounds.shape[0]:
        raise ValueError(f"gain_bounds: {bounds.shape[0]} gain bounds for the controller's {len(names)} gains {names}")
    return names, bounds[:, 0].copy(), bounds[:, 1].copy()
