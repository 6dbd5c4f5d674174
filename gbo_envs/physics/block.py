"""Base class of the physical effect blocks and the validation of their parameters.

An effect block sits on one side of the sampled-data loop of
:class:`gbo_envs.closed_loop.ClosedLoop`:

* ``side = "actuator"``: between the commanded input ``u`` (controller output,
  after the loop's input delay) and the plant input; called once per sample as
  ``actuate(u, speed) -> u_applied``, where ``speed`` is the mechanical speed
  (``y`` for a speed loop, ``dy/dt`` for a position loop);
* ``side = "sensor"``: between the plant output and the measurement;
  ``measure(y) -> y_measured``;
* ``side = "plant"``: changes the linear plant itself before it is discretised,
  possibly per experiment; ``modify_plant(plant, experiment_index) -> plant``.

Every array argument is of shape (batch,): one entry per gain vector of the
batch being simulated. Blocks are vectorised over the batch and keep their
per-row state (if any) between calls; ``reset(batch, rng, dt, draws)`` starts a new
simulation. A block with measurement noise (``stochastic = True``) takes its
random numbers from a :class:`RowNoise` built there, so that rows given the
same draw index (``draws``) see the same noise: the common random numbers over
which :meth:`gbo_envs.ControllerTuningEnv.evaluate` averages the cost.
To start the experiment at rest, the simulator inverts the static maps:
``level_for(y_measured)`` (sensor) gives the true output whose measurement is
``y_measured``, and ``command_for(u_applied, speed)``
(actuator) gives the commanded input that produces ``u_applied`` at rest; a
stateful block also sets its state to that rest condition there.

Blocks with state (``backlash``, ``cogging``) hold it between ``reset`` and
the end of one simulation: one block object must not be used by two
simulations running at the same time (deep-copy the loop for threads).
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from gbo_envs.physics.lti import ContinuousPlant

__all__ = ["DELAY_LIMIT", "DRIFT_RATE_LIMIT", "EffectBlock", "EffectParameter", "MAGNITUDE_LIMIT", "RowNoise", "SIDES",
           "validated_count", "validated_finite"]

#: Where a block acts in the loop.
SIDES = ("actuator", "sensor", "plant")

#: Upper bound of every effect parameter in input, output or speed units (a limit, width, torque, step,
#: bias, amplitude, period, friction coefficient). Reason: 1e9 units is beyond any physical drive or
#: sensor (the package's plants work below 1e3 V, N, rad/s or m), and a signal of that size times a
#: loop's gains stays far inside double range, so a simulation cannot overflow to inf or NaN.
MAGNITUDE_LIMIT = 1e9
#: Upper bound of ``time_delay``'s ``delay`` in s. Reason: the delay line holds ``delay / dt`` samples
#: (1e6 at 1 ms), and no loop experiment lasts that long; a loop also checks the delay against its
#: experiment's length (a delay longer than the experiment never lets the input reach the output).
DELAY_LIMIT = 1e3
#: Upper bound of ``drift``'s ``rate`` (relative change per experiment). Reason: a parameter that grows
#: more than tenfold from one experiment to the next belongs to a different plant, not to a drift.
DRIFT_RATE_LIMIT = 10.0


@dataclass(frozen=True)
class EffectParameter:
    """Description of one numeric effect parameter (what a twin may fit).

    Attributes
    ----------
    name : str
        Keyword of the block's constructor.
    unit : str
        Physical unit; "input units" are those of the commanded plant input
        (controller output), "output units" those of the measured output,
        "speed units" those of the mechanical speed.
    low, high : float
        Allowed closed range ``[low, high]``, finite (see :data:`MAGNITUDE_LIMIT`); the ``zero``
        value is also allowed outside it (a saturation's ``limit = inf`` is no saturation).
    default : float or None
        Value used when the parameter is not given; ``None`` means required.
    zero : float
        Value at which this parameter makes the block have no effect, or
        ``nan`` if it is not the block's magnitude.
    description : str
        One line of physics.
    """

    name: str
    unit: str
    low: float
    high: float
    default: float | None
    zero: float
    description: str

    def validate(self, effect: str, value: Any) -> float:
        """Return ``value`` as a float, or raise ``ValueError`` naming effect, parameter and range."""
        interval = f"[{self.low:g}, {self.high:g}]"
        if isinstance(value, bool) or not isinstance(value, numbers.Real):
            raise ValueError(f"{effect}: parameter {self.name!r} must be a real number in {interval} "
                             f"({self.unit}), got {value!r} of type {type(value).__name__}")
        value = float(value)
        if value == self.zero:
            return value
        if np.isnan(value) or not (self.low <= value <= self.high):
            raise ValueError(f"{effect}: parameter {self.name!r} must be in {interval} ({self.unit}), "
                             f"got {value!r}")
        if np.isinf(value):  # only the "off" value, returned above (saturation: limit = inf), may be infinite
            raise ValueError(f"{effect}: parameter {self.name!r} must be finite, in {interval} ({self.unit}), "
                             f"got {value!r}")
        return value


def _label(name: str, owner: str | None) -> str:
    return f"{owner}: parameter {name!r}" if owner else name


def validated_count(name: str, value: Any, low: int = 1, owner: str | None = None) -> int:
    """``value`` as an int ``>= low``, else ``ValueError`` naming ``name`` (and ``owner``, e.g. an effect)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < low:
        raise ValueError(f"{_label(name, owner)} must be an integer >= {low}, got {value!r}")
    return int(value)


def validated_finite(name: str, value: Any, unit: str, positive: bool = False, owner: str | None = None) -> float:
    """``value`` as a finite float ``>= 0`` (``> 0`` if ``positive``), else ``ValueError`` naming ``name``."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not np.isfinite(value) or value < 0 \
            or (positive and value == 0):
        raise ValueError(f"{_label(name, owner)} must be a finite number {'> 0' if positive else '>= 0'} ({unit}), "
                         f"got {value!r}")
    return float(value)


class RowNoise:
    """Random numbers for a batch of simulated loops: one value per row and call.

    Parameters
    ----------
    rng : numpy.random.Generator
        Source of the numbers.
    batch : int
        Rows of the batch.
    draws : array_like of int, shape (batch,), optional
        Draw index ``j`` of each row (common random numbers). Rows with the
        same index get the same values, and the values of draw ``j`` depend
        only on ``rng``'s seed and the number of draws ``K = max(draws) + 1``,
        not on the gains or on which rows are in the batch, so a cost
        averaged over draws ``0..K-1`` is the same function of the gains
        wherever it is evaluated. ``None``: every row is an independent
        experiment.
    """

    def __init__(self, rng: np.random.Generator | None, batch: int, draws=None) -> None:
        if rng is None:
            raise ValueError("rng: a numpy Generator is required for a loop with random behaviour "
                             "(measurement noise, a random cogging start angle)")
        self._rng = rng
        self._draws = None if draws is None else np.asarray(draws, dtype=np.intp)
        if self._draws is not None and self._draws.shape != (batch,):
            raise ValueError(f"draws: expected one draw index per row, shape ({batch},), got {self._draws.shape}")
        self._size = batch if self._draws is None else int(self._draws.max(initial=-1)) + 1

    @property
    def size(self) -> int:
        """Values drawn per call: the number of draws ``K`` (``max(draws) + 1``), or the rows if independent."""
        return self._size

    @property
    def columns(self) -> np.ndarray:
        """Shape (batch,): which of the ``size`` values of a call each row reads (its draw index, or its row)."""
        return np.arange(self._size) if self._draws is None else self._draws

    def standard_normal(self, size: int | None = None) -> np.ndarray:
        """N(0, 1) values of shape (batch,), or (size, batch) when ``size`` is given."""
        values = self._rng.standard_normal(self._size if size is None else (size, self._size))
        return values if self._draws is None else values[..., self._draws]

    def rows(self, size: int) -> np.ndarray:
        """N(0, 1) values of shape (batch, size): a whole noise sequence per row."""
        values = self._rng.standard_normal((self._size, size))
        return values if self._draws is None else values[self._draws]

    def uniform(self) -> np.ndarray:
        """Shape (batch,): values uniform in [0, 1)."""
        values = self._rng.random(self._size)
        return values if self._draws is None else values[self._draws]

    def stratified_uniform(self) -> np.ndarray:
        """Shape (batch,): as :meth:`uniform`, but draw ``j`` of ``K`` falls in ``[j / K, (j + 1) / K)``.

        The mean over the ``K`` draws then covers the unit interval evenly (stratified sampling);
        independent rows (no ``draws``) are plain uniform values.
        """
        values = self.uniform()
        return values if self._draws is None else (self._draws + values) / self._size


class EffectBlock:
    """A physical effect that can be put into any plant loop.

    Subclasses declare ``name`` (catalogue name), ``side``, ``parameters`` (a
    tuple of :class:`EffectParameter`; the numeric, fittable parameters),
    ``options`` (non-numeric settings with their allowed values) and
    ``magnitude_param`` (the parameter whose ``zero`` value switches the
    block off). ``param_names``, ``param_units`` and ``param_bounds`` are
    derived class attributes.
    """

    name: ClassVar[str] = ""
    side: str = "actuator"
    parameters: ClassVar[tuple[EffectParameter, ...]] = ()
    options: ClassVar[dict[str, tuple]] = {}
    magnitude_param: ClassVar[str] = ""
    stochastic: ClassVar[bool] = False
    param_names: ClassVar[tuple[str, ...]] = ()
    param_units: ClassVar[tuple[str, ...]] = ()
    param_bounds: ClassVar[tuple[tuple[float, float], ...]] = ()

    def __init_subclass__(cls, **kwargs) -> None:
        super().__init_subclass__(**kwargs)
        cls.param_names = tuple(p.name for p in cls.parameters)
        cls.param_units = tuple(p.unit for p in cls.parameters)
        cls.param_bounds = tuple((p.low, p.high) for p in cls.parameters)

    # -- construction and description --------------------------------------------------------------
    def _set_params(self, **values: Any) -> None:
        """Validate and store the numeric parameters as attributes."""
        for spec in self.parameters:
            value = values[spec.name]
            if value is None and spec.default is not None:
                value = spec.default
            setattr(self, spec.name, spec.validate(self.name, value))

    def _check_option(self, option: str, value: Any) -> Any:
        """Return ``value`` if it is an allowed value of ``option``, else raise ``ValueError``."""
        allowed = self.options[option]
        if not any(value == a and type(value) is type(a) for a in allowed):
            raise ValueError(f"{self.name}: parameter {option!r} must be one of {allowed}, got {value!r}")
        return value

    @classmethod
    def from_params(cls, params: dict[str, Any] | None = None) -> EffectBlock:
        """Build from a ``{parameter: value}`` dict, rejecting unknown parameter names."""
        params = {} if params is None else params
        if not isinstance(params, dict):
            raise ValueError(f"{cls.name}: parameters must be a dict {{name: value}}, got {params!r}")
        allowed = cls.param_names + tuple(cls.options)
        for key in params:
            if key not in allowed:
                raise ValueError(f"{cls.name}: unknown parameter {key!r}; allowed parameters are {allowed}")
        for spec in cls.parameters:
            if spec.default is None and spec.name not in params:
                raise ValueError(f"{cls.name}: parameter {spec.name!r} is required "
                                 f"(a real number in [{spec.low:g}, {spec.high:g}], {spec.unit})")
        return cls(**params)

    @classmethod
    def zero(cls, **options: Any) -> EffectBlock:
        """The block at zero magnitude: it leaves the loop exactly as without it."""
        spec = next(p for p in cls.parameters if p.name == cls.magnitude_param)
        return cls(**{cls.magnitude_param: spec.zero}, **options)

    @property
    def params(self) -> dict[str, Any]:
        """Numeric parameters and options as a dict (``build_effects`` accepts it back)."""
        out: dict[str, Any] = {name: getattr(self, name) for name in self.param_names}
        out.update({name: getattr(self, name) for name in self.options})
        return out

    @property
    def magnitude(self) -> float:
        """Value of the magnitude parameter (see ``magnitude_param``)."""
        return float(getattr(self, self.magnitude_param))

    @property
    def is_zero(self) -> bool:
        """Whether the block is at zero magnitude (no effect at all)."""
        spec = next(p for p in self.parameters if p.name == self.magnitude_param)
        return self.magnitude == spec.zero

    def __repr__(self) -> str:
        body = ", ".join(f"{k}={v!r}" for k, v in self.params.items())
        return f"{type(self).__name__}({body})"

    def __eq__(self, other: object) -> bool:
        return type(other) is type(self) and other.params == self.params

    def __hash__(self) -> int:
        return hash((type(self).__name__, repr(self)))

    def random_in(self, moving_at_start: bool) -> bool:
        """Whether the block draws random numbers in a loop whose mechanism moves at the start (a speed loop)
        or rests there (a position loop): ``stochastic`` unless a block says otherwise."""
        return self.stochastic

    def at_fixed_start(self) -> EffectBlock:
        """This block starting the same way in every experiment (cogging ``synchronised``); itself if it does."""
        return self

    # -- simulator contract (identity defaults) ---------------------------------------------------
    def reset(self, batch: int, rng: np.random.Generator | None, dt: float, draws=None) -> None:
        """Start a simulation of ``batch`` loops sampled every ``dt`` s (clears any state).

        ``draws`` (shape (batch,), optional) is the draw index of each row for
        a stochastic block (see :class:`RowNoise`); other blocks ignore it.
        """

    def command_for(self, u_applied: np.ndarray, speed: np.ndarray) -> np.ndarray:
        """Commanded input of shape (batch,) that yields ``u_applied`` at rest at ``speed`` (actuator side)."""
        return u_applied

    def actuate(self, u: np.ndarray, speed: np.ndarray) -> np.ndarray:
        """Plant input of shape (batch,) for the commanded input ``u`` at mechanical ``speed`` (actuator side)."""
        return u

    def level_for(self, y_measured: np.ndarray) -> np.ndarray:
        """True output of shape (batch,) whose measurement is ``y_measured`` (sensor side)."""
        return y_measured

    def measure(self, y: np.ndarray) -> np.ndarray:
        """Measurement of shape (batch,) of the true plant output ``y`` (sensor side)."""
        return y

    def modify_plant(self, plant: ContinuousPlant, experiment_index: int) -> ContinuousPlant:
        """The plant as it is at experiment ``experiment_index`` (plant side)."""
        return plant
