"""Coast-downs: stretches at zero drive where the mechanism slows down, the direct view of its friction.

With the drive at zero the only input to the plant is its friction (and the bias of a record whose rest
the data do not show). A linear model lets the speed decay exponentially towards the bias's level; Coulomb
friction ``T_c`` adds a constant deceleration and stops the mechanism in finite time (a straight ramp where
the friction dominates); viscous friction steepens the exponential. So a coast-down makes friction
observable even in records that neither reverse nor show their rest
(:func:`agents.twin.evidence.excitation_notes`), and its deceleration gives a starting level of the
Coulomb torque (:func:`coast_down_torque`).
"""

from __future__ import annotations

import numpy as np

from agents.twin.model import GreyFit
from agents.twin.records import Batch

__all__ = ["MIN_COAST_SAMPLES", "coast_down_mask", "coast_down_torque", "coast_downs", "speed_tolerance"]

#: Fewest consecutive samples at zero drive, moving and slowing down, that make a coast-down.
MIN_COAST_SAMPLES = 3


def speed_tolerance(speed: np.ndarray, mask: np.ndarray) -> float:
    """Level below which a speed is not told from standstill: 3 noise std (second differences) plus a quantum."""
    d2 = np.diff(speed, n=2, axis=1)[mask[:, 2:]]
    sigma = float(np.sqrt(np.median(d2**2) / (6.0 * 0.4549))) if d2.size >= 10 else 0.0
    changes = np.abs(np.diff(speed, axis=1)[mask[:, 1:]])
    changes = changes[changes > 1e-12 * max(float(np.max(np.abs(speed[mask]))), 1e-300)]
    quantum = float(np.min(changes)) if changes.size else 0.0
    return 3.0 * sigma + quantum


def _speed(data: Batch, output: str) -> np.ndarray:
    return data.y if output != "position" else np.gradient(data.y, data.dt, axis=1)


def coast_down_mask(data: Batch, output: str, speed_tol: float) -> np.ndarray:
    """Samples (bool, records by samples) of coast-downs to standstill: in a run of at least
    :data:`MIN_COAST_SAMPLES` samples with the command at zero (within ``1e-6`` of the largest command), the
    samples from the run's start while the speed is beyond ``speed_tol``, where it then comes within
    ``speed_tol`` of zero before the run ends (the mechanism stops at zero drive: a constant load, as a
    record's bias is, would carry it on through zero)."""
    speed = _speed(data, output)
    u_tol = 1e-6 * max(float(np.max(np.abs(data.u[data.mask]))), 1e-300)
    idle = data.mask & (np.abs(data.u) <= u_tol)
    out = np.zeros_like(idle)
    for k in range(data.n_records):
        edges = np.flatnonzero(np.diff(np.concatenate([[0], idle[k].astype(np.int8), [0]])))
        for start, stop in zip(edges[::2], edges[1::2]):
            moving = np.abs(speed[k, start:stop]) > speed_tol
            if stop - start < MIN_COAST_SAMPLES or not moving[0] or moving.all():
                continue
            first_stop = int(np.argmin(moving))  # the first sample within the tolerance of standstill
            out[k, start : start + first_stop] = True
    return out


def coast_downs(data: Batch, output: str, speed_tol: float) -> np.ndarray:
    """Records (bool, shape (n_records,)) with a coast-down (:func:`coast_down_mask`)."""
    return coast_down_mask(data, output, speed_tol).any(axis=1)


def coast_down_torque(data: Batch, base: GreyFit) -> float | None:
    r"""The Coulomb torque (input units) that the coast-downs of ``data`` show under ``base``'s linear part.

    The linear part as a first-order lag of static gain ``G = b_m / a_n`` and time constant
    ``\tau = a_{n-1} / a_n`` (the sum of its poles' time constants), sampled with a zero-order hold
    (``a = e^{-dt / \tau}``): at zero drive with the record's bias ``b``,
    ``\omega_{k+1} = a \omega_k + (1 - a) G (b - T_c \operatorname{sign} \omega_k)``, so each step of a
    coast-down gives ``T_c = (b - (\omega_{k+1} - a \omega_k) / ((1 - a) G)) \operatorname{sign} \omega_k``;
    the median over the steps (``None`` without a coast-down, for a position output or a plant with an
    integrator, a non-positive gain or time constant, or a non-positive median).
    """
    if base.spec.output == "position" or base.spec.n_integrators:
        return None
    mask = coast_down_mask(data, base.spec.output, speed_tolerance(data.y, data.mask))
    steps = mask[:, :-1] & mask[:, 1:]  # both ends of the step in the coast-down
    if not steps.any():
        return None
    den = np.asarray(base.plant.den, dtype=float)
    num = np.asarray(base.plant.num, dtype=float)
    gain, tau = num[-1] / den[-1], den[-2] / den[-1]
    if not (gain > 0.0 and tau > 0.0):
        return None
    a = np.exp(-data.dt / tau)
    now, after = data.y[:, :-1], data.y[:, 1:]
    bias = np.where(data.initial.pinned, base.bias, 0.0)[:, None]
    levels = ((bias - (after - a * now) / ((1.0 - a) * gain)) * np.sign(now))[steps]
    level = float(np.median(levels))
    return level if level > 0.0 else None
