"""A grey-box model: its structure (:class:`ModelSpec`), its fitted state (:class:`GreyFit`) and its error.

The model of a record is the open-loop replay of its commanded input ``u``
(:func:`agents.twin.open_loop.simulate_open_loop`): a continuous-time transfer function
``B(s)/A(s) e^{-s tau}`` (the SRIVC structure of :mod:`agents.twin.srivc`) with effect
blocks from the catalogue, and per record its start (:mod:`agents.twin.initial`): the rest
level ``y0_k`` of the measured output and a constant plant-input bias ``b_k``, both
measured and pinned for a record that shows its rest, both estimated for one that does
not (the bias is then the rest input of that unobserved rest, SRIVC's ``u0_k`` in
disguise, ``b_k = v_rest(y0_k) - u0_k``).

The global parameters of a structure are the linear part ``b_0..b_m, a_1..a_{n-k}``, the
input delay and the fitted parameters of each effect (:func:`fitted_parameters`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from gbo_envs.physics.effects import EFFECT_NAMES, EFFECTS, build_effect
from gbo_envs.physics.lti import ContinuousPlant
from gbo_envs.physics.static_map import STATIC_MAPS

__all__ = ["FITTED_PARAMETERS", "VARIANT_PARAMETERS", "GreyFit", "ModelSpec", "effect_items", "effect_offset",
           "fitted_parameters", "output_error", "residual_in_increments", "to_increments"]

#: Effect parameters the grey-box fit estimates, and whether they are moved by the gradient
#: iteration (``True``) or chosen on a grid (``False``). Other parameters keep their defaults.
FITTED_PARAMETERS: dict[str, tuple[tuple[str, bool], ...]] = {
    "time_delay": (("delay", True),),
    "saturation": (("limit", True),),
    "dead_zone": (("width", True),),
    "coulomb_friction": (("torque", True),),
    "viscous_friction": (("coefficient", True),),
    "stiction": (("breakaway", True), ("threshold", True)),
    "backlash": (("width", True),),
    "quantization": (("step", False),),
    "drift": (("rate", True),),
    "offset": (("value", True),),
    "cogging": (("amplitude", True), ("period", True), ("phase", True)),
    "compliance": (("frequency", True), ("damping", True)),
    # the static maps (:mod:`agents.twin.static_map`): the inner breakpoints and the values there, as
    # MATLAB's pwlinear estimates both; the outer two held on the identity (the linear part keeps the gain
    # and the rest levels the offset)
    "input_map": (("k1", True), ("k2", True), ("k3", True), ("v1", True), ("v2", True), ("v3", True)),
    "output_map": (("k1", True), ("k2", True), ("k3", True), ("v1", True), ("v2", True), ("v3", True)),
}


#: Fitted parameters of an effect's variants, where they differ from :data:`FITTED_PARAMETERS`, keyed by
#: ``(effect, option, value)``: direction-dependent Coulomb friction (the pseudo-option ``variant``, which is
#: not the block's) fits its level and its asymmetry, friction that fades out at low speed its level and the
#: speed below which it ramps; a coupling seen from the motor also its inertia ratio.
VARIANT_PARAMETERS: dict[tuple[str, str, str], tuple[tuple[str, bool], ...]] = {
    ("coulomb_friction", "variant", "asymmetric"): (("torque", True), ("asymmetry", True)),
    ("coulomb_friction", "variant", "smooth"): (("torque", True), ("smoothing", True)),
    ("compliance", "measured", "motor"): (("frequency", True), ("damping", True), ("inertia_ratio", True)),
    # a map whose signal takes both signs, its breakpoint k1 at zero: held there at zero and at k4 on the
    # identity, v0 free (a one-way drive or sensor is v0 = 0), the breakpoints k2, k3 free
    ("input_map", "variant", "zero"): (("k2", True), ("k3", True), ("v0", True), ("v2", True), ("v3", True)),
    ("output_map", "variant", "zero"): (("k2", True), ("k3", True), ("v0", True), ("v2", True), ("v3", True)),
}


def fitted_parameters(name: str, options=()) -> tuple[tuple[str, bool], ...]:
    """``((parameter, smooth), ...)`` fitted for effect ``name`` with ``options`` (its variant, if any).

    ``smooth`` says whether the gradient iteration moves the parameter (``False``: chosen on a grid).
    """
    for key, value in dict(options).items():
        if (name, key, value) in VARIANT_PARAMETERS:
            return VARIANT_PARAMETERS[(name, key, value)]
    return FITTED_PARAMETERS[name]


@dataclass(frozen=True)
class ModelSpec:
    """Structure of a grey-box model: transfer-function orders and effects (with fixed options).

    ``effects`` is a tuple of ``(name, ((option, value), ...))`` in application order.
    """

    n_poles: int = 2
    n_zeros: int = 0
    n_integrators: int = 0
    output: str = "speed"
    effects: tuple = ()

    def with_effect(self, name: str, options: Mapping | None = None) -> ModelSpec:
        """This structure with one more effect (appended)."""
        return ModelSpec(self.n_poles, self.n_zeros, self.n_integrators, self.output,
                         self.effects + ((name, tuple(sorted((options or {}).items()))),))

    @property
    def effect_names(self) -> tuple[str, ...]:
        """Names of the effects."""
        return tuple(name for name, _ in self.effects)

    @property
    def effect_labels(self) -> tuple[str, ...]:
        """The effects as ``--effects`` names them, with their variants (``coulomb_friction:smooth``)."""
        return tuple(effect_label(name, options) for name, options in self.effects)

    @property
    def label(self) -> str:
        """Short description, e.g. ``"linear(2p0z)+saturation"``."""
        base = f"linear({self.n_poles}p{self.n_zeros}z" + (f"{self.n_integrators}i" if self.n_integrators else "")
        return base + ")" + "".join(f"+{name}" for name in self.effect_names)

    @property
    def n_linear(self) -> int:
        """Linear parameters ``b_0..b_m, a_1..a_{n-k}``."""
        return self.n_zeros + 1 + self.n_poles - self.n_integrators

    @property
    def n_global(self) -> int:
        """Global parameters: the linear part, the delay and the effects' fitted parameters."""
        return self.n_linear + 1 + sum(len(fitted_parameters(name, options)) for name, options in self.effects)

    @property
    def n_start(self) -> int:
        """Initial-state parameters of a record that starts moving (:mod:`agents.twin.initial`): the plant's
        state beyond its output, ``n_poles - 1`` (the free response's mean slope over 1 .. n - 1 samples)."""
        return max(self.n_poles - 1, 0)

    def global_names(self) -> list[str]:
        """Names of the global parameters (before the per-record rest levels and biases)."""
        names = [f"b{j}" for j in range(self.n_zeros + 1)]
        names += [f"a{i}" for i in range(1, self.n_poles - self.n_integrators + 1)]
        names.append("delay")
        for i, (name, options) in enumerate(self.effects):
            names += [f"{name}.{p}" if self.effect_names.count(name) == 1 else f"{name}[{i}].{p}"
                      for p, _ in fitted_parameters(name, options)]
        return names

    def smooth_mask(self) -> np.ndarray:
        """Which global parameters the gradient iteration moves (grid parameters excluded)."""
        flags = [True] * (self.n_linear + 1)
        for name, options in self.effects:
            flags += [smooth for _, smooth in fitted_parameters(name, options)]
        return np.array(flags)

    def plant(self, theta: np.ndarray) -> ContinuousPlant:
        """Linear plant of the global parameters ``theta``."""
        nb = self.n_zeros + 1
        linear = theta[: self.n_linear].tolist()  # Python floats: the plant takes them as they are
        num = tuple(linear[:nb])
        den = (1.0, *linear[nb:], *([0.0] * self.n_integrators))
        return ContinuousPlant(num=num, den=den, delay=max(float(theta[self.n_linear]), 0.0), output=self.output)

    def effect_params(self, theta: np.ndarray) -> list[tuple[str, dict]]:
        """``[(name, {parameter: value, option: value})]`` of the global parameters ``theta``."""
        out, pos = [], self.n_linear + 1
        for name, options in self.effects:
            params = dict(options)
            for p, _ in fitted_parameters(name, options):
                params[p] = float(theta[pos])
                pos += 1
            out.append((name, params))
        return out

    def blocks(self, theta: np.ndarray) -> tuple:
        """Effect blocks of the global parameters ``theta``."""
        return tuple(build_effect(name, _valid(name, params)) for name, params in self.effect_params(theta))


