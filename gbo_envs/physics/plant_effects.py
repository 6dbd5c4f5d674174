"""Plant-side effects: they change the linear plant itself, before its exact discretisation.

``time_delay`` adds dead time; ``drift`` makes plant parameters change from
one experiment to the next (a time-varying plant). Both are applied by
:meth:`gbo_envs.closed_loop.ClosedLoop.at_experiment` (the env calls it in
``loop_for_experiment``), so a loop whose only effects are plant-side still
runs on the exact linear fast path.
"""

from __future__ import annotations

import re
from dataclasses import replace

import numpy as np

from gbo_envs.physics.block import DELAY_LIMIT, DRIFT_RATE_LIMIT, EffectBlock, EffectParameter
from gbo_envs.physics.lti import ContinuousPlant

__all__ = ["DRIFT_MODES", "Drift", "TimeDelay", "plant_parameter"]

#: How a drifting parameter's relative change grows with the experiment index.
DRIFT_MODES = ("linear", "exponential", "step")

_PARAMETER = re.compile(r"^(gain|delay|num\d+|den\d+)$")


class TimeDelay(EffectBlock):
    """Extra input dead time (transport delay, slower bus or computation).

    ``G(s) -> G(s) exp(-delay s)``: added to the plant's own delay and folded
    into its exact zero-order-hold discretisation (integer and fractional
    samples, :meth:`gbo_envs.physics.lti.ContinuousPlant.discretize`).

    Parameters
    ----------
    delay : float
        Extra delay in s, ``>= 0`` (0: none).
    """

    name = "time_delay"
    side = "plant"
    parameters = (EffectParameter("delay", "s", 0.0, DELAY_LIMIT, None, 0.0, "extra input dead time"),)
    magnitude_param = "delay"

    def __init__(self, delay: float) -> None:
        self._set_params(delay=delay)
        if not np.isfinite(self.delay):
            raise ValueError(f"time_delay: parameter 'delay' must be finite, got {self.delay}")

    def modify_plant(self, plant, experiment_index):
        if self.delay == 0.0:
            return plant
        return replace(plant, delay=plant.delay + self.delay)


