"""A flexible coupling between a motor and its load: the two-mass resonance, as a plant-side effect.

Most motion rigs are identified as one rigid inertia, ``G(s)``. A belt, a long
shaft, a bellows or elastic coupling joins two inertias instead: the motor's
``J_m`` and the load's ``J_l``, through a stiffness ``k`` (N m/rad) with damping
``c`` (N m s/rad). Between torque and speed this adds a pole pair (the resonance,
where the inertias swing against each other) and, seen from the motor, a zero
pair (the anti-resonance, where the load absorbs the motor's motion). Its
parameters, from the physical ones:

* resonance ``w = sqrt(k (J_m + J_l) / (J_m J_l))`` (rad/s), damping
  ``zeta = (c / 2) sqrt((J_m + J_l) / (k J_m J_l))``;
* inertia ratio ``r = J_l / J_m``; anti-resonance ``w_a = w / sqrt(1 + r)``, with
  damping ``zeta_a = zeta / sqrt(1 + r)``.

The rigid plant ``G(s)`` (both inertias as one) becomes ``G(s) F(s)``:

* ``measured="load"`` (the output is the load's speed or position, e.g. an
  encoder on the load side):
  ``F(s) = (2 zeta s / w + 1) / (s^2 / w^2 + 2 zeta s / w + 1)``;
* ``measured="motor"`` (the output is the motor's, e.g. the drive's own encoder):
  ``F(s) = (s^2 / w_a^2 + 2 zeta_a s / w_a + 1) / (s^2 / w^2 + 2 zeta s / w + 1)``.

``F(0) = 1``: the static gain and the rigid-body motion are unchanged. The
coupling is linear, so a loop with it alone still runs on the exact linear path.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from gbo_envs.physics.block import MAGNITUDE_LIMIT, EffectBlock, EffectParameter
from gbo_envs.physics.lti import ContinuousPlant

__all__ = ["Compliance"]

#: Where the output is measured: the load (after the coupling) or the motor (before it).
MEASURED_SIDES = ("load", "motor")


class Compliance(EffectBlock):
    """A flexible coupling: the two-mass resonance between motor and load (see the module docstring).

    Parameters
    ----------
    frequency : float
        Resonance ``w`` in rad/s, in ``[1e-3, 1e9]``; ``inf`` is a rigid coupling (no effect).
    damping : float, default 0.05
        Damping ratio ``zeta`` of the resonance (dimensionless), in ``[0, 10]``; couplings are lightly
        damped, 0.02-0.2.
    inertia_ratio : float, default 1.0
        Load over motor inertia ``r = J_l / J_m`` (dimensionless), in ``[0, 1e3]``; it sets the
        anti-resonance ``w / sqrt(1 + r)`` seen from the motor (``measured="motor"``) and is unused
        on the load side.
    measured : {"load", "motor"}, default "load"
        Which inertia the output measures.

    Examples
    --------
    The paper's DC motor speed loop with its load behind a coupling that rings at 12 rad/s
    (measured at the load)::

        gym.make("gbo_envs/DCMotor-v0", effects={"compliance": {"frequency": 12.0, "damping": 0.08}})
    """

    name = "compliance"
    side = "plant"
    parameters = (
        EffectParameter("frequency", "rad/s", 1e-3, MAGNITUDE_LIMIT, None, float("inf"),
                        "resonance of the two inertias on the coupling (inf: rigid)"),
        EffectParameter("damping", "1", 0.0, 10.0, 0.05, float("nan"), "damping ratio of the resonance"),
        EffectParameter("inertia_ratio", "1", 0.0, 1e3, 1.0, float("nan"),
                        "load over motor inertia: the anti-resonance w / sqrt(1 + r) seen from the motor"),
    )
    options = {"measured": MEASURED_SIDES}
    magnitude_param = "frequency"

    def __init__(self, frequency: float, damping: float = 0.05, inertia_ratio: float = 1.0,
                 measured: str = "load") -> None:
        self._set_params(frequency=frequency, damping=damping, inertia_ratio=inertia_ratio)
        self.measured = self._check_option("measured", measured)

    def factor(self) -> tuple[np.ndarray, np.ndarray]:
        """``(numerator, denominator)`` of ``F(s)``, highest power first (``F(0) = 1``)."""
        w, zeta = self.frequency, self.damping
        den = np.array([1.0 / w**2, 2.0 * zeta / w, 1.0])
        if self.measured == "load":
            return np.array([2.0 * zeta / w, 1.0]), den
        root = np.sqrt(1.0 + self.inertia_ratio)
        w_a, zeta_a = w / root, zeta / root
        return np.array([1.0 / w_a**2, 2.0 * zeta_a / w_a, 1.0]), den

    def modify_plant(self, plant: ContinuousPlant, experiment_index: int) -> ContinuousPlant:
        if np.isinf(self.frequency):
            return plant
        num_f, den_f = self.factor()
        num = np.polymul(plant.num, num_f)
        den = np.polymul(plant.den, den_f)
        return replace(plant, num=tuple(num / den[0]), den=tuple(den / den[0]))
