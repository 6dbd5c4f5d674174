#!/usr/bin/env python3
"""Convert parzival2/DC-Motor-Parameter-Estimation Scripts/Experiment_Rpm.csv
(DC 775 motor, STM32 'bluepill' + ChibiOS, AMT102 encoder, 5 ms loop) to the
workbench format experiment,t,r,u,y.

Raw columns (CRLF, written by a PyQt serial logger):
    Timestamp       firmware time [s], 0.005 s steps (float32 rounding noise)
    Angle in deg    MISLABELLED: it is the speed printed by start_experiment() in
                    main.cpp, (1/2pi)*dtheta[rad]/0.005 s = rev/s, multiplied by
                    57.2958 in the PC logger (the factor meant for degrees).
                    Quantum 5.5953 = 57.2958/(2048*0.005) -> 2048 counts/rev.
Input is NOT logged; it is reconstructed from main.cpp start_experiment():
    PWM channel enabled with 20.00 % duty (supply 15 V, ~3 V mean) right after the
    sample printed at t=0.995 s and again after t=4.995 s; disabled right after the
    samples printed at t=2.995 s and t=6.995 s.  Each printed speed is the mean
    over the PRECEDING 5 ms.  Zero-order-hold convention used here: u[k] is the
    command held on [t_k, t_k+dt), so u = 3.0 V for t in [0.995, 2.990] and
    [4.995, 6.990], else 0.
Output: experiment 1, t = k*0.005 s, u = nominal mean voltage [V] (0.2*15 V),
        r = u (open loop), y = speed [rad/s] = raw/57.2958*2*pi.
Only numpy/pandas/stdlib.
"""
import os

import numpy as np
import pandas as pd

HERE = os.path.dirname(os.path.abspath(__file__))
RAW = os.path.join(HERE, "raw", "Experiment_Rpm.csv")
OUT = os.path.join(HERE, "dc775_twostep.csv")
V_ON = 0.20 * 15.0           # 20 % duty of the 15 V lab supply (author: "about ~3V")
DT = 0.005


def main():
    df = pd.read_csv(RAW)
    traw = df.iloc[:, 0].to_numpy(float)
    yraw = df.iloc[:, 1].to_numpy(float)
    k = np.arange(len(traw))
    assert np.max(np.abs(traw - k * DT)) < 1e-6, "time base is not the 5 ms grid"
    t = k * DT
    ms = np.round(t * 1000).astype(int)
    on = ((ms >= 995) & (ms <= 2990)) | ((ms >= 4995) & (ms <= 6990))
    u = np.where(on, V_ON, 0.0)
    y = yraw / 57.2958 * 2 * np.pi
    out = pd.DataFrame({"experiment": 1, "t": np.round(t, 6), "r": u, "u": u, "y": y})
    out.to_csv(OUT, index=False, float_format="%.8g")
    print(f"wrote {OUT}: {len(out)} rows")


if __name__ == "__main__":
    main()