def _valid(name: str, params: dict) -> dict:
    """Clip fitted values into the block's allowed ranges (the iteration may touch a bound); the pseudo-option
    ``variant`` (which parameters are fitted) is not the block's."""
    out = {key: value for key, value in params.items() if key != "variant"}
    for spec in (STATIC_MAPS.get(name) or EFFECTS[name]).parameters:
        if spec.name in out and not isinstance(out[spec.name], str):
            out[spec.name] = float(np.clip(out[spec.name], spec.low, spec.high))
    return out


def residual_in_increments(spec: ModelSpec) -> bool:
    """Whether the fit of ``spec`` takes the simulation error on the output's increments: a position output
    (of the closed-loop records, :func:`output_error`)."""
    return spec.output == "position"


def to_increments(err: np.ndarray, mask: np.ndarray, rows=None) -> np.ndarray:
    """``err`` (records by samples, 0 on padding) replaced in place by its first sample and its increments.

    ``rows`` (bool, one per record) limits it to those records (default every record); ``mask`` may be
    ``None`` when no record is padded.
    """
    if rows is None or np.all(rows):
        err[:, 1:] -= err[:, :-1].copy()
    elif np.any(rows):
        err[rows, 1:] -= err[rows, :-1].copy()
    if mask is not None:
        err[~mask] = 0.0
    return err


