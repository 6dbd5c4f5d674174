"""Digital twin: identify the plant from closed-loop records and run the closed loop on it.

* :func:`identify_linear`: SRIVC identification of a continuous-time transfer
  function with input delay (the paper's DT plant), as a plain function;
* :class:`LinearTwin`: the same as a scikit-learn estimator (``fit``, ``predict``, ``score``);
* :class:`GreyBoxTwin`: the linear part plus physical effects of the catalogue, fitted
  by simulation error (scikit-learn estimator);
* :class:`TwinEnv` / :func:`make_twin_env`: the plant env's closed loop and cost
  with the identified plant, noise-free and vectorised.
"""

from __future__ import annotations

import importlib

from agents.twin.compare import compare
from agents.twin.csvio import read_csv, write_csv
from agents.twin.diagnose import diagnose
from agents.twin.diagnosis_options import CandidateSearch, DiagnosisRules
from agents.twin.env import TwinEnv, make_twin_env
from agents.twin.fits import fit_model
from agents.twin.identify import DelaySearch, IdentifyOptions, SrivcOptions, identify_linear
from agents.twin.ladder import error_ladder
from agents.twin.model import GreyFit, ModelSpec
from agents.twin.records import Batch
from agents.twin.residuals import residuals

#: The scikit-learn estimators, loaded on first access: the workbench's pipeline imports no scikit-learn (0.4 s
#: of every ``gbo twin`` command on the project machine).
_ESTIMATORS = {"GreyBoxTwin": "agents.twin.greybox_twin", "LinearTwin": "agents.twin.linear_twin"}

__all__ = ["GreyBoxTwin", "LinearTwin", "TwinEnv", "identify_linear", "make_twin_env"]
__all__ += ["Batch", "GreyFit", "ModelSpec", "compare", "diagnose", "error_ladder", "fit_model", "read_csv",
            "residuals", "write_csv"]
__all__ += ["CandidateSearch", "DelaySearch", "DiagnosisRules", "IdentifyOptions", "SrivcOptions"]


def __getattr__(name: str):
    if name in _ESTIMATORS:
        return getattr(importlib.import_module(_ESTIMATORS[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
