"""``gbo twin diagnose`` on records made as real rigs make them, each with a known answer (issue 35).

The sets are the test suite's generator (:func:`tests.support.real_like_records`): a 0.1 s servo driven open
loop from rest (u = 0, y = 0 for 0.1 s), two input levels per record, six records alternating in sign (both
directions), speed from a 1024-line encoder differenced over 4 samples (a 1.53 rad/s quantum), 1 ms
samples, 2 s per record, and one hidden effect each:

* ``asymmetric_friction``: Coulomb friction 0.08 forward, 0.12 backward (``torque`` 0.1, ``asymmetry`` -0.2);
* ``saturation``: a drive limit of 0.45 input units;
* ``dead_zone``: a dead band 0.16 wide (the second level, 0.05, inside it: the motor coasts);
* ``time_delay``: 30 ms of dead time.

and records like other machines (issue 56), each from its generator here:

* ``foc_staircase``: :func:`foc_staircase_records`, a BLDC motor under field-oriented control driven by a
  q-axis current staircase from standstill (4 steps, the first with the first sample), 10 ms samples,
  Coulomb friction 0.1 A (:data:`FOC_FRICTION`);
* ``speed_rig``: :func:`speed_rig_records`, a lab DC motor speed rig under PID steps from rest, 10 ms
  samples, a 40 ms dead time and a 25 rpm encoder quantum whose levels jitter with the timer;
* ``flexible_load_open`` and ``flexible_load_closed``: :func:`flexible_load_open_records` (six open-loop
  voltage steps, 1 s at 4 ms) and :func:`flexible_load_closed_records` (PI steps and swept sines, 4 s at 2 ms)
  of a DC motor carrying a flexible beam whose mode, near 2.3 Hz (:data:`FLEX_MODE`), the encoder on the
  motor sees;
* ``belt_tacho``: :func:`belt_tacho_records`, a belt-driven DC motor with a tachogenerator at 10 Hz: a
  static gain falling from 1.06 at 1 V to 0.85 at 5 V (:data:`BELT_MAP`), Coulomb friction 1 V that
  decelerates it in ramps at zero drive, a drive and a sensor that work one way only (0 .. 4.3 V), under an
  open-loop PRBS and a staircase from rest and five closed-loop steps under lead/lag compensators.

Each set is written as a workbench CSV and diagnosed by the command a user runs, ``gbo twin diagnose FILE
--json --quiet``; one JSON line per set: the best candidate, the RMSE before and after it, the noise floor and
the ratio of the two, and the command's wall time. Run from the repository root::

    python benchmarks/real_like_sets.py --out out/real_like
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:  # the generator lives in the test suite
    sys.path.insert(0, str(REPO))

import numpy as np  # noqa: E402
from scipy.signal import chirp  # noqa: E402

from agents.twin.csvio import write_csv  # noqa: E402
from agents.twin.open_loop import simulate_open_loop  # noqa: E402
from gbo_envs import ClosedLoop, ContinuousPlant, Experiment, PIDController  # noqa: E402
from gbo_envs.physics.effects import build_effect, build_effects  # noqa: E402
from tests.support import real_like_records  # noqa: E402

#: The FOC drive's speed loop seen from the q-axis current: 20 rad/s per A, 50 ms mechanical time constant.
FOC_PLANT = ContinuousPlant((400.0,), (1.0, 20.0))
#: The FOC set's hidden friction (``coulomb_friction`` parameters, in A of q-axis current).
FOC_FRICTION = {"torque": 0.1}


def foc_staircase_records(friction: dict | None = None, *, n_records: int = 4, stairs: int = 4,
                          stair_s: float = 0.5, dt: float = 0.01, noise: float = 0.3, seed: int = 0) -> list:
    """Speed staircases from standstill as an FOC drive logs them: the current on from the first sample.

    Each record holds ``stairs`` q-axis current levels (A) of ``stair_s`` s each, rising from 40 % to 100 %
    of about 1 A (+-10 % per record), the first from ``t = 0``; the motor (:data:`FOC_PLANT`, with Coulomb
    friction ``friction``, default :data:`FOC_FRICTION`) is at standstill before it, so the speed (rad/s,
    Gaussian noise of std ``noise``) is 0 at ``t = 0``. Records alternate in sign; ``r`` equals ``u``.
    Sampled every ``dt`` s.

    Returns
    -------
    list of gbo_envs.Experiment
    """
    rng = np.random.default_rng(seed)
    per = int(round(stair_s / dt))
    t = np.arange(stairs * per) * dt
    records = []
    for k in range(n_records):
        sign = 1.0 if k % 2 == 0 else -1.0
        u = np.repeat(sign * np.linspace(0.4, 1.0, stairs) * rng.uniform(0.9, 1.1), per)
        blocks = build_effects({"coulomb_friction": dict(FOC_FRICTION if friction is None else friction)})
        speed = simulate_open_loop(FOC_PLANT, u[None], dt, blocks, y0=0.0, bias=0.0).y_true[0]
        y = speed + noise * rng.standard_normal(speed.size)
        records.append(Experiment(gains=(), t=t, r=u.copy(), u=u, y=y, index=k))
    return records

#: The speed rig's motor: 150 rpm per V, 0.15 s mechanical time constant.
RIG_PLANT = ContinuousPlant((1000.0,), (1.0, 6.667))
#: The speed rig's hidden dead time (s) and its encoder quantum (rpm).
RIG_DELAY, RIG_QUANTUM = 0.04, 25.0


def speed_rig_records(*, n_records: int = 6, duration: float = 2.0, dt: float = 0.01, jitter: float = 1e-3,
                      seed: int = 0) -> list:
    """PID speed steps of a lab DC motor rig as its logger writes them, with a known dead time.

    Each record steps the reference from rest (0 rpm) to a level drawn from 600-1500 rpm at ``t = 0`` under a
    PID (``Kp`` 0.004-0.008 V/rpm, ``Ki`` 0.03-0.06 V/(rpm s), ``Kd`` 2e-4 V s/rpm, drawn per record); the
    motor (:data:`RIG_PLANT`) acts :data:`RIG_DELAY` s after its command, and the speed is read as whole
    encoder counts per sample (:data:`RIG_QUANTUM` rpm, in the loop), logged over a timed interval whose
    length jitters (relative std ``jitter``: the logged level is ``n q (1 + eps)``). Sampled every ``dt`` s.

    Returns
    -------
    list of gbo_envs.Experiment
    """
    rng = np.random.default_rng(seed)
    blocks = build_effects({"time_delay": {"delay": RIG_DELAY}, "quantization": {"step": RIG_QUANTUM, "mode": "floor"}})
    records = []
    for k in range(n_records):
        loop = ClosedLoop(RIG_PLANT, PIDController(), dt=dt, duration=duration, r1=0.0, r2=rng.uniform(600.0, 1500.0),
                          effects=blocks)
        gains = np.array([rng.uniform(0.004, 0.008), rng.uniform(0.03, 0.06), 2e-4])
        res = loop.simulate(gains[None], rng=rng)
        y = res.y[0] * (1.0 + jitter * rng.standard_normal(res.y[0].size))
        records.append(Experiment(gains=gains, t=res.t, r=res.r, u=res.u[0], y=y, index=k))
    return records


#: The flexible-load rig's motor: 20 rad/s per V, mechanical and electrical poles at 10 and 100 rad/s.
FLEX_MOTOR = ContinuousPlant((20000.0,), (1.0, 110.0, 1000.0))
#: Its beam: a mode at 2.3 Hz, lightly damped, seen by the encoder on the motor (load over motor inertia 0.3).
FLEX_MODE = {"frequency": 2.0 * np.pi * 2.3, "damping": 0.03, "inertia_ratio": 0.3, "measured": "motor"}


def flexible_load_plant() -> ContinuousPlant:
    """:data:`FLEX_MOTOR` with the beam's mode :data:`FLEX_MODE` (the ``compliance`` block's factor)."""
    return build_effects({"compliance": dict(FLEX_MODE)})[0].modify_plant(FLEX_MOTOR, 0)


def flexible_load_open_records(*, n_records: int = 6, duration: float = 1.0, dt: float = 0.004, noise: float = 0.2,
                               seed: int = 0) -> list:
    """Open-loop voltage steps of a DC motor carrying a flexible beam (:func:`flexible_load_plant`).

    Each record holds the drive off for 0.1 s, then steps it to a level drawn from 1-3 V, alternating in sign;
    the motor speed (rad/s, from the motor's encoder, Gaussian noise of std ``noise``) starts at rest. Sampled
    every ``dt`` s for ``duration`` s. ``r`` equals ``u``.

    Returns
    -------
    list of gbo_envs.Experiment
    """
    rng = np.random.default_rng(seed)
    t = np.arange(int(round(duration / dt))) * dt
    plant = flexible_load_plant()
    records = []
    for k in range(n_records):
        u = np.where(t >= 0.1, (1.0 if k % 2 == 0 else -1.0) * rng.uniform(1.0, 3.0), 0.0)
        speed = simulate_open_loop(plant, u[None], dt, y0=0.0, bias=0.0).y_true[0]
        records.append(Experiment(gains=(), t=t, r=u.copy(), u=u, y=speed + noise * rng.standard_normal(t.size),
                                  index=k))
    return records


def flexible_load_closed_records(*, n_steps: int = 3, n_sweeps: int = 4, duration: float = 4.0, dt: float = 0.002,
                                 noise: float = 0.2, seed: int = 1) -> list:
    """The flexible-beam motor (:func:`flexible_load_plant`) under a PI speed loop: steps and swept sines.

    The PI (Tustin, eq. (Cv): ``Kp`` 0.03-0.08 V s/rad, ``Ki`` 3-10 1/s, drawn per record) closes the loop on
    the noisy speed (std ``noise``, rad/s) every ``dt`` s. ``n_steps`` records step the reference at 0.2 s to
    20-40 rad/s (alternating in sign); ``n_sweeps`` sweep it as a logarithmic chirp of 10-20 rad/s amplitude
    from 0.2 Hz to 4-6 Hz over ``duration`` s. The loop moves the beam's mode (its closed-loop poles sit at
    13-14 rad/s, the plant's mode at 14.45 rad/s).

    Returns
    -------
    list of gbo_envs.Experiment
    """
    rng = np.random.default_rng(seed)
    t = np.arange(int(round(duration / dt))) * dt
    plant = flexible_load_plant().discretize(dt)
    records = []
    for k in range(n_steps + n_sweeps):
        kp, ki = rng.uniform(0.03, 0.08), rng.uniform(3.0, 10.0)
        if k < n_steps:
            r = np.where(t >= 0.2, (1.0 if k % 2 == 0 else -1.0) * rng.uniform(20.0, 40.0), 0.0)
        else:
            r = rng.uniform(10.0, 20.0) * chirp(t, 0.2, t[-1], rng.uniform(4.0, 6.0), method="logarithmic")
        x = np.zeros(plant.order)
        u, y = np.zeros(t.size), np.zeros(t.size)
        e_old = u_old = 0.0
        for i in range(t.size):
            y[i] = float(plant.c @ x) + noise * rng.standard_normal()
            e = r[i] - y[i]
            u[i] = u_old + (kp + kp * ki * dt / 2.0) * e + (-kp + kp * ki * dt / 2.0) * e_old  # eq. (Cv), Tustin
            x = plant.phi @ x + plant.gamma0 * u[i]
            e_old, u_old = e, u[i]
        records.append(Experiment(gains=(kp, ki), t=t, r=r, u=u, y=y, index=k))
    return records


#: The belt drive's motor and belt seen from the drive voltage to the tacho voltage: 1 V/V, 0.4 s time constant.
BELT_PLANT = ContinuousPlant((2.5,), (1.0, 2.5))
#: Its drive (``input_map`` parameters, V): one way only (nothing below 0 V), the gain falling with the level, so
#: that with :data:`BELT_FRICTION` the steady tacho voltage over the drive voltage is 1.06 at 1 V, 0.955 at
#: 3 V and 0.85 at 5 V.
BELT_MAP = {"k0": -1.0, "k1": 0.0, "k2": 1.0, "k3": 3.0, "k4": 5.0,
            "v0": 0.0, "v1": 0.0, "v2": 2.06, "v3": 3.865, "v4": 5.25}
#: Its Coulomb friction (``coulomb_friction`` parameters, V of drive).
BELT_FRICTION = {"torque": 1.0, "smoothing": 0.2}
#: The tachogenerator's one-way range (V): it reads nothing below 0 and clips at 4.3 V.
BELT_SENSOR = (0.0, 4.3)


def belt_tacho_records(*, dt: float = 0.1, noise: float = 0.01, seed: int = 0) -> list:
    """A belt-driven DC motor with a one-way drive and tachogenerator, logged at ``dt`` (10 Hz), from rest.

    Seven records: an open-loop PRBS (0 or 4 V, holds of 1-4 s, 40 s), an open-loop staircase (1 to 5 V in
    5 s stairs, then 6 s at zero drive), each after 2 s at rest, and five closed-loop steps from rest to a
    tacho voltage of 1.0-4.0 V (8 s each) under lead/lag compensators (PID with ``Kd`` and a 0.2 s
    derivative filter, gains drawn per record). The plant (:data:`BELT_PLANT`) gets the drive's map
    (:data:`BELT_MAP`) of the command less the Coulomb friction (:data:`BELT_FRICTION`): at zero drive the
    friction decelerates it to standstill in a ramp. The tacho reads the speed with Gaussian noise of std
    ``noise`` (V) clipped to :data:`BELT_SENSOR`. Open-loop records have ``r = u``.

    Returns
    -------
    list of gbo_envs.Experiment
    """
    rng = np.random.default_rng(seed)
    blocks = (build_effect("input_map", BELT_MAP), build_effect("coulomb_friction", BELT_FRICTION))
    low, high = BELT_SENSOR
    sensor = build_effect("output_map", {"k0": low - 1.0, "k1": low, "k2": 0.5 * (low + high), "k3": high,
                                         "k4": high + 1.0, "v0": low, "v1": low, "v2": 0.5 * (low + high),
                                         "v3": high, "v4": high})
    rest = int(round(2.0 / dt))
    holds, level = [], 4.0
    while sum(len(h) for h in holds) < int(round(38.0 / dt)):
        holds.append(np.full(int(rng.integers(1, 5) / dt), level if len(holds) % 2 == 0 else 0.0))
    prbs = np.concatenate([np.zeros(rest), *holds])[: rest + int(round(38.0 / dt))]
    stairs = np.concatenate([np.zeros(rest), np.repeat(np.arange(1.0, 6.0), int(round(5.0 / dt))),
                             np.zeros(int(round(6.0 / dt)))])
    records = []
    for k, u in enumerate((prbs, stairs)):
        speed = simulate_open_loop(BELT_PLANT, u[None], dt, blocks, y0=0.0, bias=0.0).y_true[0]
        y = sensor.measure(speed + noise * rng.standard_normal(speed.size))
        records.append(Experiment(gains=(), t=np.arange(u.size) * dt, r=u.copy(), u=u, y=y, index=k))
    for k, r2 in enumerate(np.linspace(1.0, 4.0, 5), start=2):
        loop = ClosedLoop(BELT_PLANT, PIDController(filter_time=0.2), dt=dt, duration=8.0, r1=0.0, r2=float(r2),
                          effects=(*blocks, sensor))
        gains = np.array([rng.uniform(0.6, 1.2), rng.uniform(1.5, 3.0), rng.uniform(0.05, 0.15)])
        res = loop.simulate(gains[None], rng=rng)
        y = sensor.measure(res.y[0] + noise * rng.standard_normal(res.y[0].size))
        # no gains in the record: the open-loop records have none, and a CSV holds one set of gain columns
        records.append(Experiment(gains=(), t=res.t, r=res.r, u=res.u[0], y=y, index=k))
    return records


def _servo(effects: dict, levels: tuple[float, float]):
    """The servo set with ``effects`` hidden, at the two input ``levels``."""
    return effects, lambda: real_like_records(effects, levels=levels)


#: set name -> (hidden effects, generator of its records)
SETS = {
    "asymmetric_friction": _servo({"coulomb_friction": {"torque": 0.1, "asymmetry": -0.2}}, (0.3, 0.6)),
    "saturation": _servo({"saturation": {"limit": 0.45}}, (0.3, 0.6)),
    "dead_zone": _servo({"dead_zone": {"width": 0.16}}, (0.5, 0.05)),
    "time_delay": _servo({"time_delay": {"delay": 0.03}}, (0.3, 0.6)),
    "foc_staircase": ({"coulomb_friction": FOC_FRICTION}, foc_staircase_records),
    "speed_rig": ({"time_delay": {"delay": RIG_DELAY}, "quantization": {"step": RIG_QUANTUM}}, speed_rig_records),
    "flexible_load_open": ({"compliance": FLEX_MODE}, flexible_load_open_records),
    "flexible_load_closed": ({"compliance": FLEX_MODE}, flexible_load_closed_records),
    "belt_tacho": ({"input_map": BELT_MAP, "coulomb_friction": BELT_FRICTION, "output_map": {"range": BELT_SENSOR}},
                   belt_tacho_records),
}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", default="out/real_like", help="folder for the CSVs (default out/real_like)")
    parser.add_argument("--sets", nargs="*", choices=list(SETS), default=list(SETS))
    args = parser.parse_args(argv)
    out = Path(args.out)
    for name in args.sets:
        effects, generate = SETS[name]
        path = write_csv(generate(), out / f"{name}.csv")
        start = time.perf_counter()
        done = subprocess.run([sys.executable, "-m", "evaluation.cli", "twin", "diagnose", str(path), "--json",
                               "--quiet"], capture_output=True, text=True, cwd=REPO, check=True)
        wall = time.perf_counter() - start
        payload = json.loads(done.stdout)
        best = payload["best_step"]
        after = best["rmse"] if best else payload["rmse"]
        noise = payload["noise_rmse"]
        print(json.dumps({"set": name, "hidden": effects, "best": payload["best"],
                          "params": best["params"].get(payload["best"]) if best else None,
                          "rmse_before": payload["rmse"], "rmse_after": after,
                          "rmse_fall_percent": best["rmse_fall_percent"] if best else 0.0, "noise_floor": noise,
                          "after_over_floor": after / noise if noise else None, "wall_s": round(wall, 2),
                          "command": f"gbo twin diagnose {path} --json --quiet"}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