class Drift(EffectBlock):
    """Plant parameters that change from one experiment to the next (heating, wear, load change).

    At experiment ``k`` (0-based, as ``info["experiment_index"]``) each named
    parameter is multiplied by the factor

    * ``mode = "linear"``: ``1 + rate * max(0, k - start)``;
    * ``mode = "exponential"``: ``(1 + rate) ** max(0, k - start)``;
    * ``mode = "step"``: ``1 + rate`` from experiment ``start`` on, 1 before
      (an abrupt change such as a new load).

    Parameter names refer to the :class:`~gbo_envs.physics.lti.ContinuousPlant`
    ``G(s) = num(s) / den(s) exp(-delay s)``: ``"gain"`` scales the whole
    numerator (the static gain), ``"delay"`` the dead time, ``"num<i>"`` and
    ``"den<i>"`` single coefficients, indexed from the highest power of ``s``
    (for the DC motor ``den = (1, tau1, tau2)``: ``"den1"`` is ``tau1``,
    ``"den2"`` is ``tau2``).

    Parameters
    ----------
    parameter : str or tuple of str
        Plant parameter(s) that drift.
    rate : float or tuple of float
        Relative change per experiment (``"linear"``, ``"exponential"``) or
        relative size of the step (``"step"``), dimensionless, in ``[-1, inf)``;
        e.g. ``-0.01`` is a 1 % fall per experiment. One value for all
        parameters or one per parameter. 0: no drift.
    mode : {"linear", "exponential", "step"}, default "linear"
    start : int, default 0
        First experiment index at which the plant differs from the nominal.
    """

    name = "drift"
    side = "plant"
    parameters = (EffectParameter("rate", "1 per experiment", -1.0, DRIFT_RATE_LIMIT, None, 0.0,
                                  "relative parameter change per experiment"),)
    options = {"parameter": ("gain", "delay", "num<i>", "den<i>"), "mode": DRIFT_MODES, "start": ("int >= 0",)}
    magnitude_param = "rate"

    def __init__(self, rate, parameter="gain", mode: str = "linear", start: int = 0) -> None:
        names = (parameter,) if isinstance(parameter, str) else parameter
        if not isinstance(names, (tuple, list)) or not names or not all(
                isinstance(n, str) and _PARAMETER.match(n) for n in names):
            raise ValueError(f"drift: parameter 'parameter' must be a plant parameter name or a tuple of them, "
                             f"one of {self.options['parameter']}, got {parameter!r}")
        self.parameter = parameter if isinstance(parameter, str) else tuple(parameter)
        self._names = tuple(names)
        rates = rate if isinstance(rate, (tuple, list)) else (rate,) * len(names)
        if len(rates) != len(names):
            raise ValueError(f"drift: parameter 'rate' needs one value or one per drifting parameter "
                             f"({len(names)}), got {rate!r}")
        spec = self.parameters[0]
        self._rates = tuple(spec.validate(self.name, r) for r in rates)
        if not all(np.isfinite(self._rates)):
            raise ValueError(f"drift: parameter 'rate' must be finite, got {rate!r}")
        self.rate = self._rates[0] if not isinstance(rate, (tuple, list)) else self._rates
        self.mode = self._check_option("mode", mode)
        if isinstance(start, bool) or not isinstance(start, (int, np.integer)) or start < 0:
            raise ValueError(f"drift: parameter 'start' must be an integer experiment index >= 0, got {start!r}")
        self.start = int(start)

    @property
    def magnitude(self) -> float:
        return float(max(abs(r) for r in self._rates))

    @property
    def is_zero(self) -> bool:
        return all(r == 0.0 for r in self._rates)

    def factor(self, experiment_index: int) -> np.ndarray:
        """Multiplicative factor of each drifting parameter at this experiment, shape (n_parameters,)."""
        rates = np.asarray(self._rates)
        elapsed = max(0, int(experiment_index) - self.start)
        if self.mode == "linear":
            return 1.0 + rates * elapsed
        if self.mode == "exponential":
            return (1.0 + rates) ** elapsed
        return 1.0 + rates if int(experiment_index) >= self.start else np.ones_like(rates)

    def modify_plant(self, plant, experiment_index):
        factors = self.factor(experiment_index).tolist()  # Python floats: the same products, without numpy's overhead
        if all(f == 1.0 for f in factors):
            return plant
        if any(f <= 0.0 for f in factors):
            raise ValueError(f"drift: parameters {self._names} reach the factors {factors} (<= 0) at "
                             f"experiment {experiment_index}; choose 'rate' so that they stay positive")
        num, den, delay = list(plant.num), list(plant.den), plant.delay
        for name, f in zip(self._names, factors):
            if name == "gain":
                num = [c * f for c in num]
            elif name == "delay":
                delay = delay * f
            else:
                coeffs, index = (num, int(name[3:])) if name.startswith("num") else (den, int(name[3:]))
                if index >= len(coeffs):
                    raise ValueError(f"drift: parameter {name!r} does not exist for a plant with {name[:3]} of "
                                     f"length {len(coeffs)}; allowed indices 0..{len(coeffs) - 1}")
                coeffs[index] = coeffs[index] * f
        return replace(plant, num=tuple(num), den=tuple(den), delay=delay)

    def current_values(self, plant: ContinuousPlant, experiment_index: int) -> dict[str, float]:
        """The drifting parameters' values at this experiment, ``{name: value}``."""
        modified = self.modify_plant(plant, experiment_index)
        return {name: plant_parameter(modified, name) for name in self._names}


def plant_parameter(plant: ContinuousPlant, name: str) -> float:
    """Value of a named plant parameter of ``plant``.

    ``"gain"`` is the numerator's constant coefficient ``num[-1]`` (the whole
    numerator scales with it; for the DC motor it is ``L``), ``"delay"`` the
    dead time in s, ``"num<i>"``/``"den<i>"`` single coefficients.
    """
    if name == "gain":
        return float(plant.num[-1])
    if name == "delay":
        return float(plant.delay)
    coeffs = plant.num if name.startswith("num") else plant.den
    return float(coeffs[int(name[3:])])
