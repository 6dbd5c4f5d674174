"""How the digital twin guides BO: the objects ``GuidedBO(guidance=...)`` is composed with.

As BoTorch composes a model with an acquisition function instead of switching
one optimiser by flags, guided BO takes its guidance as an object that carries
only the parameters of that guidance:

* :class:`TwinPrior` (the default): the twin's metrics are the prior mean of the
  default BO's metric GPs; it has no parameters of its own.
* :class:`TwinIterations`: the paper's Algorithm 1, BO iterations on the twin
  while the GP is uncertain; it holds the parameters of eqs. (eta1),
  (DT_stop_a) and (DT_stop_b) and the periodic rule of Sec. V-A.

The parameters both guidances use stay on :class:`~agents.guided_bo.GuidedBO`:
``eta2`` (eq. (DT_rmse1): whether the twin may guide at all), ``delta``
(eq. (reinit_DTdataset): when the twin data set restarts), ``n_samples`` (the
twin data's decimation, eq. (Ds)) and ``twin_poles``.

A study file (``evaluation/studies/*.toml``), or any caller of
``agents.make``, may name a guidance instead: ``guidance = "iterations"`` (its
defaults, the paper's table) or ``guidance = {iterations = {eta1 = 3.0}}`` (a
table of its parameters); :func:`as_guidance` turns either into the object.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any, ClassVar

from agents.parameters import Interval, Options, validate_params

__all__ = ["ACTIVATION_RULES", "GUIDANCE_RULES", "Guidance", "TwinIterations", "TwinPrior", "as_guidance"]

#: How the twin is switched on: the paper's uncertainty test eq. (DT_activation), or every
#: ``period`` plant experiments for ``n_ei`` twin iterations (the twin-fidelity study, Sec. V-A).
ACTIVATION_RULES = ("uncertainty", "periodic")


@dataclass(frozen=True)
class TwinPrior:
    """The twin's metrics as the prior mean of the default BO's metric GPs (``GuidedBO``'s default).

    Each metric GP models the plant's discrepancy from the twin, and EI runs on that
    posterior on every ``ask``, with no twin iterations (see ``guidance="prior"`` in
    :class:`~agents.guided_bo.GuidedBO`). The guidance has no parameters: the twin's
    activation threshold ``eta2`` (eq. (DT_rmse1)) and the re-initialisation threshold
    ``delta`` (eq. (reinit_DTdataset)) act in both guidances and are ``GuidedBO``'s.

    Examples
    --------
    >>> from agents.guidance import TwinPrior
    >>> TwinPrior()
    TwinPrior()
    """

    #: The name a study file or ``agents.make`` gives this guidance.
    name: ClassVar[str] = "prior"
    #: ``GuidedBO``'s surrogate under this guidance: one GP per performance metric.
    model: ClassVar[str] = "metrics"


@dataclass(frozen=True)
class TwinIterations:
    r"""The paper's Algorithm 1: BO iterations on the twin while the GP is uncertain, on one GP on the cost.

    The defaults are the paper's parameter table. Every ``ask`` after the initial design
    activates the twin when ``sqrt(v_n(theta+)) > eta1 sigma_eps`` (eq. (eta1)) and the
    twin fits (``GuidedBO``'s ``eta2``, eq. (DT_rmse1)); BO then runs on the twin until
    for ``n_ei`` consecutive iterations ``a_EI,i <= eta3 max_j a_EI,j`` (eq. (DT_stop_a)),
    or for ``max_twin_iterations`` (eq. (DT_stop_b)). See ``guidance="iterations"`` in
    :class:`~agents.guided_bo.GuidedBO` for the choices where the paper leaves room.

    Parameters
    ----------
    eta1 : float, default 3.0
        Activation threshold of eq. (eta1), in units of the cost noise ``sigma_eps``
        (dimensionless, >= 0): the twin is used when the GP's posterior std at the next
        query exceeds ``eta1 * sigma_eps``. (The paper states ``eta1 = 3`` without a
        unit; tying it to the noise level makes the same value work on every plant.)
    eta3 : float, default 0.2
        Stopping threshold of eq. (DT_stop_a), a fraction (dimensionless, >= 0) of the
        largest EI realised since the activation; ``inf`` runs exactly ``n_ei`` iterations.
    n_ei : int, default 3
        ``n~_EI`` of eq. (DT_stop_a): consecutive twin iterations (count, >= 1) below
        ``eta3`` that stop the activation.
    max_twin_iterations : int, default 20
        Cap of eq. (DT_stop_b): twin iterations per activation (count, >= 1).
    activation : {"uncertainty", "periodic"}, default "uncertainty"
        ``"uncertainty"``: the test of eq. (eta1). ``"periodic"``: every ``period``
        plant experiments, for exactly ``n_ei`` iterations, subject only to ``eta2``
        (the twin-fidelity study, Sec. V-A).
    period : int, default 1
        ``N_G`` of the periodic rule, in plant experiments (>= 1).

    Raises
    ------
    ValueError
        A parameter outside its range, naming it, e.g. ``eta1: must be a float in [0, inf), got -1.0``.

    Examples
    --------
    >>> from agents.guidance import TwinIterations
    >>> TwinIterations(eta1=2)
    TwinIterations(eta1=2.0, eta3=0.2, n_ei=3, max_twin_iterations=20, activation='uncertainty', period=1)
    """

    eta1: float = 3.0
    eta3: float = 0.2
    n_ei: int = 3
    max_twin_iterations: int = 20
    activation: str = "uncertainty"
    period: int = 1

    #: The name a study file or ``agents.make`` gives this guidance.
    name: ClassVar[str] = "iterations"
    #: ``GuidedBO``'s surrogate under this guidance: one GP on the cost (the twin's points enter ``D``
    #: as costs, Algorithm 1, line D_in_DT).
    model: ClassVar[str] = "cost"
    _parameter_constraints: ClassVar[dict[str, list]] = {
        "eta1": [Interval(float, 0.0, None)],
        "eta3": [Interval(float, 0.0, None)],
        "n_ei": [Interval(int, 1, None)],
        "max_twin_iterations": [Interval(int, 1, None)],
        "activation": [Options(ACTIVATION_RULES)],
        "period": [Interval(int, 1, None)],
    }

    def __post_init__(self) -> None:
        checked = validate_params(self._parameter_constraints, {f.name: getattr(self, f.name) for f in fields(self)})
        for name, value in checked.items():  # ints to int, reals to float: equal objects for equal values
            object.__setattr__(self, name, value)


#: A guidance object.
Guidance = TwinPrior | TwinIterations

#: Guidance by name (``guidance = "iterations"`` in a study file).
_BY_NAME: dict[str, type] = {TwinPrior.name: TwinPrior, TwinIterations.name: TwinIterations}

#: The guidance names: the twin as prior mean of the metric GPs, or the paper's twin iterations.
GUIDANCE_RULES = tuple(_BY_NAME)


def as_guidance(value: Any) -> TwinPrior | TwinIterations:
    """The guidance object that ``value`` names.

    Parameters
    ----------
    value : TwinPrior, TwinIterations, str or mapping
        A guidance object (returned as it is); a name, ``"prior"`` or ``"iterations"``
        (its defaults); or a mapping of one name to the guidance's parameters,
        ``{"iterations": {"eta1": 3.0}}`` (a study file's ``{iterations = {eta1 = 3.0}}``).

    Raises
    ------
    ValueError
        Anything else, or a parameter the guidance rejects.
    """
    if isinstance(value, (TwinPrior, TwinIterations)):
        return value
    if isinstance(value, str) and value in _BY_NAME:
        return _BY_NAME[value]()
    if isinstance(value, Mapping) and len(value) == 1:
        (name, params), = value.items()
        if name in _BY_NAME and isinstance(params, Mapping):
            cls = _BY_NAME[name]
            known = {f.name for f in fields(cls)}
            unknown = sorted(set(params) - known)
            if unknown:
                raise ValueError(f"guidance: {name!r} takes {sorted(known) or 'no parameters'}, got {unknown}")
            return cls(**params)
    raise ValueError(f"guidance: must be one of {GUIDANCE_RULES}, TwinPrior(), TwinIterations(...) or a "
                     f"table of one of them, e.g. {{'iterations': {{'eta1': 3.0}}}}, got {value!r}")
