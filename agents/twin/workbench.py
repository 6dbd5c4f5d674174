"""Twin workbench: compare a twin with measurements, analyse its residuals, diagnose the missing effect.

* :func:`fit_model`: grey-box fit of a model structure (:mod:`agents.twin.model`, :mod:`agents.twin.least_squares`),
  started from the SRIVC fit of the linear part and data-based effect guesses
  (:mod:`agents.twin.fits`, :mod:`agents.twin.linear_fit`, :mod:`agents.twin.guesses`);
* :func:`compare`: fit % (NRMSE as MATLAB's ``compare``) and RMSE per experiment and overall
  (:mod:`agents.twin.compare`);
* :func:`residuals`: whiteness, input cross-correlation and where the model fails (:mod:`agents.twin.residuals`);
* :func:`noise_floor`: the measurement's noise or quantization floor (:mod:`agents.twin.noise_floor`);
* :func:`diagnose`: every catalogued effect tried as an addition, ranked on held-out experiments
  (its decision rules :class:`DiagnosisRules`, its search :class:`CandidateSearch`);
* :func:`error_ladder`: add the best effect, diagnose again, until nothing helps
  (:mod:`agents.twin.diagnose`, :mod:`agents.twin.ladder`, with the evidence of :mod:`agents.twin.evidence`);
* :class:`GreyBoxTwin`: the grey-box fit as a scikit-learn estimator (:mod:`agents.twin.greybox_twin`),
  and :class:`LinearTwin`, the paper's linear twin by SRIVC (:mod:`agents.twin.linear_twin`).

This module gathers their public functions in one place.

Conventions (generic data, open or closed loop, nothing of the DC motor assumed): the
base linear model has ``n_poles`` poles and an input delay of at most one sample (the
computation delay of a digital loop; a longer dead time is the ``time_delay`` effect);
each record starts where its data say (:mod:`agents.twin.initial`): at a rest it shows,
with its rest level and command measured and pinned, or at a rest it does not show, with
its own rest level ``y0`` and plant-input bias estimated (SRIVC's rest input in disguise).
"""

from __future__ import annotations

import importlib

from agents.twin.candidates import candidate_problems
from agents.twin.compare import CompareResult, compare
from agents.twin.diagnose import Diagnosis, diagnose
from agents.twin.diagnosis_options import CandidateSearch, DiagnosisRules
from agents.twin.evidence import SEPARATING_EXPERIMENTS, separating_experiment
from agents.twin.fits import fit_model, refine_grid_parameters
from agents.twin.guesses import data_scales, effect_starts
from agents.twin.ladder import error_ladder
from agents.twin.linear_fit import PROFILE_EFFECTS, linear_fit
from agents.twin.noise_floor import noise_floor, quantization_step
from agents.twin.ranking import heldout_rss
from agents.twin.residuals import ResidualAnalysis, residuals

__all__ = ["CompareResult", "Diagnosis", "ResidualAnalysis", "SEPARATING_EXPERIMENTS", "compare", "data_scales",
           "diagnose", "effect_starts", "error_ladder", "fit_model", "heldout_rss", "linear_fit", "noise_floor",
           "quantization_step", "residuals", "separating_experiment"]
__all__ += ["PROFILE_EFFECTS", "candidate_problems", "refine_grid_parameters"]
__all__ += ["CandidateSearch", "DiagnosisRules"]

#: The scikit-learn estimators, loaded on first access: the pipeline itself imports no scikit-learn (0.4 s of
#: every ``gbo twin`` command on the project machine).
_ESTIMATORS = {"GreyBoxTwin": "agents.twin.greybox_twin", "LinearTwin": "agents.twin.linear_twin"}
__all__ += list(_ESTIMATORS)


def __getattr__(name: str):
    if name in _ESTIMATORS:
        return getattr(importlib.import_module(_ESTIMATORS[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
