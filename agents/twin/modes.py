"""Resonances the model lacks, sought in the plant: where the residual follows the plant input through a mode.

A record of 1 s holds only two periods of a 2.3 Hz mode, and a step's residual has its power at low
frequencies, so the residual's periodogram shows no peak there. :func:`plant_modes` asks another
question, one the records answer however short they are: which lightly damped second-order filter

.. math:: H_{\\omega,\\zeta}(s) = \\frac{\\omega^2}{s^2 + 2 \\zeta \\omega s + \\omega^2}

of the *plant input* ``u`` (and its derivative ``s H / omega``) explains the most of the residual
``e = y - y_sim`` beyond what the model's own response and the input itself explain. The residual of
a replay is ``e = (G - G_model) u`` plus noise, also in a closed loop (the recorded command is
replayed), so the answer is a mode of the plant, not of the loop (a closed loop's resonance sits
where the controller moved it). The frequencies are scanned on a geometric grid from one period per
record to half the Nyquist frequency, the damping on :data:`SCAN_DAMPING`, each record's regressors
and residual centred on their means; a mode is a local maximum over frequency that a lightly damped
filter explains better than a real pole pair at the same frequency (:data:`OVERDAMPED`).

A mode's damping within :data:`RESONANCE_DAMPING` is what a resonance means (:func:`is_resonance`):
below it the fit is a numerical artefact of the noise, above it the two poles are a lag, not a mode.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from agents.twin.model import GreyFit
from agents.twin.records import Batch

__all__ = ["OVERDAMPED", "RESONANCE_DAMPING", "SCAN_DAMPING", "SCAN_POINTS", "Mode", "is_resonance", "plant_modes"]

#: Damping ratios (-) that a resonance has: a lightly damped mode of a flexible coupling, a beam, a belt or a
#: mount (0.005, a steel beam's structural damping) up to the edge of visible ringing (0.7: the step response
#: overshoots by 5 %, the frequency response no longer peaks above 1/sqrt(2) damping).
RESONANCE_DAMPING = (0.005, 0.7)
#: Damping ratios (-) of the filters :func:`plant_modes` scans at every frequency.
SCAN_DAMPING = (0.01, 0.03, 0.1)
#: Damping (-) of the reference filter at each frequency: a mode must explain more than this real pole pair.
OVERDAMPED = (0.3, 1.0)
#: Frequencies on the scan's geometric grid.
SCAN_POINTS = 48


@dataclass(frozen=True)
class Mode:
    """A mode of the plant that the residual shows (:func:`plant_modes`).

    Attributes
    ----------
    frequency : float
        Natural frequency ``omega`` in rad/s.
    damping : float
        Damping ratio ``zeta`` of the scan's best filter (-), one of :data:`SCAN_DAMPING`.
    share : float
        Share of the residual power (beyond the model's response and the input) that the mode explains, in %.
    """

    frequency: float
    damping: float
    share: float

    @property
    def hertz(self) -> float:
        """The frequency in Hz."""
        return self.frequency / (2.0 * np.pi)


def is_resonance(damping: float) -> bool:
    """Whether a second-order mode of damping ratio ``damping`` (-) is a resonance (:data:`RESONANCE_DAMPING`)."""
    low, high = RESONANCE_DAMPING
    return bool(low <= damping <= high)


def plant_modes(data: Batch, fit: GreyFit, n_modes: int = 2, min_share: float = 5.0) -> list[Mode]:
    """The plant's modes that the residual of ``fit`` shows, strongest first (see the module docstring).

    Parameters
    ----------
    data : Batch
    fit : GreyFit
        The model whose residual ``data.y - fit.y_sim`` is searched.
    n_modes : int, default 2
        Modes returned at most.
    min_share : float, default 5.0
        Least share (%) of the residual power beyond the nuisance regressors a mode must explain.

    Returns
    -------
    list of Mode
        Empty when the records are too short (fewer than 16 samples) or no mode stands out. The first
        ``k`` modes do not depend on ``n_modes >= k``: one scan of a model serves every caller (a diagnosis
        scans each model once, :func:`agents.twin.diagnose.diagnose`, and passes the modes down).
    """
    mask = data.mask
    n = int(mask.sum(axis=1).min())
    if n < 16:
        return []
    dt = data.dt
    u = np.where(mask, data.u - data.u[:, :1], 0.0)
    nuisance = np.column_stack([_centred(np.where(mask, fit.y_sim - fit.y_sim[:, :1], 0.0), mask)[mask],
                                _centred(u, mask)[mask]])
    q = np.linalg.qr(nuisance)[0] if np.all(np.linalg.norm(nuisance, axis=0) > 0) else np.zeros((nuisance.shape[0], 0))
    e = _orthogonal(_centred(np.where(mask, data.y - fit.y_sim, 0.0), mask)[mask], q)
    base = float(e @ e)
    if not base > 0.0:
        return []

    def share(w: float, zeta: float) -> float:  # % of the residual power the mode's two regressors explain
        x = np.column_stack([_orthogonal(_centred(r, mask)[mask], q) for r in _mode_response(u, w, zeta, dt)])
        gram, b = x.T @ x, x.T @ e
        if not np.linalg.det(gram) > 1e-12 * np.prod(np.diag(gram)):  # a vanishing regressor: nothing explained
            return 0.0
        return 100.0 * float(b @ np.linalg.solve(gram, b)) / base

    span = float(mask.sum(axis=1).max() * dt)
    grid = np.geomspace(2.0 * np.pi / span, 0.5 * np.pi / dt, SCAN_POINTS)
    scores = np.array([[share(w, zeta) for zeta in (*SCAN_DAMPING, *OVERDAMPED)] for w in grid])
    k = len(SCAN_DAMPING)
    light = scores[:, :k].max(axis=1)
    gain = light - scores[:, k:].max(axis=1)  # beyond a damped or real pole pair at the same frequency
    peaks = [i for i in range(1, grid.size - 1) if light[i] >= light[i - 1] and light[i] >= light[i + 1]
             and light[i] >= min_share and gain[i] >= 0.5 * min_share]
    peaks.sort(key=lambda i: -light[i])
    out = []
    step = grid[1] / grid[0]
    for i in peaks[:n_modes]:  # refined between the grid's neighbours, at each damping of the scan
        fine = grid[i] * step ** np.linspace(-1.0, 1.0, 9)
        values = np.array([[share(w, zeta) for zeta in SCAN_DAMPING] for w in fine])
        a, b = np.unravel_index(np.argmax(values), values.shape)
        out.append(Mode(float(fine[a]), float(SCAN_DAMPING[b]), float(values[a, b])))
    return out


def _mode_response(u: np.ndarray, w: float, zeta: float, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """``H u`` and ``(s / w) H u`` of :math:`H = w^2 / (s^2 + 2 zeta w s + w^2)`, Tustin-discretised with the
    frequency prewarped to ``w`` (rows of ``u`` are records, sampled every ``dt`` s)."""
    # scipy.signal.lfilter's numbers, compiled, without scipy.signal's 0.5 s import
    # heavy dependency: numba (kept off the diagnose start-up path)
    from gbo_envs.physics.kernels import lfilter_rows

    c = w / np.tan(min(w * dt / 2.0, 0.49 * np.pi))  # prewarped: the discrete filter peaks at w
    den = np.array([c * c + 2.0 * zeta * w * c + w * w, 2.0 * (w * w - c * c), c * c - 2.0 * zeta * w * c + w * w])
    low = w * w * np.array([1.0, 2.0, 1.0])
    band = w * c * np.array([1.0, 0.0, -1.0])
    rows = u.shape[0]
    out = lfilter_rows(np.stack([low / den[0], band / den[0]]).repeat(rows, axis=0), den / den[0], u,
                       source=np.tile(np.arange(rows), 2))
    return out[:rows], out[rows:]


def _centred(x: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """``x`` minus each record's mean over its real samples, 0 on padding."""
    count = np.maximum(mask.sum(axis=1, keepdims=True), 1)
    mean = np.sum(np.where(mask, x, 0.0), axis=1, keepdims=True) / count
    return np.where(mask, x - mean, 0.0)


def _orthogonal(x: np.ndarray, q: np.ndarray) -> np.ndarray:
    """``x`` with its projection on the orthonormal columns ``q`` removed."""
    return x - q @ (q.T @ x)
