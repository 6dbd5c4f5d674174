"""BoTorch behind the tuner API: a SingleTaskGP and a log-EI acquisition (registry name ``botorch``)."""

from __future__ import annotations

import numpy as np

from agents.feasibility import constraint_set, reported_slacks
from agents.parameters import Interval, Options, validate_params
from agents.peers.base import PeerTuner, require

__all__ = ["ACQUISITIONS", "BoTorchTuner"]

#: ``acquisition`` values: BoTorch's qLogNoisyExpectedImprovement or analytic LogExpectedImprovement.
ACQUISITIONS = ("qlognei", "logei")

#: ``optimize_acqf``: L-BFGS-B starting points, and the random points they are picked from.
NUM_RESTARTS, RAW_SAMPLES = 8, 256


class BoTorchTuner(PeerTuner):
    """BoTorch's standard loop on the unit box, after BO's initial design.

    Every proposal: a ``SingleTaskGP`` (BoTorch's defaults: Matern 5/2 ARD with its
    priors, learned noise) on the unit-box gains and the negated costs (BoTorch
    maximises), outcomes standardised (``Standardize``), hyperparameters by
    ``fit_gpytorch_mll``; then the acquisition is maximised over the unit box by
    ``optimize_acqf``. Computed in float64; torch's random state is seeded from the
    tuner rng for every proposal (and restored afterwards), so runs reproduce.

    Parameters
    ----------
    n_initial : int, default 1
        Size ``N0`` of the Latin hypercube initial design (the same points as ``agents.make("bo")``).
    acquisition : {"qlognei", "logei"}, default "qlognei"
        ``"qlognei"``: ``qLogNoisyExpectedImprovement`` with the training gains as baseline.
        ``"logei"``: ``LogExpectedImprovement`` with ``best_f`` the best measured cost
        (the maximum of the negated costs).

    Raises
    ------
    ImportError
        If BoTorch is not installed (``pip install "gbo-envs[peers]"``).

    Notes
    -----
    On an env with constraints (``env.unwrapped.constraints``), BoTorch's outcome constraints:
    the ``SingleTaskGP`` models the negated cost and every constraint's ``value - limit``
    (:func:`agents.feasibility.reported_slacks`) as outcomes (each standardised), and the
    acquisition is constrained: ``"qlognei"`` is ``qLogNoisyExpectedImprovement`` with the cost
    as objective and ``constraints=[Z -> Z[..., 1 + j]]`` (feasible where ``<= 0``, BoTorch's
    convention, weighted by a sigmoid of the samples); ``"logei"`` is
    ``LogConstrainedExpectedImprovement`` with every constraint outcome bounded above by 0 and
    ``best_f`` the best feasible cost (the best cost while none is feasible).
    """

    name = "botorch"
    library = ("botorch", "botorch")

    _parameter_constraints: dict[str, list] = {
        "n_initial": [Interval(int, 1, None)],
        "acquisition": [Options(ACQUISITIONS)],
    }

    def __init__(self, *, n_initial: int = 1, acquisition: str = "qlognei") -> None:
        self._params = validate_params(self._parameter_constraints, {
            "n_initial": n_initial, "acquisition": acquisition})
        require(*self.library)
        self.n_initial = self._params["n_initial"]
        self.acquisition = self._params["acquisition"]

    def _start(self) -> None:
        self._seeds = np.random.default_rng(self.library_seed)
        self._constraints = constraint_set(self.env)
        self._C: list[list[float]] = []

    def _tell(self, gains: np.ndarray, cost: float, record: dict | None) -> None:
        if self._constraints is not None:
            self._C.append(reported_slacks(record, *self._constraints))
        super()._tell(gains, cost, record)

    def _observe(self, unit: np.ndarray, cost: float) -> None:
        """Nothing to do: the GP is refitted on all data at every proposal."""

    def _propose(self) -> np.ndarray:
        import torch
        from botorch.acquisition import LogExpectedImprovement, qLogNoisyExpectedImprovement
        from botorch.fit import fit_gpytorch_mll
        from botorch.models import SingleTaskGP
        from botorch.models.transforms.outcome import Standardize
        from botorch.optim import optimize_acqf
        from gpytorch.mlls import ExactMarginalLogLikelihood

        dim = self.space.dim
        with torch.random.fork_rng():
            torch.manual_seed(int(self._seeds.integers(2**31)))
            train_x = torch.as_tensor(np.asarray(self._X), dtype=torch.float64)
            train_y = -torch.as_tensor(np.asarray(self._y), dtype=torch.float64).unsqueeze(-1)
            if self._constraints is not None:
                acqf = self._constrained_acquisition(train_x, train_y)
            else:
                model = SingleTaskGP(train_x, train_y, outcome_transform=Standardize(m=1))
                fit_gpytorch_mll(ExactMarginalLogLikelihood(model.likelihood, model))
                if self.acquisition == "qlognei":
                    acqf = qLogNoisyExpectedImprovement(model, X_baseline=train_x)
                else:
                    acqf = LogExpectedImprovement(model, best_f=train_y.max())
            bounds = torch.stack([torch.zeros(dim, dtype=torch.float64), torch.ones(dim, dtype=torch.float64)])
            candidate, _ = optimize_acqf(acqf, bounds=bounds, q=1, num_restarts=NUM_RESTARTS,
                                         raw_samples=RAW_SAMPLES)
        return candidate.detach().numpy().reshape(dim)

    def _constrained_acquisition(self, train_x, train_y):
        """BoTorch's constrained acquisition on the cost and the constraint outcomes (class Notes)."""
        import torch
        from botorch.acquisition import qLogNoisyExpectedImprovement
        from botorch.acquisition.analytic import LogConstrainedExpectedImprovement
        from botorch.acquisition.objective import GenericMCObjective
        from botorch.fit import fit_gpytorch_mll
        from botorch.models import SingleTaskGP
        from botorch.models.transforms.outcome import Standardize
        from gpytorch.mlls import ExactMarginalLogLikelihood

        slacks = torch.as_tensor(np.asarray(self._C), dtype=torch.float64).reshape(train_y.shape[0], -1)
        k = slacks.shape[1]
        outcomes = torch.cat([train_y, slacks], dim=-1)
        model = SingleTaskGP(train_x, outcomes, outcome_transform=Standardize(m=1 + k))
        fit_gpytorch_mll(ExactMarginalLogLikelihood(model.likelihood, model))
        if self.acquisition == "qlognei":
            return qLogNoisyExpectedImprovement(
                model, X_baseline=train_x, objective=GenericMCObjective(lambda Z, X=None: Z[..., 0]),
                constraints=[lambda Z, j=j: Z[..., 1 + j] for j in range(k)])
        feasible = torch.all(slacks <= 0, dim=-1)
        best = train_y[feasible].max() if bool(feasible.any()) else train_y.max()
        return LogConstrainedExpectedImprovement(model, best_f=best, objective_index=0,
                                                 constraints={1 + j: (None, 0.0) for j in range(k)})
