"""Fit % and RMSE come from one residual (:func:`agents.twin.compare.error_figures`): they move together."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from agents.twin.compare import compare
from agents.twin.fidelity import rmse
from agents.twin.fits import fit_structure
from agents.twin.model import ModelSpec, output_error
from agents.twin.records import Batch
from gbo_envs import ClosedLoop, ContinuousPlant, Experiment, PDT1Controller

PLANT = ContinuousPlant(num=(0.44262 / 0.070983,), den=(1.0, 15.0, 0.0), delay=0.001, output="position")


@pytest.fixture(scope="module")
def position_loop():
    """Closed-loop position records (errors on increments) and their linear fit."""
    loop = ClosedLoop(plant=PLANT, controller=PDT1Controller(), dt=0.001, duration=0.3, r1=0.03, r2=0.04,
                      output_noise_std=2e-4)
    rng = np.random.default_rng(0)
    records = []
    for k, g in enumerate(np.linspace([5123.8, 40.1], [6136.2, 51.0], 3)):
        res = loop.simulate(g[None, :], rng=rng)
        records.append(Experiment(gains=g, t=res.t, r=res.r, u=res.u[0], y=res.y[0], index=k))
    data = Batch.from_records(records)
    return data, fit_structure(data, None, ModelSpec(n_poles=2, n_integrators=1, output="position"))


def candidates(data, fit):
    """Model outputs as a diagnosis's candidates give them: the fit, offset, ramped, scaled and noisy."""
    rng = np.random.default_rng(1)
    t = data.t
    span = float(np.ptp(data.y))
    outs = {"fit": fit.y_sim, "offset": fit.y_sim + 0.3 * span, "ramp": fit.y_sim + 0.2 * span * t / t.max(),
            "gain": data.y + 1.05 * (fit.y_sim - data.y),
            "noise": fit.y_sim + 1e-3 * span * rng.standard_normal(t.shape),
            "lag": np.concatenate([fit.y_sim[:, :1], fit.y_sim[:, :-1]], axis=1)}
    out = {}
    for name, y_sim in outs.items():
        err = output_error(data.y, y_sim, data.mask, fit.spec, data.closed_loop)
        out[name] = dataclasses.replace(fit, y_sim=y_sim, rmse=rmse(err, mask=data.mask))  # a GreyFit's RMSE
    return out


def test_rmse_falls_iff_fit_rises_across_candidates(position_loop):
    data, fit = position_loop
    figures = {name: compare(data, cand) for name, cand in candidates(data, fit).items()}
    for name, cand in candidates(data, fit).items():
        assert figures[name].rmse_all == pytest.approx(cand.rmse, rel=1e-12)  # the RMSE a fit reports
    names = list(figures)
    for a in names:
        for b in names:
            ra, rb = figures[a].rmse_all, figures[b].rmse_all
            fa, fb = figures[a].fit_percent_all, figures[b].fit_percent_all
            if not np.isclose(ra, rb, rtol=1e-9):
                assert (ra < rb) == (fa > fb), (a, b, ra, rb, fa, fb)


def test_fit_percent_is_rmse_normalised(position_loop):
    """``fit = 100 (1 - RMSE sqrt(N) / ||d||)`` with one ``||d||`` for every candidate."""
    data, fit = position_loop
    n = int(data.mask.sum())
    scales = {name: (100.0 - c.fit_percent_all) / (c.rmse_all * np.sqrt(n))
              for name, c in ((k, compare(data, v)) for k, v in candidates(data, fit).items())}
    np.testing.assert_allclose(list(scales.values()), scales["fit"], rtol=1e-9)
