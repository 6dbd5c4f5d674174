"""The tidy result of a tuning run: one row per experiment."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["TuningResult", "METRIC_COLUMNS"]

#: Metric columns of a result table, in the env's metric order.
METRIC_COLUMNS = ("overshoot_pct", "settling_time", "rise_time", "itae")


@dataclass(eq=False)
class TuningResult:
    """Everything a tuning run produced, one row per experiment.

    Rows with ``source == "plant"`` are real experiments (counted in
    ``experiment``, 1-based); rows with ``source == "twin"`` are digital-twin
    evaluations made before the plant experiment of the same number.

    Attributes
    ----------
    tuner : str
        Registry name of the tuner.
    env_id : str
        Id of the env (or its class name).
    gain_names : tuple of str
    rows : list of dict
        Columns: ``experiment, source, <gain names>, cost, best_cost,
        true_cost, unstable, overshoot_pct, settling_time, rise_time, itae,
        wall_time`` (s since the run started), plus tuner-specific extras.
    seed : int or None
    interrupted : bool
        Whether the run was stopped early (rows hold what finished).
    """

    tuner: str
    env_id: str
    gain_names: tuple[str, ...]
    rows: list[dict] = field(default_factory=list)
    seed: int | None = None
    interrupted: bool = False
    info: dict = field(default_factory=dict)

    def to_pandas(self):
        """The rows as a :class:`pandas.DataFrame`."""
        import pandas as pd

        columns = ["experiment", "source", *self.gain_names, "cost", "best_cost", "true_cost", "unstable",
                   *METRIC_COLUMNS, "wall_time"]
        frame = pd.DataFrame(self.rows)
        extras = [c for c in frame.columns if c not in columns]
        for column in columns:
            if column not in frame:
                frame[column] = np.nan
        return frame[columns + extras]

    @property
    def plant_rows(self) -> list[dict]:
        """Rows of real experiments only."""
        return [row for row in self.rows if row["source"] == "plant"]

    @property
    def n_experiments(self) -> int:
        """Number of real (plant) experiments."""
        return len(self.plant_rows)

    @property
    def n_twin(self) -> int:
        """Number of digital-twin evaluations."""
        return len(self.rows) - self.n_experiments

    def _best_row(self) -> dict:
        rows = self.plant_rows
        if not rows:
            raise ValueError("result: no plant experiment was run")
        return min(rows, key=lambda row: row["cost"])

    @property
    def best_gains(self) -> np.ndarray:
        """Gains of the lowest measured cost, shape (n_gains,)."""
        row = self._best_row()
        return np.array([row[name] for name in self.gain_names])

    @property
    def best_cost(self) -> float:
        """Lowest measured (noisy) cost over the plant experiments."""
        return float(self._best_row()["cost"])

    def min_true_cost_curve(self) -> np.ndarray:
        """Lowest noise-free cost observed up to each plant experiment, shape (n_experiments,).

        Divided by ``J(theta*)`` this is the paper's *minimum observed optimality
        ratio* (issue 4: "best observed noise-free cost / ground-truth optimum").
        """
        values = [row.get("true_cost", row["cost"]) for row in self.plant_rows]
        return np.fmin.accumulate(np.asarray(values, dtype=float)) if values else np.empty(0)

    def best_true_cost_curve(self) -> np.ndarray:
        """Noise-free cost of the best-measured gains after each plant experiment, shape (n_experiments,).

        A stricter variant of :meth:`min_true_cost_curve`: the tuner's own choice
        (lowest measured cost) judged by its true cost.
        """
        curve, best_measured, best_true = [], np.inf, np.nan
        for row in self.plant_rows:
            if row["cost"] < best_measured:
                best_measured, best_true = row["cost"], row.get("true_cost", row["cost"])
            curve.append(best_true)
        return np.asarray(curve, dtype=float)

    def plot(self, ax=None, optimum: float | None = None):
        """Best measured cost against the number of plant experiments.

        Parameters
        ----------
        ax : matplotlib Axes, optional
        optimum : float, optional
            Ground-truth ``J(theta*)`` drawn as a horizontal line.
        """
        from gbo_envs.lazy_pyplot import pyplot

        plt = pyplot()
        if ax is None:
            _, ax = plt.subplots(figsize=(6, 4))
        rows = self.plant_rows
        experiments = [row["experiment"] for row in rows]
        ax.plot(experiments, [row["cost"] for row in rows], "o", ms=3, alpha=0.5, label="measured cost")
        ax.step(experiments, [row["best_cost"] for row in rows], where="post", label="best measured cost")
        if optimum is not None:
            ax.axhline(optimum, color="k", ls="--", lw=1, label="ground-truth optimum")
        ax.set_xlabel("plant experiments")
        ax.set_ylabel("cost J")
        ax.set_title(f"{self.tuner} on {self.env_id}")
        ax.legend(fontsize=8)
        return ax
