"""Twin workbench: compare a twin with measurements, analyse its residuals, diagnose the missing effect.

* :func:`fit_model`: grey-box fit of a model structure (:mod:`agents.twin.greybox`),
  started from the SRIVC fit of the linear part and data-based effect guesses
  (:mod:`agents.twin.fitting`, :mod:`agents.twin.guesses`);
* :func:`compare`: fit % (NRMSE as MATLAB's ``compare``) and RMSE per experiment and overall
  (:mod:`agents.twin.compare`);
* :func:`residuals`: whiteness, input cross-correlation and where the model fails (:mod:`agents.twin.residuals`);
* :func:`noise_floor`: the measurement's noise or quantization floor (:mod:`agents.twin.noise`);
* :func:`diagnose`: every catalogued effect tried as an addition, ranked on held-out experiments;
* :func:`error_ladder`: add the best effect, diagnose again, until nothing helps
  (:mod:`agents.twin.diagnose`, with the evidence of :mod:`agents.twin.evidence`);
* :func:`fit_twin_effects` and friends: the :class:`~agents.twin.TwinEstimator` with effects
  (:mod:`agents.twin.effect_estimator`).

This module gathers their public functions in one place.

Conventions (generic closed-loop data, nothing of the DC motor assumed): each
record starts at rest; the base linear model has ``n_poles`` poles and an input
delay of at most one sample (the computation delay of a digital loop; a longer
dead time is the ``time_delay`` effect); each record has its own rest level
``y0`` and plant-input bias (SRIVC's rest input in disguise).
"""

from __future__ import annotations

from agents.twin.compare import CompareResult, compare
from agents.twin.diagnose import Diagnosis, diagnose, error_ladder, heldout_rss
from agents.twin.effect_estimator import fit_twin_effects, predict_twin_effects, rmse_twin_effects
from agents.twin.evidence import SEPARATING_EXPERIMENTS, separating_experiment
from agents.twin.fitting import PROFILE_EFFECTS, candidate_problems, fit_model, linear_fit, refine_grid_parameters
from agents.twin.guesses import data_scales, effect_starts
from agents.twin.noise import noise_floor, quantization_step
from agents.twin.residuals import ResidualAnalysis, residuals

__all__ = ["CompareResult", "Diagnosis", "ResidualAnalysis", "SEPARATING_EXPERIMENTS", "compare", "data_scales",
           "diagnose", "effect_starts", "error_ladder", "fit_model", "heldout_rss", "linear_fit", "noise_floor",
           "fit_twin_effects", "predict_twin_effects", "quantization_step", "residuals", "rmse_twin_effects",
           "separating_experiment"]
__all__ += ["PROFILE_EFFECTS", "candidate_problems", "refine_grid_parameters"]
