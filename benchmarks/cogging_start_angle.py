"""The cost surface of a speed loop with cogging: a start angle fixed at the step, or random as on a rig.

DCMotor-v0 runs its step experiment from ``r1 = 245`` rad/s: the rotor turns 39 times a
second when the step is applied, so a clock-triggered step meets it at any angle.
For DCMotor-v0 with ``{"cogging": {"amplitude": 10}}`` (one ripple per revolution) this
prints, for each start model and ripple phase, the 100 x 100 ground truth's optimum
(grid cell and ``J*``), the ratio there of the ``phase = 0`` optimum of the same model, and
the ratio of the optimum of DCMotor-v0 without cogging (what a linear twin aims at).

* ``synchronised=True``: every experiment starts at ``theta = 0``, the same ripple phase
  at the step (the model before 2026-11-26);
* ``synchronised=False`` (the default): a random angle per experiment, stratified over
  the ground truth's 16 noise draws (:class:`gbo_envs.physics.actuator.Cogging`).

Writes ``benchmarks/results/cogging_start_angle.md``::

    python benchmarks/cogging_start_angle.py        # about 3 min on one core
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

import gbo_envs

RESULTS = Path(__file__).resolve().parent / "results"
AMPLITUDE = 10.0
PHASES = {True: (0.0, 0.1, 0.5), False: (0.0, 0.5)}


def surface(synchronised: bool, phase: float) -> np.ndarray:
    """Expected-cost grid of DCMotor-v0 with cogging of :data:`AMPLITUDE` at ``phase``."""
    cogging = {"amplitude": AMPLITUDE, "phase": phase, "synchronised": synchronised}
    return gbo_envs.ground_truth("gbo_envs/DCMotor-v0", use_table=False, n_jobs=1,
                                 effects={"cogging": cogging}).costs


def cell(costs: np.ndarray) -> tuple[int, ...]:
    """Grid cell of the minimum."""
    return tuple(int(i) for i in np.unravel_index(np.argmin(costs), costs.shape))


def main() -> None:
    linear = cell(gbo_envs.ground_truth("gbo_envs/DCMotor-v0", n_jobs=1).costs)
    rows = ["| start angle | phase (rad) | optimum cell | J* | phase-0 optimum there (J / J*) "
            "| linear optimum there (J / J*) | shift from linear (cells) |", "|---|---|---|---|---|---|---|"]
    for synchronised, phases in PHASES.items():
        first = None
        for phase in phases:
            costs = surface(synchronised, phase)
            best = cell(costs)
            first = first or best
            shift = max(abs(a - b) for a, b in zip(best, linear))
            rows.append(f"| {'fixed (synchronised)' if synchronised else 'random (default)'} | {phase:g} | {best} "
                        f"| {costs[best]:.4f} | {costs[first] / costs[best]:.3f} | {costs[linear] / costs[best]:.3f} "
                        f"| {shift} |")
            print(rows[-1], flush=True)
    text = ("# DCMotor-v0 with cogging of amplitude 10: the start angle\n\n"
            f"Optimum of DCMotor-v0 without cogging: cell {linear}.\n\n" + "\n".join(rows) + "\n")
    (RESULTS / "cogging_start_angle.md").write_text(text)
    print(f"wrote {RESULTS / 'cogging_start_angle.md'}")


if __name__ == "__main__":
    main()
