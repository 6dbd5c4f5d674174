"""Time-varying plants: the plant parameters change from one experiment to the next.

A tuner on a real rig meets plants that do not stay put: a motor heats up over
a session (its torque/force constant falls and lubricants thin), or a load is
changed between two experiments. :class:`TimeVaryingMixin` adds such a
*parameter schedule* to any plant env that has a ``plant_params`` dict and a
module-level plant factory; the loop of experiment ``k`` is the initial loop
with the plant rebuilt from the scheduled parameters (all effect blocks,
controller, sampling and experiment stay the same).

Conventions shared by every variant:

* experiment ``k`` counts from 0 within a session; ``reset`` starts a new
  session at ``k = 0``, i.e. restores the initial plant;
* ``info["plant_params"]`` reports the true parameters of the experiment just
  run (for evaluation; a tuner must not use it);
* the cost normalisers are computed once, on the initial plant, and stay
  fixed, so that costs of different experiments are comparable;
* :func:`gbo_envs.ground_truth` and ``evaluate(gains)`` without an index see
  the plant of experiment 0 and of the next experiment respectively;
  ``evaluate(gains, experiment_index=k)`` gives the optimum that moves.

Schedules
---------
:class:`GradualDrift` (eq. below, a first-order thermal approach)::

    p_k = p_0 (1 + rel_change (1 - exp(-k / time_constant)))

:class:`AbruptChange`: ``p_k = p_0`` for ``k < at`` and ``p_k = new`` from
experiment ``at`` on.
"""

from __future__ import annotations

import numbers
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from gbo_envs.closed_loop import ClosedLoop
from gbo_envs.envs.dc_motor import DC_MOTOR, DCMotorEnv
from gbo_envs.envs.linear_motor import LINEAR_MOTOR, LinearMotorEnv
from gbo_envs.physics.lti import ContinuousPlant

__all__ = [
    "AbruptChange",
    "DCMotorDriftEnv",
    "DCMotorStepEnv",
    "GradualDrift",
    "LinearMotorDriftEnv",
    "LinearMotorStepEnv",
    "ParameterSchedule",
    "TimeVaryingMixin",
]


class ParameterSchedule:
    """Plant parameters as a function of the experiment index."""

    def params(self, initial: dict[str, float], index: int) -> dict[str, float]:
        """Parameters at experiment ``index`` (0-based) given those at experiment 0."""
        raise NotImplementedError

    def validate(self, initial: dict[str, float]) -> None:
        """Raise ``ValueError`` if the schedule names a parameter ``initial`` lacks."""


@dataclass(frozen=True)
class GradualDrift(ParameterSchedule):
    """First-order drift towards a new steady state, as a motor heating over a session.

    ``p_k = p_0 (1 + rel_change[p] (1 - exp(-k / time_constant)))``: the
    parameter starts at ``p_0``, moves by ``rel_change[p] / time_constant``
    (relative) per experiment at first, and approaches ``p_0 (1 + rel_change[p])``
    (thermal equilibrium).

    Parameters
    ----------
    rel_change : dict of str to float
        Final relative change of each drifting parameter (e.g. ``{"gain": -0.1}``:
        10 % lower), each ``> -1``.
    time_constant : float
        Time constant in experiments, ``> 0``.
    """

    rel_change: dict[str, float] = field(default_factory=dict)
    time_constant: float = 20.0

    def __post_init__(self) -> None:
        if not isinstance(self.rel_change, dict) or not self.rel_change:
            raise ValueError(f"drift: expected a non-empty dict {{parameter: relative change}}, "
                             f"got {self.rel_change!r}")
        for name, value in self.rel_change.items():
            if not _is_real(value) or not np.isfinite(value) or value <= -1.0:
                raise ValueError(f"drift: relative change of {name!r} must be a finite number > -1, got {value!r}")
        if not _is_real(self.time_constant) or not np.isfinite(self.time_constant) or self.time_constant <= 0.0:
            raise ValueError(f"drift_time_constant: must be > 0 experiments, got {self.time_constant!r}")

    def validate(self, initial: dict[str, float]) -> None:
        _check_names("drift", self.rel_change, initial)

    def progress(self, index: int) -> float:
        """``1 - exp(-k / time_constant)``: fraction of the final change reached at experiment ``k``."""
        return float(-np.expm1(-max(int(index), 0) / self.time_constant))

    def params(self, initial, index):
        done = self.progress(index)
        return {name: value * (1.0 + self.rel_change.get(name, 0.0) * done) for name, value in initial.items()}


