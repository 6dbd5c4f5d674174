"""Bring your own plant: tune a (simulated) DC motor rig through ExternalPlantEnv, crash-safe.

The rig here is a plain Python function, as your hardware driver would be:
it sets the PI gains, runs one 5 s speed step 245 -> 306 rad/s at 2 ms and
returns ``t, r, u, y``. The simulated motor has Coulomb friction, an encoder
that quantises the speed, sensor noise, and a communication fault on one
call - the env records that experiment as failed and the session goes on.

Every experiment is committed to an SQLite log before the next is proposed;
rerun the script and it resumes (here: finds the session done). The log is
exported as workbench CSV for ``gbo twin``.

Run: ``python examples/external_plant.py [--tuner bo] [--budget 15]`` (about 10-20 s).
"""

from __future__ import annotations

import argparse

import numpy as np
from scipy.signal import cont2discrete

from evaluation.sessions import SessionStore, TuningSession, export_csv
from gbo_envs import ExternalPlantEnv, FailurePolicy, StepExperiment
from gbo_envs.controllers import PIController

DT = 0.002  # s
DURATION = 5.0  # s
R1, R2 = 245.0, 306.0  # rad/s


class SimulatedRig:
    """A DC motor speed rig: ``G(s) = 9.544 / (s^2 + 4.145 s + 4.199)``, 2 ms delay, friction, encoder.

    Parameters
    ----------
    friction : float
        Coulomb friction in controller units (opposes the direction of rotation).
    encoder_step : float
        Speed quantum of the encoder in rad/s (2048-line encoder at 2 ms).
    noise_std : float
        Sensor noise in rad/s.
    fault_on_call : int or None
        Call number (1-based) on which the rig's link "drops" and the call raises.
    seed : int
        Seed of the sensor noise.
    """

    def __init__(self, friction: float = 2.0, encoder_step: float = 2 * np.pi / (2048 * DT), noise_std: float = 0.3,
                 fault_on_call: int | None = 9, seed: int = 0) -> None:
        num, den = [9.544], [1.0, 4.145, 4.199]
        # controllable canonical form, zero-order hold at DT
        a = np.array([[0.0, 1.0], [-den[2], -den[1]]])
        b = np.array([[0.0], [1.0]])
        c = np.array([[num[0], 0.0]])
        self.phi, self.gamma, self.c, _, _ = cont2discrete((a, b, c, np.zeros((1, 1))), DT, method="zoh")
        self.gain_dc = num[0] / den[2]
        self.friction = friction
        self.encoder_step = encoder_step
        self.noise_std = noise_std
        self.fault_on_call = fault_on_call
        self.rng = np.random.default_rng(seed)
        self.calls = 0

    def __call__(self, gains: np.ndarray):
        """Run one step experiment with PI gains ``(Kp, Ki)``; return ``t, r, u, y`` of shape (2501,)."""
        self.calls += 1
        if self.calls == self.fault_on_call:
            raise ConnectionError("rig link dropped (simulated fault)")
        kp, ki = float(gains[0]), float(gains[1])
        n = int(round(DURATION / DT)) + 1
        t = np.arange(n) * DT
        r = np.full(n, R2)
        # at rest at R1: the input balances the plant gain and the friction
        u_rest = R1 / self.gain_dc + self.friction
        x = np.array([R1 / self.c[0, 0], 0.0])  # y = c x = R1, at rest
        b0, b1 = kp + kp * ki * DT / 2, -kp + kp * ki * DT / 2
        u = np.empty(n)
        y = np.empty(n)
        u_prev, e_prev, u_delayed = u_rest, 0.0, u_rest
        noise = self.noise_std * self.rng.standard_normal(n)
        for k in range(n):
            speed = float(self.c[0] @ x)
            y[k] = np.round((speed + noise[k]) / self.encoder_step) * self.encoder_step
            e = r[k] - y[k]
            u[k] = u_prev + b0 * e + b1 * e_prev
            u_prev, e_prev = u[k], e
            applied = u_delayed - self.friction * np.sign(speed)  # one-sample (2 ms) input delay
            u_delayed = u[k]
            x = self.phi @ x + self.gamma[:, 0] * applied
        return t, r, u, y


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tuner", default="bo", help="tuner registry name (default: bo)")
    parser.add_argument("--budget", type=int, default=15, help="plant experiments (default: 15)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--db", default="out/external_plant.sqlite", help="experiment log")
    parser.add_argument("--csv", default="out/external_plant.csv", help="workbench CSV export")
    args = parser.parse_args(argv)

    rig = SimulatedRig()
    low, high = np.array([0.11, 0.87]), np.array([1.10, 2.08])
    env = ExternalPlantEnv(
        rig,
        {"Kp": (low[0], high[0]), "Ki": (low[1], high[1])},
        controller=PIController(),  # with dt and duration, a digital twin can simulate this loop
        experiment=StepExperiment(reference=(R1, R2), dt=DT, duration=DURATION),
        reference_gains=np.linspace(low, high, 5),  # 5 rig experiments; cost=CostSpec(normalizers=...) skips them
        failure_policy=FailurePolicy(on_failure="penalize", timeout_s=30.0),
    )
    print(f"normalisers measured on the rig ({len(env.reference_records)} experiments): "
          f"{np.array2string(env.normalizers, precision=4)}")

    session = TuningSession(args.db, env, args.tuner, budget=args.budget, seed=args.seed, env_id="simulated-dc-rig",
                            env_kwargs={"friction": rig.friction, "noise_std": rig.noise_std})
    result = session.run(progress=True)
    rows = result.plant_rows
    failed = [row for row in rows if row["status"] == "failed"]
    ok = [row for row in rows if row["status"] == "ok"]
    best = min(ok, key=lambda row: row["cost"])
    print(f"session {session.session_id}: {len(rows)} experiments ({session.n_replayed} resumed from {args.db}), "
          f"{len(failed)} failed")
    for row in failed:
        print(f"  experiment {row['experiment']} failed: {row['reason']} -> the tuner was told cost {row['cost']:g}")
    print(f"best: Kp = {best['Kp']:.3f}, Ki = {best['Ki']:.3f}, cost J = {best['cost']:.4f} "
          f"(overshoot {best['overshoot_pct']:.2f} %, settling {best['settling_time']:.3f} s)")
    with SessionStore(args.db, read_only=True) as store:
        _, count = export_csv(store, args.csv, session_id=session.session_id)
    print(f"wrote {count} experiments to {args.csv} (gbo twin compare {args.csv})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
