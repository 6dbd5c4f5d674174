"""The settings of :func:`agents.twin.diagnose.diagnose`, in two keyword-only groups: its decision rules and its search.

:class:`DiagnosisRules` says what evidence names an effect (the rules of
:func:`agents.twin.ranking.rank`); :class:`CandidateSearch` says which candidates are tried
and with how many trial points. Both are frozen and checked when made
(:mod:`agents.parameters`: an out-of-range setting raises, naming it and its range).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from agents.parameters import Boolean, Interval, check_fields

__all__ = ["CandidateSearch", "DiagnosisRules"]


@dataclass(frozen=True)
class DiagnosisRules:
    """When a diagnosis names an effect ``best`` (:func:`agents.twin.ranking.rank`).

    Parameters
    ----------
    bic_margin : float, default 10.0
        ``best`` needs ``delta_bic < -bic_margin`` ("very strong" evidence on the
        Kass-Raftery scale), dimensionless, ``>= 0``; two improving effects whose ``delta_bic``
        differ by less than it (and whose held-out RMSE differ by less than 1 %) are
        reported as indistinguishable.
    min_gain : float, default 0.02
        ``best`` also needs its held-out RMSE ``min_gain`` (a fraction in ``[0, 1)``) below the
        current model's, and the effect itself must matter: switching it off (magnitude at zero)
        must change the output by at least a fifth of the RMS it explains (``effect_rms``), so
        that no effect is credited with a refit of the other parameters.
    noise_gain : float, default 0.05
        ``best`` also needs its held-out RMSE at least ``noise_gain`` times the measurement
        noise floor (:func:`agents.twin.noise_floor.noise_floor_estimate`, units of ``y``) below
        the current model's, ``>= 0``: a gain far below what the measurement resolves is not
        evidence (on noise-free data the linear model's error is far below the floor, and an
        effect would otherwise be credited with fitting that error).

    Examples
    --------
    >>> DiagnosisRules(bic_margin=6)
    DiagnosisRules(bic_margin=6.0, min_gain=0.02, noise_gain=0.05)
    """

    bic_margin: float = 10.0
    min_gain: float = 0.02
    noise_gain: float = 0.05

    _parameter_constraints: ClassVar[dict[str, list]] = {
        "bic_margin": [Interval(float, 0.0, None, closed="left", finite=True)],
        "min_gain": [Interval(float, 0.0, 1.0, closed="left")],
        "noise_gain": [Interval(float, 0.0, None, closed="left", finite=True)],
    }

    def __post_init__(self) -> None:
        check_fields(self)


@dataclass(frozen=True)
class CandidateSearch:
    """Which candidates a diagnosis tries, and the trial points of their fits.

    Parameters
    ----------
    max_iter : int, default 20
        Trial points of the full-data least-squares fits
        (:func:`agents.twin.least_squares.fit_problems`), ``>= 0``.
    screen_iter : int, default 8
        Trial points after which a candidate whose cost is not below the current
        model's (fitted with all ``max_iter``) stops, ``>= 1``: it cannot pass the decision
        rules without beating the current model. The candidates ahead of it are fitted
        again from their starts with all ``max_iter`` trial points.
    skip_unexcited : bool, default True
        Do not fit the effects the data cannot show (:func:`agents.twin.evidence.excitation_notes`,
        judged on all experiments together and on how each starts). They stay in
        ``candidates`` with their ``note``, ``"fitted": False``, no entry in ``fits``, the
        current model's errors (the effect is absorbed by the estimated rest levels, so
        its fit is the current model's) and a ``delta_bic`` of its extra parameters' penalty alone.
    orders : bool, default True
        Also try the general structures: the linear part grown by a pole pair, a pole or a zero
        (:data:`agents.twin.candidates.ORDER_CANDIDATES`) and the static input and output maps
        (:mod:`agents.twin.static_map`), ranked as the effects are.
    general_as_fallback : bool, default True
        Try the general structures only where the catalogue's effects leave them a chance of being
        named (:func:`agents.twin.diagnose.general_needed`): a grown order comes after every effect that
        passes the rules, and a map goes ahead of one only where it explains
        :data:`agents.twin.ranking.SHARE_POINTS` percentage points more of the residual power. With
        ``False`` they are always fitted, and the ranking lists them too.

    Examples
    --------
    >>> CandidateSearch(orders=False)
    CandidateSearch(max_iter=20, screen_iter=8, skip_unexcited=True, orders=False, general_as_fallback=True)
    """

    max_iter: int = 20
    screen_iter: int = 8
    skip_unexcited: bool = True
    orders: bool = True
    general_as_fallback: bool = True

    _parameter_constraints: ClassVar[dict[str, list]] = {
        "max_iter": [Interval(int, 0, None)],
        "screen_iter": [Interval(int, 1, None)],
        "skip_unexcited": [Boolean()],
        "orders": [Boolean()],
        "general_as_fallback": [Boolean()],
    }

    def __post_init__(self) -> None:
        check_fields(self)
