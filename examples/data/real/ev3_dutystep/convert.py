#!/usr/bin/env python3
"""Convert dimaioksha/ROBOTS RobotLab2/Data/log<duty>.txt (LEGO EV3 Large Motor,
open-loop duty-cycle steps from rest) to the workbench format experiment,t,r,u,y.

Raw file format (written by RobotLab2/Src/Lab2.py, ev3dev Python):
    one line per loop pass: "<position> <time>"
    position  motor.position, tacho counts = degrees (EV3 Large Motor: 360 counts/rev),
              reset to 0 before each run
    time      seconds since the run started (time.time() difference), jittery
              (~4-12 ms, median ~5 ms), run length 5 s
    The duty cycle (percent, -100..100, run_direct duty_cycle_sp) is only in the
    file name: log50.txt -> +50 %, log-50.txt -> -50 %.
Output, one experiment per file, sorted by duty cycle:
    t  uniform grid with the median raw sample time, starting at 0
    y  position [deg], linearly interpolated onto the grid (default) or zero-order
       hold (--zoh keeps the 1-degree quantisation)
    u  duty cycle [%] (constant over the record; the command is issued from the
       first loop pass on), r = u (open loop)
Only numpy/pandas/stdlib.
"""
import glob
import os
import re
import sys

import numpy as np
import pandas as pd

HERE = os.path.dirname(os.path.abspath(__file__))
RAW_DIR = os.path.join(HERE, "raw")
OUT = os.path.join(HERE, "ev3_dutystep.csv")


def load(path):
    a = np.loadtxt(path)
    pos, t = a[:, 0], a[:, 1]
    return t, pos


def resample(t, y, dt, zoh=False):
    n = int(np.floor((t[-1] - t[0]) / dt + 1e-9)) + 1
    tg = t[0] + dt * np.arange(n)
    if zoh:
        idx = np.searchsorted(t, tg, side="right") - 1
        yg = y[np.clip(idx, 0, len(y) - 1)]
    else:
        yg = np.interp(tg, t, y)
    return tg - t[0], yg


def main(zoh=False):
    files = glob.glob(os.path.join(RAW_DIR, "log*.txt"))
    recs = []
    for f in files:
        m = re.match(r"log(-?\d+)\.txt$", os.path.basename(f))
        if m:
            recs.append((int(m.group(1)), f))
    recs.sort()
    dts = np.concatenate([np.diff(load(f)[0]) for _, f in recs])
    dt = float(np.round(np.median(dts), 5))
    rows = []
    for k, (duty, f) in enumerate(recs, start=1):
        t, pos = load(f)
        tg, yg = resample(t, pos, dt, zoh=zoh)
        u = np.full_like(tg, float(duty))
        rows.append(pd.DataFrame({"experiment": k, "t": np.round(tg, 6),
                                  "r": u, "u": u, "y": yg}))
        print(f"experiment {k}: {os.path.basename(f)} duty={duty:+d} %, "
              f"{len(t)} raw samples -> {len(tg)} on dt={dt} s")
    out = pd.concat(rows, ignore_index=True)
    out.to_csv(OUT, index=False, float_format="%.6g")
    print(f"wrote {OUT}: {len(out)} rows, median raw dt={np.median(dts):.5f} s "
          f"(min {dts.min():.5f}, max {dts.max():.5f}), method={'zoh' if zoh else 'linear'}")


if __name__ == "__main__":
    main(zoh="--zoh" in sys.argv)
