"""BoTorch behind the tuner API: a SingleTaskGP and a log-EI acquisition (registry name ``botorch``)."""

from __future__ import annotations

import numpy as np

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
