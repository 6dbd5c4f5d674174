"""Digital controllers with named gains and units, run by :class:`~gbo_envs.closed_loop.ClosedLoop`.

* :class:`PIController`, :class:`PDT1Controller`: the paper's first-order laws
  (eqs. (Cv) and (LM_Controller)), one recursion ``u[k] = b0 e[k] + b1 e[k-1] - a1 u[k-1]``;
* :class:`LinearController`: any linear law given as a continuous state space,
  Tustin at the loop's rate, with an output limit and anti-windup;
  :class:`PIDController` (PID with a derivative filter) and
  :class:`CascadeController` (position P -> speed PI with velocity feed-forward).
"""

from __future__ import annotations

from gbo_envs.controllers.base import Controller, DiscreteStateSpace
from gbo_envs.controllers.cascade import CascadeController
from gbo_envs.controllers.first_order import PDT1Controller, PIController
from gbo_envs.controllers.pid import PIDController
from gbo_envs.controllers.state_space import ANTI_WINDUP, LinearController, tustin

__all__ = ["ANTI_WINDUP", "CONTROLLERS", "CascadeController", "Controller", "DiscreteStateSpace", "LinearController",
           "PDT1Controller", "PIController", "PIDController", "tustin"]

CONTROLLERS = {"PI": PIController, "PDT1": PDT1Controller, "PID": PIDController, "cascade": CascadeController}
