"""The shared part of the peer-library adapters: the initial design, the data, the optional import."""

from __future__ import annotations

import abc
import importlib
from types import ModuleType

import numpy as np
from scipy.stats import qmc

from agents.base import Tuner
from agents.parameters import Interval, validate_params

__all__ = ["PeerTuner", "latin_hypercube", "require"]

#: What each extra installs, quoted in the ImportError of a missing library.
EXTRAS = {"peers": "the peer libraries", "mf": "multi-fidelity BO"}


def require(module: str, package: str, extra: str = "peers") -> ModuleType:
    """Import an optional library, or raise an ImportError that names the extra to install.

    Parameters
    ----------
    module : str
        Import name, e.g. ``"botorch"``.
    package : str
        Distribution name, e.g. ``"scikit-optimize"``.
    extra : str, default "peers"
        The ``gbo-envs`` extra that installs it, a key of :data:`EXTRAS`.
    """
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise ImportError(f'{package} is not installed; install {EXTRAS[extra]} with pip install '
                          f'"gbo-envs[{extra}]"') from exc


def latin_hypercube(rng: np.random.Generator, dim: int, n_initial: int) -> np.ndarray:
    """The initial design of ``agents.make("bo")``: ``n_initial`` unit-box points, shape (n_initial, dim).

    Drawn as :class:`agents.bo.BayesianOptimization` draws it (the first draw from the
    tuner rng), so that a peer and BO start from the same gains for the same seed.
    """
    return qmc.LatinHypercube(d=dim, rng=rng).random(n_initial)


class PeerTuner(Tuner):
    """Base of the peer adapters: BO's initial design first, then the library proposes.

    The first ``n_initial`` asks are BO's Latin hypercube points (:func:`latin_hypercube`);
    every tell goes to the library, which proposes from then on. The library works on
    the unit box ``[0, 1]^n`` (gains mapped by :meth:`agents.space.GainSpace.to_unit`) and
    is seeded by :attr:`library_seed`, the tuner rng's next draw, so runs reproduce.
    Asking twice without a tell returns the same proposal.

    Subclasses implement :meth:`_start` (build the library's optimizer), :meth:`_propose`
    (a unit-box point) and :meth:`_observe` (learn a unit-box point and its cost).

    A subclass names its library in :attr:`library`; one whose only keyword is
    ``n_initial`` inherits this constructor.

    Parameters
    ----------
    n_initial : int, default 1
        Size ``N0`` of the Latin hypercube initial design (the same points as ``agents.make("bo")``), ``>= 1``.

    Raises
    ------
    ImportError
        If the library is not installed (``pip install "gbo-envs[peers]"``).
    """

    #: (import name, distribution name) of the peer library
    library: tuple[str, str]

    _parameter_constraints: dict[str, list] = {"n_initial": [Interval(int, 1, None)]}

    def __init__(self, *, n_initial: int = 1) -> None:
        self._params = validate_params(self._parameter_constraints, {"n_initial": n_initial})
        require(*self.library)
        self.n_initial = self._params["n_initial"]

    def _setup(self) -> None:
        self._initial = latin_hypercube(self.rng, self.space.dim, self.n_initial)
        self.library_seed = int(self.rng.integers(2**31))
        self._X: list[np.ndarray] = []  # unit box
        self._y: list[float] = []  # costs
        self._pending: np.ndarray | None = None
        self._start()

    def _ask(self) -> np.ndarray:
        n = len(self._y)
        if n < self.n_initial:
            return self.space.from_unit(self._initial[n])
        if self._pending is None:
            self._pending = np.clip(np.asarray(self._propose(), dtype=float), 0.0, 1.0)
        return self.space.from_unit(self._pending)

    def _tell(self, gains: np.ndarray, cost: float, record: dict | None) -> None:
        unit = np.clip(self.space.to_unit(gains), 0.0, 1.0)
        self._X.append(unit)
        self._y.append(cost)
        self._pending = None
        self._observe(unit, cost)

    @abc.abstractmethod
    def _start(self) -> None:
        """Build the library's optimizer on the unit box, seeded by :attr:`library_seed`."""

    @abc.abstractmethod
    def _propose(self) -> np.ndarray:
        """The library's next point, shape (n_gains,), in the unit box."""

    @abc.abstractmethod
    def _observe(self, unit: np.ndarray, cost: float) -> None:
        """Tell the library a unit-box point of shape (n_gains,) and its cost (to be minimised)."""
