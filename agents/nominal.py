"""The paper's nominal controller: PI gains from phase and gain margins (Ho et al. 1995).

Ho, Hang and Cao (1995) tune a PI controller ``C(s) = Kp (1 + Ki / s)`` for a
first-order-plus-dead-time (FOPDT) plant ``L e^{-l s} / (1 + tau s)`` so the
loop has phase margin ``Phi_m`` and gain margin ``A_m``; the paper (subsec.
nominal_tuning, eqs. (PGM:omega), (PGM:Kp), (PGM:Kv), Table nominal_ctl_specs)
designs its two nominal DC motor controllers with them.

By default :class:`NominalPGM` uses the FOPDT the env declares for its nominal
design (``env.unwrapped.nominal_fopdt``): on the DC motor envs that is
:data:`gbo_envs.envs.dc_motor.NOMINAL_FOPDT`, which reproduces the paper's table,
(0.85, 1.07) at 60 deg and (0.86, 0.89) at 75 deg. The FOPDT of the identified
model of Table I does not: it gives (1.71, 3.59), outside the feasible set (the
paper designed on the real loop's margins, not on that model).
"""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np

from agents.base import Tuner
from agents.parameters import HasMethods, Interval, Options, validate_params
from gbo_envs.envs.dc_motor import NOMINAL_FOPDT

__all__ = ["NominalPGM", "pgm_pi_gains", "fopdt_from_second_order", "PAPER_NOMINAL_GAINS", "PAPER_TABLE_FOPDT",
           "FOPDT_SOURCES"]

#: The paper's Table nominal_ctl_specs: phase margin (deg) -> (Kp, Ki), both at A_m = 46 dB.
PAPER_NOMINAL_GAINS = {60.0: (0.85, 1.07), 75.0: (0.86, 0.89)}

#: FOPDT (gain, tau in s, delay in s) that reproduces Table nominal_ctl_specs (the DC motor envs'
#: ``nominal_fopdt``; see :data:`gbo_envs.envs.dc_motor.NOMINAL_FOPDT` for the evidence).
PAPER_TABLE_FOPDT = NOMINAL_FOPDT

#: ``fopdt`` by name: the env's declared nominal design model, or the FOPDT of its identified plant.
FOPDT_SOURCES = ("env", "identified")


def pgm_pi_gains(phase_margin_deg: float, gain_margin_db: float, gain: float, tau: float,
                 delay: float) -> tuple[float, float, float]:
    """PI gains of Ho et al. (1995) for an FOPDT plant ``gain e^{-delay s} / (1 + tau s)``.

    ``omega_p = (A_m Phi_m + pi/2 A_m (A_m - 1)) / ((A_m^2 - 1) l)``  (eq. (PGM:omega)),
    ``Kp = omega_p tau / (A_m L)``  (eq. (PGM:Kp)),
    ``Ki = 2 omega_p - 4 omega_p^2 l / pi + 1 / tau``  (eq. (PGM:Kv)),

    with ``Phi_m`` in rad and ``A_m`` the gain margin as an amplitude ratio
    (``10^(dB / 20)``); ``Ki`` is ``1 / T_i`` of ``C(s) = Kp (1 + Ki / s)``.

    Parameters
    ----------
    phase_margin_deg : float
        ``Phi_m``, degrees, in (0, 90).
    gain_margin_db : float
        ``A_m``, dB, > 0.
    gain : float
        FOPDT gain ``L`` (plant output units per controller output unit).
    tau : float
        FOPDT time constant, s.
    delay : float
        FOPDT dead time ``l``, s, > 0.

    Returns
    -------
    Kp : float
        Controller output units per rad/s.
    Ki : float
        1/s.
    omega_p : float
        Approximate phase-crossover frequency, rad/s.
    """
    if not 0.0 < phase_margin_deg < 90.0:
        raise ValueError(f"phase_margin_deg: must be in (0, 90), got {phase_margin_deg}")
    if not gain_margin_db > 0.0:
        raise ValueError(f"gain_margin_db: must be > 0, got {gain_margin_db}")
    if not (gain > 0 and tau > 0 and delay > 0):
        raise ValueError(f"gain, tau, delay: must be > 0, got {gain}, {tau}, {delay}")
    a_m = 10.0 ** (gain_margin_db / 20.0)  # dB -> amplitude ratio
    phi_m = np.deg2rad(phase_margin_deg)
    omega_p = (a_m * phi_m + 0.5 * np.pi * a_m * (a_m - 1.0)) / ((a_m**2 - 1.0) * delay)  # eq. (PGM:omega)
    kp = omega_p * tau / (a_m * gain)  # eq. (PGM:Kp)
    ki = 2.0 * omega_p - 4.0 * omega_p**2 * delay / np.pi + 1.0 / tau  # eq. (PGM:Kv)
    return float(kp), float(ki), float(omega_p)


def fopdt_from_second_order(gain: float, tau1: float, tau2: float, delay: float) -> dict[str, float]:
    """FOPDT of ``G(s) = gain / (s^2 + tau1 s + tau2) e^{-delay s}`` by matching gain and first moment.

    ``G(s) = (gain / tau2) / (1 + (tau1 / tau2) s + s^2 / tau2) e^{-delay s}``
    ``~ (gain / tau2) e^{-delay s} / (1 + (tau1 / tau2) s)``: the static gain is
    kept and the time constant is the sum of the two lag time constants
    (``tau1 / tau2``), so the mean residence time is kept too.

    Returns
    -------
    dict
        ``{"gain": gain / tau2, "tau": tau1 / tau2 (s), "delay": delay (s)}``.
    """
    return {"gain": gain / tau2, "tau": tau1 / tau2, "delay": float(delay)}


