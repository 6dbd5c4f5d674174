"""The settings of :class:`~gbo_envs.envs.external.ExternalPlantEnv` that belong together, as keyword-only objects.

:class:`StepExperiment` is what one experiment on the rig is (the reference step, its
sampling and length); :class:`FailurePolicy` says when an experiment has failed and what
follows. Both are frozen and checked when made: a bad setting raises ``ValueError`` naming it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["FAILURE_POLICIES", "FailurePolicy", "StepExperiment"]

#: Values of ``FailurePolicy.on_failure``.
FAILURE_POLICIES = ("penalize", "stop", "skip")


def _positive_or_none(name: str, value) -> float | None:
    if value is None:
        return None
    if isinstance(value, bool) or not (np.isfinite(value) and value > 0):
        raise ValueError(f"{name}: must be a number > 0 or None, got {value}")
    return float(value)


@dataclass(frozen=True)
class StepExperiment:
    """One step experiment on the rig: the reference steps from ``r1`` to ``r2`` at ``t = 0``.

    Parameters
    ----------
    reference : tuple (r1, r2)
        The reference before and after the step, finite with ``r1 != r2``, in the units of ``y``.
    dt : float, optional
        Sample time in s, ``> 0``. With ``duration``, it enables the record checks (the sample
        time, the length) and lets a digital twin simulate the loop.
    duration : float, optional
        Length of one experiment in s, ``> dt``.

    Examples
    --------
    >>> StepExperiment((245, 306), dt=0.002, duration=5)
    StepExperiment(reference=(245.0, 306.0), dt=0.002, duration=5.0)
    """

    reference: tuple[float, float]
    dt: float | None = None
    duration: float | None = None

    def __post_init__(self) -> None:
        try:
            r1, r2 = (float(v) for v in self.reference)
        except (TypeError, ValueError):
            raise ValueError(f"reference: expected (r1, r2) finite with r1 != r2, got {self.reference!r}") from None
        if not (np.isfinite(r1) and np.isfinite(r2)) or r1 == r2:
            raise ValueError(f"reference: expected (r1, r2) finite with r1 != r2, got {self.reference!r}")
        dt = _positive_or_none("dt", self.dt)
        duration = _positive_or_none("duration", self.duration)
        if dt is not None and duration is not None and duration <= dt:
            raise ValueError(f"duration: must exceed dt = {dt} s, got {duration}")
        object.__setattr__(self, "reference", (r1, r2))
        object.__setattr__(self, "dt", dt)
        object.__setattr__(self, "duration", duration)


@dataclass(frozen=True)
class FailurePolicy:
    """When an experiment on the rig has failed, and what follows (:class:`~gbo_envs.envs.external.ExternalPlantEnv`).

    An experiment fails when ``run_experiment`` raises, runs past ``timeout_s``, or returns a
    malformed record (among the checks: a median sample time more than ``dt_rtol`` off ``dt``).

    Parameters
    ----------
    on_failure : {"penalize", "stop", "skip"}, default "penalize"
        ``"penalize"``: ``step`` reports ``failure_cost`` and the session goes on; ``"stop"``:
        ``step`` raises :class:`~gbo_envs.envs.external.ExperimentFailed` and the session ends;
        ``"skip"``: it raises with ``policy="skip"`` and the tuner is asked again without being told.
    failure_cost : float, optional
        Cost reported under ``"penalize"``, finite, dimensionless (default: the env's ``unstable_cost``).
    timeout_s : float, optional
        Wall-time limit of one experiment in s, ``> 0`` (default: none).
    dt_rtol : float, default 0.05
        Allowed relative error of the record's median sample time against ``dt``, ``> 0``.

    Examples
    --------
    >>> FailurePolicy(on_failure="stop", timeout_s=30)
    FailurePolicy(on_failure='stop', failure_cost=None, timeout_s=30.0, dt_rtol=0.05)
    """

    on_failure: str = "penalize"
    failure_cost: float | None = None
    timeout_s: float | None = None
    dt_rtol: float = 0.05

    def __post_init__(self) -> None:
        if self.on_failure not in FAILURE_POLICIES:
            raise ValueError(f"on_failure: must be one of {FAILURE_POLICIES}, got {self.on_failure!r}")
        if self.failure_cost is not None:
            if isinstance(self.failure_cost, bool) or not np.isfinite(self.failure_cost):
                raise ValueError(f"failure_cost: must be finite, got {self.failure_cost}")
            object.__setattr__(self, "failure_cost", float(self.failure_cost))
        object.__setattr__(self, "timeout_s", _positive_or_none("timeout_s", self.timeout_s))
        if isinstance(self.dt_rtol, bool) or not (np.isfinite(self.dt_rtol) and self.dt_rtol > 0):
            raise ValueError(f"dt_rtol: must be > 0, got {self.dt_rtol}")
        object.__setattr__(self, "dt_rtol", float(self.dt_rtol))
