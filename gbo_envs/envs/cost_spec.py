"""How an env makes its cost ``J`` of eq. (J_used) from an experiment's metrics: one keyword-only option object."""

from __future__ import annotations

import numbers
from dataclasses import dataclass

import numpy as np

__all__ = ["CostSpec", "PAPER_WEIGHTS"]

#: The paper's DC motor metric weights (overshoot, settling time, rise time, ITAE), Sec. IV.
PAPER_WEIGHTS = (0.44, 0.22, 0.22, 0.11)


@dataclass(frozen=True)
class CostSpec:
    """The cost ``J = sum_i w_i m_i / n_i`` of eq. (J_used) and the cost of a diverging experiment.

    It does not depend on the controller or its gains. Frozen and checked when made; array
    settings are stored as tuples of floats (so equal settings compare equal).

    Parameters
    ----------
    weights : array_like of shape (4,), default (0.44, 0.22, 0.22, 0.11)
        Metric weights ``w`` in :data:`~gbo_envs.metrics.METRIC_NAMES` order, each finite and
        ``> 0``, dimensionless (default: the paper's DC motor weights).
    normalizers : array_like of shape (4,), optional
        The metric normalisers ``n_i`` (in the metrics' units: %, s, s, s^2), each finite and
        ``> 0`` (a digital twin reuses its plant's). Default: measured by the env, as the mean
        metrics at its ``reference_gains`` (which live in the env's gain space, not here).
    unstable_cost : float, default 10.0
        Finite cost ``> 0`` reported for a diverging experiment (``info["unstable"]``), dimensionless.

    Examples
    --------
    >>> CostSpec(normalizers=(1, 2, 3, 4)).normalizers
    (1.0, 2.0, 3.0, 4.0)
    """

    weights: tuple[float, ...] = PAPER_WEIGHTS
    normalizers: tuple[float, ...] | None = None
    unstable_cost: float = 10.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "weights", tuple(map(float, validated_vector("weights", self.weights, 4, True))))
        if self.normalizers is not None:
            normalizers = validated_vector("normalizers", self.normalizers, 4, positive=True)
            object.__setattr__(self, "normalizers", tuple(map(float, normalizers)))
        if isinstance(self.unstable_cost, bool) or not isinstance(self.unstable_cost, numbers.Real) \
                or not np.isfinite(self.unstable_cost) or self.unstable_cost <= 0.0:
            # the cost J of eq. (J_used) is >= 0, so a diverging loop must not score at or below a perfect one
            raise ValueError(f"unstable_cost: must be a finite number > 0 (dimensionless, as the cost; above the "
                             f"costs of the stable loops, default 10), got {self.unstable_cost!r}")
        object.__setattr__(self, "unstable_cost", float(self.unstable_cost))


def is_complex(values) -> bool:
    """Whether ``values`` holds a complex number (``np.asarray(..., dtype=float)`` would drop its imaginary part)."""
    try:
        return bool(np.iscomplexobj(np.asarray(values)))
    except (TypeError, ValueError):  # ragged: the float conversion reports it
        return False


def validated_vector(name: str, values, size: int, positive: bool = False) -> np.ndarray:
    """``values`` as a float array of shape ``(size,)``, finite (and ``> 0`` if ``positive``).

    Raises
    ------
    TypeError
        For complex or non-numeric values, naming ``name``.
    ValueError
        For a wrong length, a non-finite entry or (``positive``) an entry ``<= 0``.
    """
    if is_complex(values):
        raise TypeError(f"{name}: expected {size} real numbers, got complex values {values!r}")
    try:
        array = np.asarray(values, dtype=float)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"{name}: expected {size} real numbers, got {values!r}") from exc
    if array.shape != (size,) or not np.all(np.isfinite(array)):
        raise ValueError(f"{name}: expected {size} finite numbers, got {values!r}")
    if positive and np.any(array <= 0.0):
        raise ValueError(f"{name}: every entry must be > 0, got {array}")
    return array