class NominalPGM(Tuner):
    """The nominal PGM controller: the same PI gains at every experiment (no learning).

    Gains come from :func:`pgm_pi_gains` on an FOPDT model, then are clipped
    into the feasible set (``clipped`` in the run's ``info`` says whether that
    happened, ``unclipped_gains`` what the formulas gave). With the defaults, on
    the DC motor envs, these are the paper's first nominal controller (0.855,
    1.070); ``phase_margin_deg=75`` gives its second, (0.855, 0.890).

    Parameters
    ----------
    phase_margin_deg : float, default 60
        ``Phi_m``, degrees, in (0, 90) (the paper's first nominal controller; 75 for the second).
    gain_margin_db : float, default 46
        ``A_m``, dB, > 0 (amplitude ratio 10^(46/20) = 199.5).
    fopdt : {"env", "identified"} or dict, default "env"
        ``"env"``: the FOPDT the env declares for its nominal design
        (``env.unwrapped.nominal_fopdt``; the DC motor envs declare the one that
        reproduces the paper's table), else as ``"identified"``.
        ``"identified"``: :func:`fopdt_from_second_order` of the env's
        identified plant (``env.unwrapped.plant_params`` with ``gain, tau1,
        tau2, delay``); for the DC motor this gives (1.707, 3.594) at 60 deg,
        clipped to (1.10, 2.08). A dict ``{"gain", "tau" (s), "delay" (s)}``
        gives the FOPDT directly (any PI env).
    """

    name = "nominal"

    _parameter_constraints = {
        "phase_margin_deg": [Interval(float, 0.0, 90.0, closed="neither")],
        "gain_margin_db": [Interval(float, 0.0, None, closed="neither")],
        "fopdt": [Options(FOPDT_SOURCES), HasMethods(("keys",))],
    }

    def __init__(self, *, phase_margin_deg: float = 60.0, gain_margin_db: float = 46.0,
                 fopdt: str | dict = "env") -> None:
        validate_params(self._parameter_constraints, {"phase_margin_deg": phase_margin_deg,
                                                      "gain_margin_db": gain_margin_db, "fopdt": fopdt})
        if isinstance(fopdt, dict) and set(fopdt) != {"gain", "tau", "delay"}:
            raise ValueError(f"fopdt: dict needs exactly the keys gain, tau, delay, got {sorted(fopdt)}")
        self.phase_margin_deg = float(phase_margin_deg)
        self.gain_margin_db = float(gain_margin_db)
        self.fopdt = fopdt
        self._params = {"phase_margin_deg": self.phase_margin_deg, "gain_margin_db": self.gain_margin_db,
                        "fopdt": fopdt}

    def model(self) -> dict[str, float]:
        """The FOPDT used: ``{"gain", "tau" (s), "delay" (s)}``."""
        if isinstance(self.fopdt, dict):
            return {k: float(v) for k, v in self.fopdt.items()}
        plant = getattr(getattr(self, "env", None), "unwrapped", None)
        declared = getattr(plant, "nominal_fopdt", None)
        if self.fopdt == "env" and declared:
            return {k: float(v) for k, v in declared.items()}
        params = getattr(plant, "plant_params", None)
        if not params or not {"gain", "tau1", "tau2", "delay"} <= set(params):
            raise ValueError(f"fopdt={self.fopdt!r}: the env declares no nominal_fopdt and its plant_params lack "
                             "gain, tau1, tau2, delay (a second-order plant); pass fopdt={'gain': ..., "
                             "'tau': ..., 'delay': ...}")
        return fopdt_from_second_order(params["gain"], params["tau1"], params["tau2"], params["delay"])

    def _setup(self) -> None:
        if self.space.dim != 2:
            raise ValueError(f"NominalPGM tunes a PI controller (2 gains), the env has {self.space.names}")
        model = self.model()
        kp, ki, omega_p = pgm_pi_gains(self.phase_margin_deg, self.gain_margin_db, **model)
        self.unclipped_gains_ = np.array([kp, ki])
        self.gains_ = np.clip(self.unclipped_gains_, self.space.low, self.space.high)
        self.clipped_ = bool(np.any(self.gains_ != self.unclipped_gains_))
        self.omega_p_ = omega_p
        if self.clipped_:
            warnings.warn(f"NominalPGM: PGM gains {np.round(self.unclipped_gains_, 4).tolist()} lie outside the "
                          f"feasible set; clipped to {np.round(self.gains_, 4).tolist()}", stacklevel=3)

    def _ask(self) -> np.ndarray:
        return self.gains_.copy()

    def _tell(self, gains: np.ndarray, cost: float, record: dict | None) -> None:
        pass

    def run_summary(self) -> dict[str, Any]:
        return {"unclipped_gains": [float(g) for g in self.unclipped_gains_], "clipped": self.clipped_,
                "omega_p": self.omega_p_, "fopdt": self.model()}