@dataclass(frozen=True)
class AbruptChange(ParameterSchedule):
    """Parameters jump to new values at experiment ``at`` and stay there.

    Parameters
    ----------
    at : int
        Index (0-based) of the first experiment run on the changed plant, ``>= 1``.
    new : dict of str to float
        New absolute values of the changing parameters, in the plant's units.
    """

    at: int = 15
    new: dict[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if isinstance(self.at, bool) or not isinstance(self.at, (int, np.integer)) or self.at < 1:
            raise ValueError(f"change_at: must be an integer experiment index >= 1, got {self.at!r}")
        if not isinstance(self.new, dict) or not self.new:
            raise ValueError(f"new_params: expected a non-empty dict {{parameter: value}}, got {self.new!r}")
        for name, value in self.new.items():
            if not _is_real(value) or not np.isfinite(value):
                raise ValueError(f"new_params: value of {name!r} must be finite, got {value!r}")

    def validate(self, initial: dict[str, float]) -> None:
        _check_names("new_params", self.new, initial)

    def params(self, initial, index):
        if index < self.at:
            return dict(initial)
        return {name: float(self.new.get(name, value)) for name, value in initial.items()}


def _is_real(value: Any) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def _check_names(what: str, given: dict[str, float], initial: dict[str, float]) -> None:
    unknown = sorted(set(given) - set(initial))
    if unknown:
        raise ValueError(f"{what}: unknown plant parameter(s) {unknown}; allowed are {tuple(initial)}")


class TimeVaryingMixin:
    """Make a plant env time-varying: mix in before the plant env class.

    The host env must have ``plant_params`` (dict of its plant's parameters,
    set by its ``__init__``) and the class attribute ``plant_factory`` (builds a
    :class:`~gbo_envs.physics.lti.ContinuousPlant` from those parameters). Call
    :meth:`_set_schedule` at the end of ``__init__``.
    """

    plant_factory: Callable[..., ContinuousPlant]
    schedule: ParameterSchedule

    def _set_schedule(self, schedule: ParameterSchedule) -> None:
        schedule.validate(self.plant_params)
        self.plant_factory(**schedule.params(self.plant_params, 10**9))  # the changed plant must be valid
        self.schedule = schedule
        self._loop_cache: tuple[int, ClosedLoop] | None = None

    def plant_params_at(self, index: int) -> dict[str, float]:
        """True plant parameters at experiment ``index`` (0-based)."""
        return self.schedule.params(self.plant_params, index)

    def loop_for_experiment(self, index: int) -> ClosedLoop:
        """The initial loop with the plant of experiment ``index``.

        Plant-side effect blocks given through ``effects`` (``time_delay``,
        ``drift``) still apply, on top of the scheduled plant.
        """
        if self._loop_cache is not None and self._loop_cache[0] == index:
            return self._loop_cache[1]
        params = self.plant_params_at(index)
        loop = self.loop if params == self.plant_params else self.loop.replace(plant=self.plant_factory(**params))
        loop = loop.at_experiment(index)
        self._loop_cache = (index, loop)
        return loop

    def extra_info(self, index: int) -> dict[str, Any]:
        """``{"plant_params": {name: value}}``, the true parameters of experiment ``index``."""
        return {"plant_params": self.plant_params_at(index)}


# -- DC motor ---------------------------------------------------------------------------------------

#: Default drift of the DC motor: torque constant (and so the gain) 10 % down when hot.
DC_DRIFT = {"gain": -0.10}
#: Default load change of the DC motor: 25 % more inertia, gain and tau2 scale by 1/1.25.
DC_STEP = {"gain": DC_MOTOR["gain"] / 1.25, "tau2": DC_MOTOR["tau2"] / 1.25}


class DCMotorDriftEnv(TimeVaryingMixin, DCMotorEnv):
    """The DC motor of ``DCMotor-v0`` heating up over the session: its gain falls gradually.

    ## Description

    As ``gbo_envs/DCMotor-v0``, but the plant gain ``L`` drifts as the motor
    warms up: ``L_k = L_0 (1 - 0.10 (1 - exp(-k / 20)))`` at experiment ``k``
    (0-based). The permanent magnets lose flux with temperature (about
    -0.1 %/K to -0.2 %/K), so the torque constant, and with it ``L``, falls
    by 10 % at thermal equilibrium (a 50-100 K rise); with a thermal time
    constant of 20 experiments the gain is 0.49 % lower at experiment 1,
    3.9 % at experiment 10 and 7.8 % at experiment 30. ``tau1``,
    ``tau2`` and the delay stay as identified. Other parameters can drift too
    (``drift`` kwarg).

    ## Action Space, Observation Space, Rewards, Episode End

    As ``DCMotor-v0``; the cost normalisers stay those of the initial plant.
    ``info["plant_params"]`` holds the true ``gain, tau1, tau2, delay`` of the
    experiment just run. ``reset`` restores the initial (cold) plant.

    ## Arguments

    Those of ``DCMotor-v0``, plus:

    * ``drift``: dict ``{parameter: final relative change}``, default
      ``{"gain": -0.10}``; parameters among ``gain, tau1, tau2, delay``.
    * ``drift_time_constant``: thermal time constant in experiments, default 20.

    ## Version History

    * v0: initial version.
    """


    def __init__(self, drift: dict[str, float] | None = None, drift_time_constant: float = 20.0, **kwargs) -> None:
        super().__init__(**kwargs)
        self._set_schedule(GradualDrift(rel_change=dict(DC_DRIFT if drift is None else drift),
                                        time_constant=float(drift_time_constant)))


class DCMotorStepEnv(TimeVaryingMixin, DCMotorEnv):
    """The DC motor of ``DCMotor-v0`` with a load change at a given experiment.

    ## Description

    As ``gbo_envs/DCMotor-v0`` up to experiment ``change_at - 1``; from
    experiment ``change_at`` (0-based, default 15) on, a load that adds 25 % to
    the rotor inertia is coupled to the shaft. In
    ``G(s) = L / (s^2 + tau1 s + tau2)`` both ``L`` and ``tau2`` are inversely
    proportional to the inertia, so they become ``9.544 / 1.25 = 7.635`` and
    ``4.199 / 1.25 = 3.359``; ``tau1`` is kept (the identified model does not
    separate its mechanical and electrical parts). Any other change is
    given as absolute values through ``new_params``.

    ## Action Space, Observation Space, Rewards, Episode End

    As ``DCMotor-v0``; the cost normalisers stay those of the initial plant.
    ``info["plant_params"]`` holds the true ``gain, tau1, tau2, delay`` of the
    experiment just run. ``reset`` restores the initial plant.

    ## Arguments

    Those of ``DCMotor-v0``, plus:

    * ``change_at``: first experiment (0-based) on the changed plant, default 15.
    * ``new_params``: dict of new absolute values among ``gain`` (rad/s^3 per
      controller unit), ``tau1`` (1/s), ``tau2`` (1/s^2), ``delay`` (s);
      default ``{"gain": 7.635, "tau2": 3.359}``.

    ## Version History

    * v0: initial version.
    """


    def __init__(self, change_at: int = 15, new_params: dict[str, float] | None = None, **kwargs) -> None:
        super().__init__(**kwargs)
        self._set_schedule(AbruptChange(at=change_at, new=dict(DC_STEP if new_params is None else new_params)))


# -- linear motor -----------------------------------------------------------------------------------

#: Default drift of the linear motor: force constant 6 % down, guide damping 25 % down when warm.
LM_DRIFT = {"gain": -0.06, "damping": -0.25}
#: Default payload change of the linear motor: 30 % more moving mass.
LM_STEP = {"inertia": LINEAR_MOTOR["inertia"] * 1.3}


class LinearMotorDriftEnv(TimeVaryingMixin, LinearMotorEnv):
    """The linear motor of ``LinearMotor-v0`` warming up over the session.

    ## Description

    As ``gbo_envs/LinearMotor-v0``, but two parameters drift with the
    temperature of the motor and guide, ``p_k = p_0 (1 + d (1 - exp(-k / 10)))``
    at experiment ``k`` (0-based):

    * ``gain`` (force constant over mass), ``d = -0.06``: the magnets lose
      flux as they warm (6 % at equilibrium);
    * ``damping``, ``d = -0.25``: the guide's lubricant thins as it warms, so
      the viscous drag falls from 0.8 to 0.6 (25 %).

    With a time constant of 10 experiments, at experiment 1 the gain has
    fallen by 0.57 % and the damping by 2.4 %; at experiment 10 by 3.8 % and
    15.8 %; at experiment 24 (the last of a 25-experiment session) by 5.5 % and
    22.7 %. The current limit, sensor and delay stay.

    ## Action Space, Observation Space, Rewards, Episode End

    As ``LinearMotor-v0``; the cost normalisers stay those of the initial
    plant. ``info["plant_params"]`` holds the true ``gain, inertia, damping,
    delay`` of the experiment just run. ``reset`` restores the initial plant.

    ## Arguments

    Those of ``LinearMotor-v0``, plus:

    * ``drift``: dict ``{parameter: final relative change}``, default
      ``{"gain": -0.06, "damping": -0.25}``; parameters among ``gain, inertia,
      damping, delay``.
    * ``drift_time_constant``: thermal time constant in experiments, default 10.

    ## Version History

    * v0: initial version.
    """


    def __init__(self, drift: dict[str, float] | None = None, drift_time_constant: float = 10.0, **kwargs) -> None:
        super().__init__(**kwargs)
        self._set_schedule(GradualDrift(rel_change=dict(LM_DRIFT if drift is None else drift),
                                        time_constant=float(drift_time_constant)))


class LinearMotorStepEnv(TimeVaryingMixin, LinearMotorEnv):
    """The linear motor of ``LinearMotor-v0`` with a payload mounted at a given experiment.

    ## Description

    As ``gbo_envs/LinearMotor-v0`` up to experiment ``change_at - 1``; from
    experiment ``change_at`` (0-based, default 10) on, a payload (e.g. a
    screwdriver head) adds 30 % to the moving mass: ``inertia`` becomes
    ``0.070983 * 1.3 = 0.092278``, so a given current accelerates the slider
    1.3 times less (4.80 instead of 6.24 m/s^2 per A). Any other change is
    given as absolute values through ``new_params``.

    ## Action Space, Observation Space, Rewards, Episode End

    As ``LinearMotor-v0``; the cost normalisers stay those of the initial
    plant. ``info["plant_params"]`` holds the true ``gain, inertia, damping,
    delay`` of the experiment just run. ``reset`` restores the initial plant.

    ## Arguments

    Those of ``LinearMotor-v0``, plus:

    * ``change_at``: first experiment (0-based) on the changed plant, default 10.
    * ``new_params``: dict of new absolute values among ``gain``, ``inertia``,
      ``damping`` (coefficients of ``G(s) = gain / (inertia s^2 + damping s)``)
      and ``delay`` (s); default ``{"inertia": 0.092278}``.

    ## Version History

    * v0: initial version.
    """


    def __init__(self, change_at: int = 10, new_params: dict[str, float] | None = None, **kwargs) -> None:
        super().__init__(**kwargs)
        self._set_schedule(AbruptChange(at=change_at, new=dict(LM_STEP if new_params is None else new_params)))
