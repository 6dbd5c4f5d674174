"""Digital twin: identify the plant from closed-loop records and run the closed loop on it.

* :class:`TwinEstimator`: scikit-learn-style SRIVC identification of a
  continuous-time transfer function with input delay (the paper's DT plant).
* :class:`TwinEnv` / :func:`make_twin_env`: the plant env's closed loop and cost
  with the identified plant, noise-free and vectorised.
"""

from __future__ import annotations

from agents.twin.env import TwinEnv, make_twin_env
from agents.twin.estimator import TwinEstimator

__all__ = ["TwinEnv", "TwinEstimator", "make_twin_env"]
