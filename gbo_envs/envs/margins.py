"""Stability margins of a sampled loop, the evidence behind a feasible set (python-control).

The paper bounds each feasible set by stability margins around a nominal
design (Sec. IV-B: phase and gain margins of the PGM design; Sec. VI-B: phase
margin above 20 degrees). :func:`loop_margins` computes them on the loop as it
is simulated: the sampled plant with its delay
(:meth:`~gbo_envs.physics.lti.DiscretePlant.transfer_function`) times the
controller's digital feedback law
(:meth:`~gbo_envs.controllers.base.Controller.z_transfer`, the error input),
broken at the plant input. Effects (limits, friction, sensors) are left out:
the margins are those of the linear loop.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

__all__ = ["Margins", "loop_margins"]


@dataclass(frozen=True)
class Margins:
    """Stability margins of one loop.

    Attributes
    ----------
    stable : bool
        Whether the closed loop's poles lie inside the unit circle.
    gain_margin_db : float
        Factor (in dB) by which the loop gain may rise before the loop goes unstable (``inf``: none).
    gain_reduction_margin_db : float
        Factor (in dB, ``<= 0``) by which it may fall, for a conditionally stable loop (``-inf``: none; a loop
        with two integrators, a position loop with a PI, has one).
    phase_margin_deg : float
        Smallest phase margin over the gain crossovers, in degrees.
    crossover : float
        Gain crossover frequency of that phase margin in rad/s.
    """

    stable: bool
    gain_margin_db: float
    gain_reduction_margin_db: float
    phase_margin_deg: float
    crossover: float


def loop_margins(loop, gains) -> Margins:
    """:class:`Margins` of ``loop`` (a :class:`~gbo_envs.closed_loop.ClosedLoop`) at one gain vector.

    Parameters
    ----------
    loop : ClosedLoop
    gains : array_like of shape (n_gains,)
        In the controller's units.
    """
    import control as ct

    num_p, den_p = loop.current_plant.discretize(loop.dt).transfer_function()
    num_c, _, den_c = loop.controller.z_transfer(np.atleast_2d(np.asarray(gains, dtype=float)), loop.dt)
    width = max(num_p.size, den_p.size)
    plant = ct.tf(np.pad(num_p, (0, width - num_p.size)), np.pad(den_p, (0, width - den_p.size)), loop.dt)
    law = ct.tf(num_c[0], den_c[0], loop.dt)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # python-control warns on the cancelled (unobservable) controller states
        open_loop = ct.minreal(law * plant, verbose=False)
        gm, pm, _, _, wpc, _ = ct.stability_margins(open_loop, returnall=True)
        poles = ct.poles(ct.feedback(open_loop, 1))
    gm, pm, wpc = (np.atleast_1d(np.asarray(v, dtype=float)) for v in (gm, pm, wpc))
    up, down = gm[gm > 1.0], gm[(gm > 0.0) & (gm < 1.0)]
    best = int(np.argmin(pm)) if pm.size else -1
    return Margins(stable=bool(np.all(np.abs(poles) < 1.0)),
                   gain_margin_db=float(20.0 * np.log10(up.min())) if up.size else np.inf,
                   gain_reduction_margin_db=float(20.0 * np.log10(down.max())) if down.size else -np.inf,
                   phase_margin_deg=float(pm[best]) if pm.size else np.inf,
                   crossover=float(wpc[best]) if pm.size else np.nan)
