"""The result of a tuning run: the records of its real experiments and a tidy table of them."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from gbo_envs.experiment import SIGNALS, Experiment
from gbo_envs.lazy_pyplot import pyplot
from gbo_envs.metrics import METRIC_NAMES
from gbo_envs.plotting import COST_LABEL, REFERENCE, axis_label, cost_surface, legend_outside, style

__all__ = ["CONSTRAINT_PREFIX", "TuningResult", "METRIC_COLUMNS", "SAMPLE_COLUMNS", "TABLE_COLUMNS",
           "constraint_columns", "env_constraints"]

#: Metric columns of a result table, in the env's metric order.
METRIC_COLUMNS = METRIC_NAMES
#: Leading columns of :meth:`TuningResult.to_pandas` (the gain names follow ``source``).
TABLE_COLUMNS = ("experiment", "source", "cost", "best_cost", "true_cost", "unstable", "feasible", *METRIC_COLUMNS,
                 "wall_time")
#: Prefix of the columns of a constrained run's ``value - limit`` per constraint (``constraint_peak_u``).
CONSTRAINT_PREFIX = "constraint_"
#: Columns of :meth:`TuningResult.samples`.
SAMPLE_COLUMNS = ("experiment", "source", *SIGNALS)
#: Record fields a row takes from the record itself, never from ``columns``.
_RECORD_KEYS = frozenset({"experiment", "experiment_index", "source", "gains", "cost", "metrics", *SIGNALS})


@dataclass(eq=False, repr=False)
class TuningResult:
    """Everything a tuning run produced.

    ``to_pandas()`` has one row per real (plant) experiment; digital-twin
    evaluations are rows with ``source == "twin"`` that only
    ``to_pandas(include_twin=True)`` shows. ``samples()`` is the long table of
    the recorded signals. ``print(result)`` gives a one-line summary.

    Attributes
    ----------
    tuner : str
        Registry name of the tuner.
    env_id : str
        Id of the env (or its class name).
    gain_names : tuple of str
    rows : list of dict
        The table in run order, plant and twin rows (see :meth:`to_pandas`);
        written through :meth:`add`.
    seed : int or None
    interrupted : bool
        Whether the run was stopped early (rows hold what finished).
    info : dict
        Tuner parameters (``"params"``) and tuner-specific figures.
    experiments : list of Experiment
        The record of every plant row, in the same order as :attr:`plant_rows`
        (without signals when none were recorded, e.g. a failed rig experiment).
    gain_units : tuple of str
        Units of the gains (the env's ``gain_units``; empty when unknown).
    constraints : dict
        ``{name: limit}`` of the env's constraints (empty without); the best result is then the
        best *feasible* experiment, and :attr:`violations` counts those that broke a limit.
    """

    tuner: str
    env_id: str
    gain_names: tuple[str, ...]
    rows: list[dict] = field(default_factory=list)
    seed: int | None = None
    interrupted: bool = False
    info: dict = field(default_factory=dict)
    experiments: list[Experiment] = field(default_factory=list)
    gain_units: tuple[str, ...] = ()
    constraints: dict = field(default_factory=dict)

    def add(self, record: Experiment, experiment: int, best_cost: float, wall_time: float,
            columns: Mapping | None = None) -> dict:
        """Append ``record`` as a row of the table (and a plant record to :attr:`experiments`).

        Parameters
        ----------
        record : Experiment
            Its ``source``, gains, cost and metrics fill those columns.
        experiment : int
            Number of the plant experiment (1-based); a twin row carries the
            number of the plant experiment it was made for.
        best_cost : float
            Lowest measured cost so far (NaN for a twin row).
        wall_time : float
            Time since the run started, in s.
        columns : mapping, optional
            Further columns (``true_cost``, ``unstable``, tuner-specific ones);
            keys that name record fields (``gains``, ``cost``, ``metrics``, ...) are ignored.

        Returns
        -------
        dict
            The row.
        """
        if record.gains.size != len(self.gain_names):
            raise ValueError(f"record.gains: expected {len(self.gain_names)} gains {self.gain_names}, "
                             f"got {record.gains.size}")
        row: dict = {"experiment": int(experiment), "source": record.source}
        row.update({name: float(g) for name, g in zip(self.gain_names, record.gains)})
        row["cost"] = record.cost
        row["best_cost"] = float(best_cost)
        for column in METRIC_COLUMNS:
            row[column] = float(record.metrics.get(column, math.nan))
        row["wall_time"] = float(wall_time)
        row.update({key: value for key, value in (columns or {}).items() if key not in _RECORD_KEYS})
        self.rows.append(row)
        if record.source == "plant":
            self.experiments.append(record)
        return row

    def to_pandas(self, include_twin: bool = False):
        """The table as a :class:`pandas.DataFrame`, one row per real experiment.

        Columns: ``experiment`` (1-based), ``source``, one per gain (e.g. ``Kp,
        Ki``), ``cost`` (measured), ``best_cost`` (lowest measured so far; with
        constraints, over the feasible experiments), ``true_cost`` (noise-free,
        NaN when unknown), ``unstable``, ``feasible`` (kept every constraint and
        stable; NaN when unknown), then with constraints ``constraint_<name>``
        (``value - limit``, ``<= 0`` kept) after the other columns,
        ``overshoot_pct, settling_time, rise_time, itae``, ``wall_time`` (s
        since the run started), then any tuner- or session-specific columns
        (e.g. ``status, reason`` of a session).

        Parameters
        ----------
        include_twin : bool, default False
            Also the digital-twin evaluations (``source == "twin"``, in run
            order before the plant experiment they were made for, with
            ``best_cost`` NaN and the tuner's twin columns such as
            ``activation, twin_iteration, twin_true_cost``).
        """
        import pandas as pd

        columns = [*TABLE_COLUMNS[:2], *self.gain_names, *TABLE_COLUMNS[2:]]
        frame = pd.DataFrame(self.rows if include_twin else self.plant_rows)
        extras = [c for c in frame.columns if c not in columns]
        for column in columns:
            if column not in frame:
                frame[column] = np.nan
        return frame[columns + extras]

    def samples(self):
        """The recorded signals as a long table, one row per sample of every real experiment.

        Columns :data:`SAMPLE_COLUMNS`: ``experiment`` (as in :meth:`to_pandas`),
        ``source``, ``t`` (s since the reference step), ``r, u, y`` (the env's
        units). Experiments recorded without signals are left out.
        """
        import pandas as pd

        frames = [pd.DataFrame({"experiment": np.full(record.n_steps, row["experiment"]),
                                "source": record.source, **{name: getattr(record, name) for name in SIGNALS}})
                  for row, record in zip(self.plant_rows, self.experiments) if record.has_signals]
        if not frames:
            return pd.DataFrame({name: pd.Series(dtype=float) for name in SAMPLE_COLUMNS})
        return pd.concat(frames, ignore_index=True)

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
        """Number of digital-twin evaluations logged as rows (``source == "twin"``)."""
        return len(self.rows) - self.n_experiments

    @property
    def twin_evaluations(self) -> int:
        """Twin simulations the tuner made: its own count (``info["twin_evaluations"]``) if it reports one,
        else :attr:`n_twin`. With the twin as the prior mean (guided BO's default) the twin is simulated on
        the acquisition grid, and those simulations are not rows."""
        reported = self.info.get("twin_evaluations")
        return int(reported) if reported is not None else self.n_twin

    def _best_row(self) -> dict:
        rows = self.plant_rows
        if not rows:
            raise ValueError("result: no plant experiment was run")
        kept = [row for row in rows if row.get("feasible") is True]
        return min(kept if self.constraints and kept else rows, key=lambda row: row["cost"])

    @property
    def violations(self) -> int:
        """Plant experiments that broke a constraint or went unstable (``feasible`` false)."""
        return sum(1 for row in self.plant_rows if row.get("feasible") is False)

    @property
    def n_feasible(self) -> int:
        """Plant experiments that kept every constraint."""
        return sum(1 for row in self.plant_rows if row.get("feasible") is True)

    @property
    def best_gains(self) -> np.ndarray:
        """Gains of the lowest measured cost, shape (n_gains,); with constraints, of the lowest feasible one
        (of all experiments if none was feasible)."""
        row = self._best_row()
        return np.array([row[name] for name in self.gain_names])

    @property
    def best_cost(self) -> float:
        """Lowest measured (noisy) cost over the plant experiments (the feasible ones, with constraints)."""
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

    def __repr__(self) -> str:
        """One line: tuner, env, seed, real experiments (and twin evaluations; with constraints the violations),
        best (feasible) gains with units, best cost."""
        twin = f" (+{self.twin_evaluations} twin evaluations)" if self.twin_evaluations else ""
        head = (f"TuningResult({self.tuner} on {self.env_id}, seed {self.seed}: {self.n_experiments} real "
                f"experiments{twin}{', interrupted' if self.interrupted else ''}")
        if self.constraints:
            head += f", {self.violations} broke a constraint"
        if not self.n_experiments:
            return head + ")"
        if self.constraints and not self.n_feasible:
            return head + "; no feasible experiment)"
        units = self.gain_units if len(self.gain_units) == len(self.gain_names) else ("",) * len(self.gain_names)
        gains = ", ".join(f"{name} = {value:.4g}{'' if unit in ('', '-') else ' ' + unit}"
                          for name, value, unit in zip(self.gain_names, self.best_gains, units))
        return f"{head}; best {gains}, cost {self.best_cost:.4g})"

    def plot(self, ax=None, optimum: float | None = None):
        """Measured and best measured cost against the plant experiments, twin refits marked.

        Axes: plant experiments (count, from 1); cost J (-).

        Parameters
        ----------
        ax : matplotlib Axes, optional
        optimum : float, optional
            Ground-truth ``J(theta*)`` drawn as a horizontal line.

        Returns
        -------
        matplotlib Axes
        """
        plt = pyplot()
        with style():
            if ax is None:
                _, ax = plt.subplots(figsize=(7.5, 4))
            rows = self.plant_rows
            experiments = [row["experiment"] for row in rows]
            ax.plot(experiments, [row["cost"] for row in rows], "o", ms=3, alpha=0.5, label="measured cost")
            ax.step(experiments, [row["best_cost"] for row in rows], where="post", label="best measured cost")
            self._plot_twin_rows(ax)
            if optimum is not None:
                ax.axhline(optimum, label="ground-truth optimum J*", **REFERENCE)
            # twin refits (guided BO): after experiment n the twin shown in the label drives the twin iterations
            for k, change in enumerate(self.info.get("twin_changes", [])):
                effects = "+".join(change.get("effects", {})) or "linear"
                ax.axvline(change["experiment"] + 0.5, color="tab:green", ls=":", lw=1,
                           label="twin refitted" if k == 0 else None)
                ax.annotate(effects, (change["experiment"] + 0.5, 1.0), xycoords=("data", "axes fraction"),
                            rotation=90, va="top", ha="right", fontsize=7, color="tab:green")
            ax.set_xlabel(axis_label("plant experiments", "count"))
            ax.set_ylabel(COST_LABEL)
            ax.set_title(f"{self.tuner} on {self.env_id}")
            legend_outside(ax)
        return ax

    def plot_gains(self, truth, ax=None):
        """The gains this run queried, in order, on the ground-truth cost surface with ``J*`` marked.

        Axes: the two gains in their units; colour bar: cost J (-).

        Parameters
        ----------
        truth : gbo_envs.GroundTruth
            Two-gain ground truth of the same env.
        ax : matplotlib Axes, optional

        Returns
        -------
        matplotlib Axes
        """
        path = self._gains_of(self.plant_rows)
        twin = self._gains_of(self._twin_rows())
        points = {f"twin evaluations ({len(twin)})": twin} if len(twin) else None
        ax = cost_surface(truth, ax=ax, points=points, path=path)
        ax.set_title(f"{self.tuner} on {self.env_id}, seed {self.seed}")
        return ax

    def _twin_rows(self) -> list[dict]:
        return [row for row in self.rows if row["source"] == "twin"]

    def _gains_of(self, rows: list[dict]) -> np.ndarray:
        """The gains of ``rows``, shape (len(rows), n_gains)."""
        return np.array([[row[name] for name in self.gain_names] for row in rows]).reshape(-1, len(self.gain_names))

    def _plot_twin_rows(self, ax) -> None:
        """Twin evaluations as crosses just before the plant experiment they were made for.

        Coloured by their fidelity ``s`` (multi-fidelity BO's ``fidelity`` column; the
        plant's is 1) with a colour bar, or in one colour when the rows carry none.
        """
        twins = self._twin_rows()
        if not twins:
            return
        x = [row["experiment"] - 0.5 for row in twins]
        cost = [row["cost"] for row in twins]
        fidelity = [row.get("fidelity", math.nan) for row in twins]
        if all(math.isfinite(s) for s in fidelity):
            points = ax.scatter(x, cost, c=fidelity, marker="x", s=14, cmap="viridis", vmin=0.0, vmax=1.0,
                                label="twin evaluations (colour: fidelity s)")
            ax.figure.colorbar(points, ax=ax, label="fidelity s (plant: 1)")
        else:
            ax.plot(x, cost, "x", ms=4, color="tab:purple", alpha=0.6, label="twin evaluations")


def env_constraints(env) -> dict:
    """``{name: limit}`` of an env's constraints (``env.unwrapped.constraints``), ``{}`` without."""
    limits = getattr(getattr(env, "unwrapped", env), "constraints", None)
    return dict(limits.to_spec()) if limits else {}


def constraint_columns(info: Mapping, failed: bool = False) -> dict:
    """The row columns of an experiment's constraints: ``feasible`` and ``constraint_<name>`` per constraint.

    ``feasible`` is ``info["feasible"]`` when the env reports it, else stable and not failed.
    """
    feasible = info.get("feasible")
    if feasible is None:
        feasible = not failed and not bool(info.get("unstable", False))
    columns = {"feasible": bool(feasible)}
    for name, value in (info.get("constraints") or {}).items():
        columns[CONSTRAINT_PREFIX + name] = float(value)
    return columns
