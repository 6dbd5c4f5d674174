"""Data-based starting values, bounds and scales of the effect parameters (scales of the data, search grids)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from agents.twin.coast_down import coast_down_torque
from agents.twin.model import GreyFit
from agents.twin.modes import RESONANCE_DAMPING, Mode, plant_modes
from agents.twin.noise_floor import quantization_step
from agents.twin.records import Batch
from agents.twin.static_map import map_starts
from gbo_envs.physics.effects import EFFECT_NAMES
from gbo_envs.physics.static_map import STATIC_MAPS

__all__ = ["data_scales", "effect_starts", "quantization_scan", "residual_frequencies", "rest_command",
           "standstill_input"]


def data_scales(data: Batch, output: str = "speed") -> dict[str, float]:
    """Magnitudes read from the data: input, output, speed and time scales (for guesses and bounds)."""
    u = data.u[data.mask]
    y = data.y[data.mask]
    speed = data.y if output != "position" else np.gradient(data.y, data.dt, axis=1)
    return {
        "u_max": float(np.max(np.abs(u))) or 1.0,
        "u_scale": float(np.percentile(np.abs(u), 95)) or float(np.max(np.abs(u))) or 1.0,
        "y_span": float(np.ptp(y)) or 1.0,
        "speed": float(np.max(np.abs(speed[data.mask]))) or 1.0,
        "horizon": float(data.mask.sum(axis=1).min() * data.dt),
    }


#: Ratio of neighbouring limits on the saturation's starting grid (:func:`effect_starts`).
SATURATION_GRID_RATIO = 1.02


#: Starts of a smooth friction's ramp (``smoothing``), as fractions of the largest speed: a coast-down's tail
#: that bends from the friction's straight ramp into an exponential shows a ramp of a few per cent.
SMOOTHING_FRACTIONS = (0.01, 0.05)


def effect_starts(name: str, data: Batch, base: GreyFit, with_starts: bool = True, options=None,
                  modes: Sequence[Mode] | None = None) -> tuple[list[np.ndarray], np.ndarray, np.ndarray, np.ndarray]:
    """Starting values, bounds and scales of the fitted parameters of effect ``name``, from the data.

    ``with_starts=False`` skips the (for quantization and drift, costlier) starting values;
    ``options`` are the effect's (its ``variant`` adds parameters:
    :data:`agents.twin.model.VARIANT_PARAMETERS`); ``modes`` the plant's modes in the residual of ``base``
    (:func:`agents.twin.modes.plant_modes`; ``None``: scanned here where the starts need them).

    Returns
    -------
    starts : list of ndarray of shape (n_effect_params,)
    lower, upper, scale : ndarray of shape (n_effect_params,)
    """
    if name in STATIC_MAPS:
        return map_starts(name, options, data)
    sc = data_scales(data, base.spec.output)
    u_max, us, speed, horizon, dt = sc["u_max"], sc["u_scale"], sc["speed"], sc["horizon"], data.dt
    rest = float(np.max(np.abs(rest_command(base))))
    fractions = np.array([0.005, 0.015, 0.05, 0.15, 0.4])
    if name == "time_delay":
        top = max(min(0.25 * horizon, 60 * dt), 2 * dt)
        grid = np.unique(np.concatenate([np.arange(1, 6) * dt, np.geomspace(dt, top, 24)]))
        return [np.array([g]) for g in grid], np.array([0.0]), np.array([top]), np.array([dt])
    if name == "saturation":
        lo = min(rest * 1.0001, 0.5 * u_max)  # the base model's rest input is only a rough guide
        # limits SATURATION_GRID_RATIO apart, from the top down to the median command (at most half the largest,
        # at least a quarter of it): the profile is a narrow V around the limit (DC+saturation, guided BO
        # seed 8: below the linear model's error only within -2.5 % .. +1.8 % of 138), so a point falls inside
        # it and Brent refines between its neighbours
        median = float(np.percentile(np.abs(data.u[data.mask]), 50))
        bottom = max(lo, min(median, 0.5 * u_max), 0.25 * u_max)
        n_grid = int(np.log(u_max / bottom) / np.log(SATURATION_GRID_RATIO))
        grid = u_max / SATURATION_GRID_RATIO ** np.arange(1, n_grid)
        if grid.size == 0:
            grid = np.array([0.5 * (lo + u_max)]) if u_max > lo else np.array([1.001 * lo])
        return [np.array([g]) for g in grid], np.array([lo]), np.array([1.05 * u_max]), np.array([us])
    held = standstill_input(data, base.spec.output) if with_starts else None  # the drive a body at rest withstood
    if name in ("dead_zone", "backlash"):
        starts = [np.array([f * us]) for f in fractions]
        if held is not None and name == "dead_zone":
            starts.append(np.array([min(2.0 * held, 2.0 * us)]))
        return starts, np.array([0.0]), np.array([2 * us]), np.array([us])
    if name == "coulomb_friction":
        levels = [f * us for f in fractions[:-1]] + ([min(held, us)] if held is not None else [])
        coast = coast_down_torque(data, base) if with_starts else None  # the level the coast-downs show
        levels += [min(coast, us)] if coast is not None else []
        if dict(options or {}).get("variant") == "asymmetric":  # the level, and its asymmetry in [-1, 1]
            return [np.array([level, 0.0]) for level in levels], np.array([0.0, -0.95]), \
                np.array([us, 0.95]), np.array([us, 0.3])
        if dict(options or {}).get("variant") == "smooth":  # the level, and the speed below which it ramps
            starts = [np.array([level, f * speed]) for level in levels for f in SMOOTHING_FRACTIONS]
            return starts, np.array([0.0, 0.0]), np.array([us, 0.5 * speed]), np.array([us, 0.05 * speed])
        return [np.array([level]) for level in levels], np.array([0.0]), np.array([us]), np.array([us])
    if name == "viscous_friction":
        c = us / speed
        return [np.array([f * c]) for f in (0.01, 0.05, 0.2)], np.array([0.0]), np.array([2 * c]), np.array([c])
    if name == "stiction":
        levels = [f * us for f in (0.01, 0.05, 0.2)] + ([min(held, us)] if held is not None else [])
        starts = [np.array([level, g * speed]) for level in levels for g in (0.002, 0.02)]
        return starts, np.array([0.0, 0.0]), np.array([us, 0.2 * speed]), np.array([us, 0.05 * speed])
    if name == "quantization":
        q, _ = quantization_step(data.y, data.mask)
        if q is not None:  # the data show their resolution: that is the step, nothing to search
            return [np.array([q])], np.array([q]), np.array([q]), np.array([q])
        grid = quantization_scan(data, base, sc["y_span"]) if with_starts else []
        grid = grid or [0.01 * sc["y_span"]]
        return [np.array([g]) for g in grid], np.array([0.0]), np.array([0.2 * sc["y_span"]]), \
            np.array([sc["y_span"] * 0.01])
    if name == "drift":
        k = max(int(np.ptp(data.index)), 1)
        slope = _gain_trend(data, base) if with_starts else 0.0
        total = np.array([0.003, 0.01, 0.03, 0.1, 0.3])  # relative change over the session
        grid = sorted({float(np.clip(slope, -0.9 / k, 1.0 / k)), *(total / k), *(-total / k)})
        return [np.array([g]) for g in grid], np.array([-0.9 / k]), np.array([1.0 / k]), np.array([0.01 / k])
    if name == "offset":
        return [np.array([f * us]) for f in (-0.05, 0.05)], np.array([-us]), np.array([us]), np.array([us])
    if name == "compliance":
        # from the plant's modes that the residual shows (agents.twin.modes), then a grid; the damping within
        # what a resonance means (RESONANCE_DAMPING): a "coupling" with damping 1.2 explained a short record's
        # lag, not a mode
        top = np.pi / dt  # the Nyquist frequency, rad/s
        found = (plant_modes(data, base) if modes is None else modes) if with_starts else []
        low, high = RESONANCE_DAMPING
        grid = sorted(set(np.geomspace(8.0 * np.pi / horizon, 0.25 * top, 6)))
        starts = [np.array([m.frequency, zeta]) for m in found for zeta in sorted({m.damping, 0.05})]
        starts += [np.array([w, zeta]) for w in grid for zeta in (0.05, 0.2)]
        lower, upper, scale = np.array([2.0 * np.pi / horizon, low]), np.array([0.5 * top, high]), \
            np.array([grid[0], 0.05])
        if dict(options or {}).get("measured") == "motor":
            starts = [np.append(s_, r) for s_ in starts for r in (0.5, 2.0)]
            lower, upper, scale = np.append(lower, 0.0), np.append(upper, 100.0), np.append(scale, 1.0)
        return starts, lower, upper, scale
    if name == "cogging":
        travel = float(np.median(np.sum(np.abs(data.y if base.spec.output != "position" else np.gradient(
            data.y, dt, axis=1)) * data.mask, axis=1) * dt))
        periods = np.geomspace(max(speed * 4 * dt, travel / 2000), max(travel / 4, speed * 8 * dt), 12)
        starts = [np.array([0.02 * us, p, ph]) for p in periods[::2] for ph in (0.0, np.pi / 2)]
        return starts, np.array([0.0, periods[0] / 2, -2 * np.pi]), np.array([us, 2 * periods[-1], 2 * np.pi]), \
            np.array([us, periods[0], 1.0])
    raise ValueError(f"unknown effect {name!r}; the catalogue is {EFFECT_NAMES}")


def quantization_scan(data: Batch, base: GreyFit, span: float, n_best: int = 3,
                       y_true: np.ndarray | None = None) -> list[float]:
    """Quantization steps ``q`` that make ``Q_q(y_true)`` of the base model match ``y``, best first.

    The error of a quantized measurement is a sawtooth of period ``q`` in the
    true output: the periodogram ``|sum_t e(t) exp(-2 pi i y_sim(t) / q)|`` of
    the base model's residual against its output peaks at ``q`` (steps between
    ``1e-3`` and ``0.1`` of the output span; the frequencies ``1/q`` are evenly
    spaced, so each block of 500 takes its exponentials as running products of one
    step's, 4x faster than 500 exponentials and within 1e-12 of them). Each peak is then refined on a
    fine grid (+-5 %, 401 points) of the rounding error itself, which is
    sharp because the levels are whole multiples of ``q``.
    """
    rng = np.random.default_rng(0)
    idx = np.flatnonzero(data.mask.ravel())
    idx = rng.choice(idx, size=min(idx.size, 2000), replace=False)
    ys = (base.y_sim if y_true is None else y_true).ravel()[idx]
    y = data.y.ravel()[idx]
    e = y - ys
    lowest, highest, spacing = 10.0, 1000.0, 0.4  # frequencies in cycles per output span: steps 0.1 .. 1e-3 of it
    df = spacing / span
    freqs = lowest / span + df * np.arange(int(np.ceil((highest - lowest) / spacing)))
    power = np.empty(freqs.size)
    step = np.exp(-2j * np.pi * df * ys)
    for start in range(0, freqs.size, 500):  # exp(-2 pi i f ys) from the block's first frequency by steps of df
        m = min(500, freqs.size - start)
        phase = np.empty((m, ys.size), dtype=complex)
        phase[0] = np.exp(-2j * np.pi * freqs[start] * ys)
        phase[1:] = step
        np.cumprod(phase, axis=0, out=phase)
        power[start : start + m] = np.abs(phase @ e)
    peaks = [i for i in np.argsort(power)[::-1][:200]]
    coarse: list[float] = []
    for i in peaks:
        q = 1.0 / freqs[i]
        if all(abs(q / c - 1.0) > 0.05 for c in coarse):
            coarse.append(q)
        if len(coarse) == n_best:
            break
    found = []
    for q0 in coarse:
        steps = q0 * np.linspace(0.95, 1.05, 401)
        cost = np.mean((y[None, :] - steps[:, None] * np.round(ys[None, :] / steps[:, None])) ** 2, axis=1)
        i = int(np.argmin(cost))
        found.append((float(cost[i]), float(steps[i])))
    return [q for _, q in sorted(found)]


def standstill_input(data: Batch, output: str = "speed", hold: float = 0.02) -> float | None:
    """The largest drive ``|u|`` that a body at rest withstood: held for a while without the speed leaving zero.

    A sample counts when the speed (``y``, or ``dy/dt`` for a position) stays within its noise of zero
    from it for ``max(3, hold * n)`` samples (``n`` the record's length); its ``|u|`` is a drive that
    friction or a dead band held. The largest such drive is where breakaway lies (just above it):
    the start of a stiction's breakaway, a Coulomb friction's level or half a dead zone's width.
    ``None`` when the body is never held at rest under a drive.
    """
    speed = data.y if output != "position" else np.gradient(data.y, data.dt, axis=1)
    best = None
    for k in range(data.n_records):
        n = int(data.mask[k].sum())
        s, u = speed[k, :n], data.u[k, :n]
        changes = np.abs(np.diff(s))
        changes = changes[changes > 1e-9 * max(float(np.max(np.abs(s))), 1e-300)]
        tol = 3.0 * (float(np.min(changes)) if changes.size else 0.0) + 1e-6 * max(float(np.ptp(s)), 1e-300)
        still = np.abs(s) <= tol
        m = max(3, int(hold * n))
        if n <= m:
            continue
        window = np.convolve(still.astype(float), np.ones(m), mode="valid")[: n - m + 1] >= m  # still from k on
        drives = np.abs(u[: n - m + 1])[window]
        drives = drives[drives > 0.0]
        if drives.size:
            best = max(best or 0.0, float(drives.max()))
    return best


def residual_frequencies(data: Batch, fit: GreyFit, n_peaks: int = 2) -> list[float]:
    """Angular frequencies (rad/s) at which the residual of ``fit`` rings: the peaks of its mean periodogram.

    The residual ``y - y_sim`` of each record, its mean removed, is transformed (real FFT, the records'
    common length), the power averaged over records, and the ``n_peaks`` largest local maxima above
    four times the record's fundamental and below half the Nyquist frequency are returned, strongest
    first. A resonance the model lacks shows as such a peak.
    """
    n = int(data.mask.sum(axis=1).min())
    if n < 16:
        return []
    e = (data.y - fit.y_sim)[:, :n]
    e = e - e.mean(axis=1, keepdims=True)
    power = np.mean(np.abs(np.fft.rfft(e * np.hanning(n), axis=1)) ** 2, axis=0)
    w = 2.0 * np.pi * np.fft.rfftfreq(n, data.dt)
    band = (w > 4.0 * 2.0 * np.pi / (n * data.dt)) & (w < 0.5 * np.pi / data.dt)
    idx = np.flatnonzero(band)
    if idx.size < 3:
        return []
    p = power[idx]
    peaks = [idx[i] for i in range(1, idx.size - 1) if p[i] >= p[i - 1] and p[i] >= p[i + 1]]
    peaks.sort(key=lambda i: -power[i])
    return [float(w[i]) for i in peaks[:n_peaks]]


def rest_command(fit: GreyFit) -> np.ndarray:
    """Plant input that holds each record at rest, before the actuator blocks.

    The equilibrium input of ``fit.plant`` at each record's rest level ``fit.y0``
    minus the record's plant-input bias ``fit.bias``.

    Returns
    -------
    ndarray of shape (n_records,)
        In the units of the command ``u``.
    """
    d = fit.plant.discretize(1.0)
    return d.equilibrium(fit.y0)[1] - fit.bias


def _gain_trend(data: Batch, base: GreyFit) -> float:
    """Relative change per experiment of a per-record gain fitted to the base model's response."""
    if data.n_records < 2:
        return 0.0
    dev_sim = base.y_sim - base.y0[:, None]
    dev = data.y - base.y0[:, None]
    num = np.sum(np.where(data.mask, dev * dev_sim, 0.0), axis=1)
    den = np.sum(np.where(data.mask, dev_sim**2, 0.0), axis=1)
    gains = num / np.maximum(den, 1e-300)
    if np.ptp(data.index) == 0:
        return 0.0
    slope = np.polyfit(data.index, gains, 1)[0]
    return float(slope / max(np.mean(gains), 1e-12))
