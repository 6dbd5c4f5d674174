#!/usr/bin/env python3
"""Convert Tamaras-hub/ESP32-DC-Motor-PID-Control data/step_response.csv
to the workbench format  experiment,t,r,u,y.

Raw columns (CRLF text, one header line):
    Tiempo (s)            time since logging start [s], 20 ms grid
    PWM                   8-bit PWM duty command 0..255 (TB6612FNG, 9 V supply)
    Voltaje (V)           nominal armature voltage = PWM/255*9 V (computed, not measured)
    Velocidad (rad/s)     motor output-shaft speed [rad/s] from encoder counts in the
                          last 20 ms window (432 counts/rev, channel A rising edge)
Output:
    experiment = 1 (single open-loop record), t from 0 [s], u = nominal voltage [V],
    r = u (open loop), y = speed [rad/s].
Only numpy/pandas/stdlib.
"""
import os

import numpy as np
import pandas as pd

HERE = os.path.dirname(os.path.abspath(__file__))
RAW = os.path.join(HERE, "raw", "step_response.csv")
OUT = os.path.join(HERE, "esp32_mdc150_step.csv")


def main():
    df = pd.read_csv(RAW, skipinitialspace=True)
    df.columns = ["t_raw", "pwm", "volt", "speed"]
    t = df["t_raw"].to_numpy(float)
    dt = np.median(np.diff(t))
    # the 20 ms grid is exact in the file (3 decimals); no resampling needed
    assert np.max(np.abs(np.diff(t) - dt)) < 1e-6, "unexpected timestamp jitter"
    t0 = t - t[0]
    u = df["volt"].to_numpy(float)
    y = df["speed"].to_numpy(float)
    out = pd.DataFrame({"experiment": 1, "t": np.round(t0, 6), "r": u, "u": u, "y": y})
    out.to_csv(OUT, index=False)
    print(f"wrote {OUT}: {len(out)} rows, dt={dt:.4f} s")


if __name__ == "__main__":
    main()