def output_error(y: np.ndarray, y_sim: np.ndarray, mask: np.ndarray, spec: ModelSpec, closed=None) -> np.ndarray:
    """Measured minus simulated output, 0 on padding: the error every RMSE of a grey-box fit is taken on.

    For a position output the error of a closed-loop record is taken on its increments
    (:func:`residual_in_increments`): in an open-loop replay of a closed loop, a slider that sticks a
    moment earlier than the plant's stays off for the rest of the record, an offset the loop itself,
    whose controller sees it, does not keep. An open-loop record has no controller to correct it: its
    position error is the error. ``closed`` (bool, one per record; default all) says which records are
    closed-loop (:attr:`agents.twin.records.Batch.closed_loop`).
    """
    err = np.where(mask, y - y_sim, 0.0)
    return to_increments(err, mask, closed) if residual_in_increments(spec) else err


@dataclass(frozen=True, eq=False)
class GreyFit:
    """A fitted grey-box model.

    Attributes
    ----------
    spec : ModelSpec
    theta : ndarray
        Global parameters (``spec.global_names()``).
    plant : ContinuousPlant
        Linear part with its delay (without the ``time_delay`` effect).
    blocks : tuple of EffectBlock
        Fitted effect blocks.
    y0, bias : ndarray of shape (n_records,)
        Rest level of the measured output and plant-input bias of each record.
    y_sim : ndarray of shape (n_records, n_steps)
        Simulated measurement.
    rmse : float
        Root-mean-square simulation error over all real samples, units of ``y``; for a position
        output, of its increments (:func:`output_error`).
    start : ndarray of shape (n_records, m)
        Initial-state parameters of each record that starts moving (``m = spec.n_start``, units of
        ``y`` per s; zero for the others); ``m = 0`` when no record starts moving.
    """

    spec: ModelSpec
    theta: np.ndarray
    plant: ContinuousPlant
    blocks: tuple
    y0: np.ndarray
    bias: np.ndarray
    y_sim: np.ndarray
    rmse: float
    start: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.start is None:
            object.__setattr__(self, "start", np.zeros((self.y0.size, 0)))

    def nuisance(self, rows=None) -> np.ndarray:
        """The per-record parameters of the records ``rows`` (default all), as a problem holds them after its
        global ones: rest levels, biases, then the initial-state parameters record by record."""
        rows = slice(None) if rows is None else rows
        return np.concatenate([self.y0[rows], self.bias[rows], self.start[rows].ravel()])

    @property
    def effect_params(self) -> dict[str, dict]:
        """``{effect: {parameter: value}}`` of the fitted effects."""
        return {name: params for name, params in self.spec.effect_params(self.theta)}

    @property
    def n_params(self) -> int:
        """Global parameters (the complexity of the model; rest levels are not counted)."""
        return int(self.theta.size)


def effect_offset(spec: ModelSpec, name: str) -> int:
    """Position of effect ``name``'s first fitted parameter among ``spec``'s effect parameters (0-based).

    Raises
    ------
    KeyError
        ``name`` is not an effect of ``spec``.
    """
    pos = 0
    for effect, options in spec.effects:
        if effect == name:
            return pos
        pos += len(fitted_parameters(effect, options))
    raise KeyError(name)


def effect_label(name: str, options=()) -> str:
    """An effect as ``--effects`` names it: ``"coulomb_friction:smooth"`` for a variant, else its name."""
    variant = dict(options).get("variant")
    return f"{name}:{variant}" if variant else name


def _named_variant(text: str) -> tuple[str, dict]:
    name, _, variant = text.strip().partition(":")
    return name, ({"variant": variant.strip()} if variant else {})


def effect_items(effects) -> list[tuple[str, dict]]:
    """``[(name, {parameter: value})]`` of effects given as names (``name:variant`` for a variant of
    :data:`VARIANT_PARAMETERS`), a comma-separated string or ``{name: values}``.

    Raises
    ------
    ValueError
        An effect outside the catalogue :data:`gbo_envs.physics.EFFECT_NAMES` and the static maps
        (``"input_map"``, ``"output_map"``), an unknown variant, or an effect named twice.
    """
    if effects is None:
        return []
    if isinstance(effects, str):
        effects = [e for e in effects.split(",") if e.strip()]
    items = effects.items() if isinstance(effects, Mapping) else [
        _named_variant(e) if isinstance(e, str) else (e[0], dict(e[1] or {})) for e in effects]
    out = []
    for name, given in items:
        name = name.strip()
        if name not in EFFECTS and name not in STATIC_MAPS:
            raise ValueError(f"unknown effect {name!r}; the catalogue is {EFFECT_NAMES}, the static maps "
                             f"{tuple(STATIC_MAPS)}")
        given = dict(given or {})
        variant = given.get("variant")
        if variant is not None and (name, "variant", variant) not in VARIANT_PARAMETERS:
            known = [v for n, option, v in VARIANT_PARAMETERS if n == name and option == "variant"]
            raise ValueError(f"effects: {name!r} has no variant {variant!r}; its variants: {known or 'none'}")
        if any(name == seen for seen, _ in out):
            raise ValueError(f"effects: {name!r} is named twice; each catalogue effect may be in the model once")
        out.append((name, given))
    return out
