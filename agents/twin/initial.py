"""How each record starts: at a rest its data show (or imply), at an unobserved rest, or moving.

A record's model needs its initial state. Real data start in three ways:

* ``"rest"``: the record shows the machine at rest before its excitation: the
  input (open loop) or the reference (closed loop) holds its first value for a
  while, and the output stays flat meanwhile (within its noise and quantum). The
  rest level ``y0`` and the rest command ``u0`` are then *measured*, and the model
  is pinned there, with no free level per record. A load or a friction that acts
  at rest must then be explained by the model itself (an ``offset``, a
  ``coulomb_friction``), which is what makes them observable. A record whose
  input is on from its first sample (a step at ``t = 0``, or the first level of a
  staircase that the output already answers before the input's first change),
  with its output at zero at the start (within its noise and quantum), is a step
  from standstill with the drive off before it: rest at ``u0 = 0`` (``assumed``
  says so; ``initial="steady"`` overrides it). The output, not the input's first
  change, tells that start.
* ``"steady"``: the excitation starts with the first sample (a closed-loop step
  at ``t = 0``, as the envs record it) and the output starts flat: the record
  starts at a rest it does not show. Its rest level and the command that held it
  are estimated: a free rest level ``y0`` and a free plant-input bias (the
  SRIVC rest input ``u0`` in disguise). A constant load within such a record
  cannot be told from the unobserved rest command.
* ``"moving"``: the output is not flat before the excitation, or, with the excitation on
  from the first sample, it changes already in that sample, before an input at sample 0
  can move a plant at rest (a record cut from a long log). The rest level, the bias and
  the free response's slopes are estimated (:func:`agents.twin.open_loop.simulate_open_loop`'
  ``initial``).

:func:`initial_conditions` classifies the records from the data; ``initial=`` of
:meth:`agents.twin.records.Batch.from_records` overrides it for every record.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["INITIAL_MODES", "InitialConditions", "initial_conditions"]

#: Values of the ``initial`` argument: detect per record, or take one case for every record
#: (``"rest"``: at the rest of the first sample; ``"zero"``: at rest with the drive off, ``u0 = 0``;
#: ``"steady"``: estimated rest level and bias).
INITIAL_MODES = ("auto", "rest", "zero", "steady")
#: Output samples checked for flatness at the start of a record whose excitation is on from its first sample:
#: the first step only. A plant at rest answers an input at sample 0 no sooner than at sample 1, and a plant of
#: relative degree 2 or more (or with a delay) by ``O(dt^2)`` there; a machine already moving changes at its speed.
#: Later samples would take a fast response from rest for motion (every LinearMotor-v0 record, with 3 samples).
START_SAMPLES = 2
#: A flat output stays within this many noise standard deviations (plus a quantum) of its median.
FLAT_SIGMAS = 5.0


@dataclass(frozen=True, eq=False)
class InitialConditions:
    """The start of each record (see the module docstring).

    Attributes
    ----------
    mode : ndarray of str, shape (n_records,)
        ``"rest"``, ``"steady"`` or ``"moving"``.
    y0, u0 : ndarray of shape (n_records,)
        Rest level of ``y`` and rest command ``u`` of the ``"rest"`` records (the mean over
        the samples before the excitation, or ``u0 = 0`` where ``assumed``), ``NaN`` for the others.
    quiet : ndarray of int, shape (n_records,)
        Samples before the excitation (0 when it starts with the record).
    assumed : ndarray of bool, shape (n_records,)
        ``"rest"`` records whose rest command is not in the data but taken as zero (a step from
        standstill with the drive off before it).
    """

    mode: np.ndarray
    y0: np.ndarray
    u0: np.ndarray
    quiet: np.ndarray
    assumed: np.ndarray

    @property
    def pinned(self) -> np.ndarray:
        """Records whose rest levels the data pin (bool, shape (n_records,))."""
        return self.mode == "rest"

    @property
    def rest_levels(self) -> np.ndarray:
        """``(y0, u0)`` per record, shape (n_records, 2); ``NaN`` rows where they are estimated."""
        return np.column_stack([self.y0, self.u0])

    def subset(self, rows) -> InitialConditions:
        """The conditions of the records ``rows``."""
        rows = np.asarray(rows, dtype=int)
        return InitialConditions(self.mode[rows], self.y0[rows], self.u0[rows], self.quiet[rows], self.assumed[rows])

    def describe(self, numbers) -> list[str]:
        """One line per kind of start, naming the experiments (``numbers``: as a person counts them)."""
        lines = []
        numbers = np.asarray(numbers)
        groups = (("rest", ~self.assumed,
                   "start{s} at a rest {it} show{s}: rest level and command measured and pinned"),
                  ("rest", self.assumed, "start{s} from standstill with the input already on: taken at rest with the "
                                         "drive off before (u0 = 0), pinned; pass --initial steady if not"),
                  ("steady", True, "start{s} with {its} excitation: rest level and rest input estimated"),
                  ("moving", True, "start{s} moving: rest level and rest input estimated"))
        for mode, extra, text in groups:
            chosen = (self.mode == mode) & extra
            if chosen.any():
                one = int(chosen.sum()) == 1
                words = {"s": "s" if one else "", "it": "it" if one else "they", "its": "its" if one else "their"}
                lines.append(f"experiment{'' if one else 's'} {_ranges(numbers[chosen])} {text.format(**words)}")
        return lines


def initial_conditions(r: np.ndarray, u: np.ndarray, y: np.ndarray, mask: np.ndarray, initial: str = "auto",
                       open_loop: np.ndarray | None = None) -> InitialConditions:
    """Classify how each record starts, and measure the rest of those that show it.

    Parameters
    ----------
    r, u, y : ndarray of shape (n_records, n_steps)
        Reference, command and measured output (padded rows allowed, see ``mask``).
    mask : ndarray of bool, shape (n_records, n_steps)
        True on real samples, which lead each row.
    initial : {"auto", "rest", "zero", "steady"}, default "auto"
        ``"auto"`` detects each record's start; ``"rest"`` takes every record to start at
        the rest of its first sample (``y0 = y[0]``, ``u0 = u[0]``); ``"zero"`` at rest at its
        first output sample with the drive off (``u0 = 0``); ``"steady"`` estimates every
        record's rest (the behaviour for records that do not show it).
    open_loop : ndarray of bool, shape (n_records,), optional
        Records without a controller (``r`` equal to ``u``): their excitation is the input's
        first change. Default: where ``r`` equals ``u``.

    Returns
    -------
    InitialConditions

    Raises
    ------
    ValueError
        ``initial`` outside :data:`INITIAL_MODES`.
    """
    if initial not in INITIAL_MODES:
        raise ValueError(f"initial: must be one of {INITIAL_MODES}, got {initial!r}")
    k = u.shape[0]
    mode = np.full(k, "steady", dtype=object)
    y0, u0, quiet = np.full(k, np.nan), np.full(k, np.nan), np.zeros(k, dtype=int)
    assumed = np.zeros(k, dtype=bool)
    if open_loop is None:
        open_loop = np.array([np.array_equal(r[i][mask[i]], u[i][mask[i]]) for i in range(k)])
    for i in range(k):
        n = int(mask[i].sum())
        ui, yi, ri = u[i, :n], y[i, :n], r[i, :n]
        if initial in ("rest", "zero"):
            mode[i], y0[i], u0[i] = "rest", yi[0], ui[0] if initial == "rest" else 0.0
            assumed[i] = initial == "zero"
            continue
        if initial == "steady":
            continue
        j = _first_change(ui if open_loop[i] else ri)
        if j >= n and not _flat(yi, yi):
            j = 0  # one level throughout, and the output moves: the step came with the first sample, or before
        quiet[i] = min(j, n)
        if j >= 1 and _flat(yi[: max(j, 2)], yi):
            mode[i], y0[i], u0[i] = "rest", float(np.mean(yi[:j])), float(np.mean(ui[:j]))
            continue
        # the excitation is on from the first sample (j = 0), or the output answers the first input level
        # before the input's first change (a staircase whose first step came with the first sample): the start
        # is judged by the output, at standstill when it sits at zero there
        driven = j == 0 or abs(float(ui[0])) > 1e-6 * max(float(np.max(np.abs(ui))), 1e-300)
        if driven and _flat(np.array([yi[0], 0.0]), yi):  # from standstill at zero, the drive just on
            mode[i], y0[i], u0[i], assumed[i], quiet[i] = "rest", float(yi[0]), 0.0, True, 0
        elif j >= 1 or not _flat(yi[:START_SAMPLES], yi, relative=1e-3):  # moving before the record
            mode[i] = "moving"
    return InitialConditions(mode.astype(str), y0, u0, quiet, assumed)


def _first_change(x: np.ndarray) -> int:
    """Index of the first sample that differs from the first (``len(x)`` if none)."""
    tol = 1e-12 * max(float(np.max(np.abs(x))), 1e-300)
    moved = np.flatnonzero(np.abs(x - x[0]) > tol)
    return int(moved[0]) if moved.size else x.size


def _flat(segment: np.ndarray, record: np.ndarray, relative: float = 1e-6) -> bool:
    """Whether ``segment`` holds one level within the noise and the quantum of ``record`` (whose start it is).

    The noise is the robust second-difference estimate of the whole record
    (``var(Delta^2 e) = 6 sigma^2``, median-based so that the record's steps do not count), and
    a quantized output may sit on either side of a level: its smallest change; on noise-free
    data, ``relative`` times the record's span.
    """
    if segment.size < 2:
        return True
    d2 = np.diff(record, n=2)
    sigma = float(np.sqrt(np.median(d2**2) / (6.0 * 0.4549))) if d2.size >= 10 else 0.0
    changes = np.abs(np.diff(record))
    changes = changes[changes > 1e-9 * max(float(np.max(np.abs(record))), 1e-300)]
    quantum = float(np.min(changes)) if changes.size else 0.0
    scale = max(float(np.ptp(record)), 1e-300)
    spread = float(np.max(np.abs(segment - np.median(segment))))
    return spread <= FLAT_SIGMAS * sigma + quantum + relative * scale


def _ranges(numbers) -> str:
    """``[1, 2, 3, 5]`` as ``"1-3, 5"``."""
    numbers = sorted(int(x) for x in numbers)
    parts, start = [], numbers[0]
    for a, b in zip(numbers, numbers[1:] + [None]):
        if b != a + 1:
            parts.append(f"{start}" if start == a else f"{start}-{a}")
            start = b
    return ", ".join(parts)
