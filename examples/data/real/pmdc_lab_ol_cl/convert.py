#!/usr/bin/env python3
"""Convert the PMDC motor lab records of kierancoz/dyn_sys_controls
(Arduino + SparkFun TB6612FNG, geared brushed DC motor, 12 encoder counts per motor
revolution, gear ratio 45, 20 Hz logging) to the workbench format experiment,t,r,u,y.

raw/PWM_Step_20Hz.csv  (lab10, motor characterisation, OPEN LOOP)
    Time   [s] PC-side time stamp of the sample (~0.05 s)
    Pulses encoder counts in the last 50 ms window (both channels, CHANGE -> 12/rev)
    wm     motor-shaft speed [rad/s] = Pulses*2*pi/(12*window)
    PWM    commanded PWM, 0..255 (staircase 20,40,...,240,255, then 0)
    Vbus   bus voltage reading [V] (constant 5.0 V)
raw/Lab10_CL_Step_20Hz.csv  (lab11, PMDC speed control)
    Time, wm_ref [rad/s] reference, wm [rad/s] measured, PWM [0..255] command
    0-16 s : open-loop feed-forward, PWM = int(0.6603*wm_ref)   (wm_ref 300, 200, 0)
    19-30 s: closed loop, PWM = int(0.6603*wm_ref + 0.10*e + 0.2*int(e) + 0.001*de/dt)

Output experiments:
    1  PWM staircase (open loop)          r = u = PWM, y = wm
    2  feed-forward steps (open loop)     r = u = PWM, y = wm  (wm_ref not kept)
    3  PID steps (closed loop)            r = wm_ref, u = PWM, y = wm
Time stamps are nearly uniform (jitter << 1 % of dt): t is set to k*median(dt)
without interpolation unless the deviation exceeds 5 % of dt (then linear
interpolation is used).  Only numpy/pandas/stdlib.
"""
import os

import numpy as np
import pandas as pd

HERE = os.path.dirname(os.path.abspath(__file__))
RAW = os.path.join(HERE, "raw")
OUT = os.path.join(HERE, "pmdc_lab_ol_cl.csv")


def uniform(t, cols):
    """Return (t_uniform, cols_uniform, dt, max_deviation)."""
    t = np.asarray(t, float) - t[0]
    dt = float(np.median(np.diff(t)))
    tg = dt * np.arange(len(t))
    dev = float(np.max(np.abs(t - tg)))
    if dev < 0.05 * dt:
        return tg, cols, dt, dev
    n = int(np.floor(t[-1] / dt + 1e-9)) + 1
    tg = dt * np.arange(n)
    return tg, [np.interp(tg, t, c) for c in cols], dt, dev


def main():
    rows = []
    # experiment 1: open-loop PWM staircase
    a = pd.read_csv(os.path.join(RAW, "PWM_Step_20Hz.csv"))
    tg, (u, y), dt, dev = uniform(a["Time"].to_numpy(), [a["PWM"].to_numpy(float),
                                                          a["wm"].to_numpy(float)])
    rows.append(pd.DataFrame({"experiment": 1, "t": tg, "r": u, "u": u, "y": y}))
    print(f"exp 1: {len(tg)} samples, dt={dt:.6f} s, max |t - k*dt| = {dev*1e3:.2f} ms")

    # experiments 2 and 3: split Lab10_CL_Step_20Hz.csv at the rest before the 2nd block
    b = pd.read_csv(os.path.join(RAW, "Lab10_CL_Step_20Hz.csv"))
    ref = b["wm_ref"].to_numpy(float)
    starts = np.flatnonzero((ref[1:] != 0) & (ref[:-1] == 0)) + 1   # 0 -> nonzero
    assert len(starts) == 2, starts
    split = starts[1] - 20               # keep 1 s (20 samples) of rest before block 2
    for k, sl, closed in [(2, slice(0, split), False), (3, slice(split, None), True)]:
        s = b.iloc[sl]
        tg, (r, u, y), dt, dev = uniform(s["Time"].to_numpy(),
                                         [s["wm_ref"].to_numpy(float),
                                          s["PWM"].to_numpy(float),
                                          s["wm"].to_numpy(float)])
        if not closed:
            r = u
        rows.append(pd.DataFrame({"experiment": k, "t": tg, "r": r, "u": u, "y": y}))
        print(f"exp {k}: {len(tg)} samples, dt={dt:.6f} s, max |t - k*dt| = {dev*1e3:.2f} ms,"
              f" raw rows {sl.start}..{(sl.stop or len(b)) - 1}")
    out = pd.concat(rows, ignore_index=True)
    out["t"] = out["t"].round(6)
    out.to_csv(OUT, index=False, float_format="%.8g")
    print(f"wrote {OUT}: {len(out)} rows")


if __name__ == "__main__":
    main()
