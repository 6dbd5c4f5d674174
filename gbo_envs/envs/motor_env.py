"""The one constructor of the built-in motor envs: a family's plant model under its controller, from its calibration.

A family (:class:`~gbo_envs.envs.dc_motor.DCMotorEnv`, :class:`~gbo_envs.envs.linear_motor.LinearMotorEnv`)
names its calibration, its plant model and its option objects; a variant of its loop
(:class:`~gbo_envs.envs.dc_motor_pid.DCMotorPIDEnv`,
:class:`~gbo_envs.envs.linear_motor_cascade.LinearMotorCascadeEnv`) changes the controller, the reference
gains and the calibration's feasible set. Everything else, and the settings every motor env takes, is here.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from typing import Any, ClassVar

import numpy as np

from gbo_envs.closed_loop import ClosedLoop
from gbo_envs.envs.base import ControllerTuningEnv
from gbo_envs.envs.cost_spec import CostSpec
from gbo_envs.envs.plant_options import ENV_NOISE, MeasurementNoise, grouped
from gbo_envs.physics.effects import build_effects
from gbo_envs.physics.lti import ContinuousPlant

__all__ = ["MotorEnv"]


class MotorEnv(ControllerTuningEnv):
    """A built-in motor env: the loop of :attr:`calibration` around :attr:`plant_factory`'s plant.

    A family defines ``_controller(options)`` (the loop's controller from its option objects) and
    ``_reference_gains(low, high)`` (the gains whose mean metrics normalise the cost).

    Parameters
    ----------
    options : dict of str to option object
        The family's option objects (``plant`` and, for the linear motor, ``drive``), given by its constructor.
    noise : bool, default True
        ``False`` gives the noise-free plant (both noise sources 0).
    measurement_noise : MeasurementNoise, optional
        The noise levels (default: the calibration's ``cost_noise_std`` and ``output_noise_std``).
    effects : dict, optional
        Effect blocks ``{name: {param: value}}`` (:func:`gbo_envs.physics.effects.build_effects`).
    out_of_bounds : {"raise", "clip", "allow"}, default "raise"
        What ``step`` does with gains outside the feasible set.
    unstable_cost : float, default 10.0
        Finite cost of a diverging experiment.
    render_mode : {None, "rgb_array"}, default None
    expectation_draws, expectation_seed : int, default 16 and 0
        The ``K`` fixed noise draws (and their seed) over which the ground truth averages when the
        measurement is noisy (``output_noise_std > 0``); unused otherwise.
    normalizers : array_like of shape (4,), optional
        Explicit cost normalisers (a digital twin reuses its plant's); default: the mean metrics at
        the family's reference gains.
    constraints : mapping, optional
        Upper limits the experiments must keep, e.g. ``{"overshoot_pct": 2.0, "peak_u": 140.0}``
        (:mod:`gbo_envs.constraints`); ``info["constraints"]`` and ``info["feasible"]``.
    **settings
        Fields of ``measurement_noise`` and of the option objects, by name
        (:func:`~gbo_envs.envs.plant_options.grouped`).
    """

    #: ``dt, duration, r1, r2`` of the step, ``gain_low, gain_high, weights, max_experiments`` and the default
    #: ``cost_noise_std, output_noise_std`` of a family (or of a variant of its loop).
    calibration: ClassVar[Mapping[str, Any]]
    #: The plant model from its parameters (``plant_params``: the fields of the ``plant`` option).
    plant_factory: Callable[..., ContinuousPlant]

    def __init__(self, *, options: dict, noise: bool = True, measurement_noise: MeasurementNoise = ENV_NOISE,
                 effects=None, out_of_bounds: str = "raise", unstable_cost: float = 10.0,
                 render_mode: str | None = None, normalizers=None, expectation_draws: int = 16,
                 expectation_seed: int = 0, constraints=None, **settings) -> None:
        options = grouped(type(self).__name__, settings, measurement_noise=measurement_noise, **options)
        calibration = self.calibration
        cost_noise_std, output_noise_std = options.pop("measurement_noise").levels(calibration, noise)
        self.plant_params = dataclasses.asdict(options["plant"])
        loop = ClosedLoop(
            plant=self.plant_factory(**self.plant_params),
            controller=self._controller(options),
            dt=calibration["dt"],
            duration=calibration["duration"],
            r1=calibration["r1"],
            r2=calibration["r2"],
            effects=self._effects(options, effects),
            output_noise_std=output_noise_std,
        )
        low, high = np.array(calibration["gain_low"]), np.array(calibration["gain_high"])
        super().__init__(
            loop=loop,
            gain_low=low,
            gain_high=high,
            cost=CostSpec(weights=calibration["weights"], normalizers=normalizers, unstable_cost=unstable_cost),
            reference_gains=self._reference_gains(low, high),
            cost_noise_std=cost_noise_std,
            max_experiments=calibration["max_experiments"],
            out_of_bounds=out_of_bounds,
            render_mode=render_mode,
            noise=noise,
            expectation_draws=expectation_draws,
            expectation_seed=expectation_seed,
        )
        self.constraints = constraints

    def _effects(self, options: dict, effects) -> tuple:
        """The loop's effect blocks: ``effects`` (a family adds its drive's and sensor's)."""
        return build_effects(effects) if effects else ()
