"""The controller interface: named gains with units, and the digital law a loop runs at its sample time.

A controller is a linear law (of any order) from the control error ``e = r - y``
and, for a two-degree-of-freedom law, the reference ``r`` to the command ``u``,
realised digitally with the Tustin (bilinear) transform at the loop's sample time
``dt``, as a real-time target runs it. :class:`~gbo_envs.closed_loop.ClosedLoop`
reads it in one of two forms:

* the first-order recursion ``u[k] = b0 e[k] + b1 e[k-1] - a1 u[k-1]``
  (:meth:`Controller.coefficients`: PI and PDT1), or
* a discrete state space with inputs ``[e, r - r1]`` (:meth:`Controller.state_space`:
  :class:`~gbo_envs.controllers.state_space.LinearController`), which may clip
  its output to a limit and keep its integrator from winding up against it.

The linear (transfer-function) simulation uses :meth:`Controller.z_transfer`,
the same law as polynomials in ``z^-1``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Controller", "DiscreteStateSpace"]


@dataclass(frozen=True, eq=False)
class DiscreteStateSpace:
    """A batch of digital controllers in state space, as the stepping simulation runs them.

    With inputs ``w[k] = [e[k], r[k] - r1]`` and the command at rest ``u_rest``::

        v[k]   = u_rest + C x[k] + D w[k]                      (unclipped command)
        u[k]   = clip(v[k], -limit, limit)                     (the controller's output)
        x[k+1] = A x[k] + B w[k] + L (u[k] - v[k])             (back-calculation)

    and a state marked in ``clamp`` keeps its value at a sample where the output
    is clipped and its update would drive ``v`` further beyond the limit
    (conditional integration: ``C_i (x_i[k+1] - x_i[k]) (v[k] - u[k]) > 0``).
    The state is the deviation from rest (zero at the start).

    Attributes
    ----------
    a : ndarray of shape (batch, n, n)
    b : ndarray of shape (batch, n, 2)
    c : ndarray of shape (batch, n)
    d : ndarray of shape (batch, 2)
    injection : ndarray of shape (batch, n)
        Back-calculation gain ``L`` (zeros: none).
    clamp : ndarray of bool, shape (n,)
        States held by conditional integration.
    limit : float
        Output limit in input units (``inf``: none).
    """

    a: np.ndarray
    b: np.ndarray
    c: np.ndarray
    d: np.ndarray
    injection: np.ndarray
    clamp: np.ndarray
    limit: float

    @property
    def order(self) -> int:
        """Number of controller states ``n``."""
        return self.a.shape[1]


@dataclass(frozen=True)
class Controller:
    """Base class: a controller with named gains; subclasses define its law.

    The base class itself has no law (an external plant's gains only need names
    and units); a subclass defines either the first-order recursion
    (:meth:`coefficients`) or a state space (:meth:`state_space`).
    """

    gain_names: tuple[str, ...] = ()
    gain_units: tuple[str, ...] = ()

    def coefficients(self, gains: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Return ``(b0, b1, a1)`` of shape (batch,) for gains of shape (batch, n_gains)."""
        raise NotImplementedError

    def state_space(self, gains: np.ndarray, dt: float) -> DiscreteStateSpace | None:
        """The law as a :class:`DiscreteStateSpace`, or ``None`` for the first-order recursion
        (:meth:`coefficients`)."""
        return None

    def z_transfer(self, gains: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
        """The digital law as polynomials in ``z^-1``: ``U = (N_e E + N_r (R - r1)) / D``.

        Parameters
        ----------
        gains : ndarray of shape (batch, n_gains)
        dt : float
            Sample time in s.

        Returns
        -------
        num_e : ndarray of shape (batch, m + 1)
            Numerator on the error.
        num_r : ndarray of shape (batch, m + 1) or None
            Numerator on the reference (``None``: a one-degree-of-freedom law, ``u`` depends on ``e`` only).
        den : ndarray of shape (batch, m + 1)
            Denominator, ``den[:, 0] = 1``.
        """
        b0, b1, a1 = (np.asarray(coef, dtype=float) for coef in self.coefficients(gains, dt))
        return np.stack([b0, b1], axis=1), None, np.stack([np.ones_like(a1), a1], axis=1)

    @property
    def has_state_space(self) -> bool:
        """Whether the law is a state space (:meth:`state_space`) rather than the first-order recursion."""
        return False

    @property
    def output_limit(self) -> float | None:
        """Limit of the controller's output in input units (``None``: unlimited, the law is linear)."""
        return None

    def units_for(self, input_unit: str, output_unit: str) -> tuple[str, ...]:
        """Units of the gains in a loop whose plant input is in ``input_unit`` and output in ``output_unit``.

        The base class knows no law, so it returns :attr:`gain_units`.

        Parameters
        ----------
        input_unit : str
            Unit of the controller's output, the plant input ``u`` (e.g. ``"A"``).
        output_unit : str
            Unit of the measured output ``y`` and of the control error (e.g. ``"rad/s"``).
        """
        return tuple(self.gain_units)

    def transfer_function(self, gains: np.ndarray) -> tuple[list[float], list[float]]:
        """Continuous feedback law ``C(s)`` from the error to ``u`` as ``(num, den)`` for one gain vector (for
        analysis: the loop transfer function is ``C(s) G(s)``)."""
        raise NotImplementedError

    @property
    def has_integrator(self) -> bool:
        """Whether ``C(s)`` has a pole at ``s = 0``."""
        return False


def grouped(unit: str) -> str:
    """``unit`` in parentheses when it is a quotient or a phrase (``rad/s``, ``input units``), else as given."""
    return f"({unit})" if "/" in unit or " " in unit else unit


def per(numerator: str, denominator: str) -> str:
    """``numerator/denominator`` with parentheses where a reader needs them: ``(input units)/(rad/s)``, ``A/m``."""
    top = f"({numerator})" if "/" in numerator or numerator.endswith("units") else numerator
    return f"{top}/{grouped(denominator)}"
