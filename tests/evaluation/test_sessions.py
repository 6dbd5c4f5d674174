"""Crash-safe tuning sessions: the SQLite log, resume by replay, failure policies, export and the CLI."""

from __future__ import annotations

import logging
import os
import re
import socket
import sqlite3
import subprocess
import sys

import gymnasium as gym
import numpy as np
import pandas as pd
import pytest

import agents
import gbo_envs  # noqa: F401  (registers the envs)
from agents.base import Tuner, TuningStopped
from evaluation.cli import main as gbo
from evaluation.sessions import (
    ReplayMismatch,
    SessionBusy,
    SessionStore,
    TuningSession,
    export_csv,
)
from evaluation.sessions import store as store_module
from gbo_envs import CostSpec, FailurePolicy, PIController, StepExperiment
from gbo_envs.envs.external import ExternalPlantEnv
from tests.support import RaiseAt

ENV = "gbo_envs/DCMotor-v0"


class CostAwareRandom(Tuner):
    """Random search whose draws depend on the told costs, with one twin row per ask and per tell."""

    name = "test-cost-aware"

    def __init__(self) -> None:
        self._params = {}

    def _setup(self) -> None:
        self.best = np.inf

    def _ask(self) -> np.ndarray:
        point = self.rng.uniform(self.space.low, self.space.high)
        self.log_twin(point, 0.0, phase="ask")
        return point

    def _tell(self, gains, cost, record) -> None:
        if cost < self.best:
            self.best = cost
            self.rng.random()
        self.log_twin(gains, cost, phase="tell")


class Unpicklable(CostAwareRandom):
    """The cost-aware search holding a local function, as the RL tuner does: no snapshot, resumed by replay."""

    name = "test-unpicklable"

    def _setup(self) -> None:
        super()._setup()
        self.scale = lambda x: x


class GlobalRandom(Tuner):
    """Not deterministic for a fixed seed: it draws from numpy's global generator."""

    name = "test-global-random"

    def __init__(self) -> None:
        self._params = {}

    def _ask(self) -> np.ndarray:
        return self.space.from_unit(np.random.random(self.space.dim))

    def _tell(self, gains, cost, record) -> None:
        pass


@pytest.fixture(autouse=True)
def _test_tuners(tuner_registry):
    """The two test tuners above, registered for each test of this module only."""
    agents.register("test-cost-aware", CostAwareRandom)
    agents.register("test-global-random", GlobalRandom)
    agents.register("test-unpicklable", Unpicklable)


class _Crash(BaseException):
    """Stands for the process dying (not caught by the session)."""


def _plant(db, session_id=1, told=True):
    with SessionStore(db) as store:
        return [r for r in store.experiments(session_id, source="plant") if r.told == told or told is None]


def _gains_costs(result):
    return [(tuple(row[n] for n in result.gain_names), row["cost"]) for row in result.plant_rows]


def test_database_pragmas_and_schema(tmp_path):
    with SessionStore(tmp_path / "runs.sqlite") as store:
        conn = store.conn
        assert conn.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
        assert conn.execute("PRAGMA foreign_keys").fetchone()[0] == 1
        assert conn.execute("PRAGMA busy_timeout").fetchone()[0] == store_module.BUSY_TIMEOUT_MS
        assert conn.execute("PRAGMA synchronous").fetchone()[0] == 2  # FULL
        assert conn.execute("PRAGMA user_version").fetchone()[0] == store_module.SCHEMA_VERSION
        assert store.integrity_check() == "ok"
        with pytest.raises(sqlite3.IntegrityError):  # foreign keys are enforced
            with store.transaction() as c:
                c.execute("INSERT INTO experiments (session_id, seq, experiment, source, status, gains, started_at)"
                          " VALUES (99, 1, 1, 'plant', 'ok', '[]', 0)")


def test_session_matches_tuner_run_and_stores_records(tmp_path):
    db = tmp_path / "runs.sqlite"
    result = TuningSession(db, ENV, "random", budget=6, seed=3).run()
    reference = agents.make("random").run(gym.make(ENV), budget=6, seed=3)
    assert _gains_costs(result) == _gains_costs(reference)
    assert [r["true_cost"] for r in result.plant_rows] == [r["true_cost"] for r in reference.plant_rows]
    assert [r["best_cost"] for r in result.plant_rows] == [r["best_cost"] for r in reference.plant_rows]
    rows = _plant(db)
    assert [r.experiment for r in rows] == [1, 2, 3, 4, 5, 6] and all(r.status == "ok" for r in rows)
    record = rows[0].record()
    replayed = gym.make(ENV)
    replayed.reset(seed=3)
    _, _, _, _, info = replayed.step(np.asarray(rows[0].gains))
    for key in ("t", "r", "u", "y"):
        np.testing.assert_array_equal(record[key], info[key])
    assert record["metrics"] == info["metrics"] and record["cost"] == info["cost"]
    assert record["experiment_index"] == 0 and rows[-1].env_state["experiment_index"] == 6
    assert rows[0].to_experiment() == record["experiment"] == info["experiment"]  # the stored record is the env's
    assert result.experiments == reference.experiments  # load_result returns the records, as Tuner.run does
    assert "experiment" not in rows[0].extra  # the record object itself is never stored as JSON
    with SessionStore(db) as store:
        (info_row,) = store.sessions()
    assert (info_row.status, info_row.done, info_row.failed, info_row.budget) == ("done", 6, 0, 6)
    assert info_row.best_cost == min(r["cost"] for r in reference.plant_rows)


def test_rerun_of_a_finished_session_runs_nothing_and_asks_nothing(tmp_path, monkeypatch):
    db = tmp_path / "runs.sqlite"
    first = TuningSession(db, ENV, "test-cost-aware", budget=5, seed=1).run()
    counting = RaiseAt(gym.make(ENV), calls=range(1, 101), error=AssertionError("the plant must not run"))
    session = TuningSession(db, counting, "test-cost-aware", budget=5, seed=1, env_id=ENV)
    asks = []
    monkeypatch.setattr(CostAwareRandom, "_ask", lambda self: asks.append(1) or self.space.low)
    again = session.run()
    assert session.n_replayed == 5 and counting.count == 0
    assert asks == [] and session.n_asked == 0  # the tuner's snapshot was loaded: no proposal asked for again
    assert _gains_costs(again) == _gains_costs(first)
    assert again.n_twin == first.n_twin == 10


def test_another_budget_extends_or_shortens_the_session(tmp_path):
    db = tmp_path / "runs.sqlite"
    uninterrupted = TuningSession(tmp_path / "ref.sqlite", ENV, "test-cost-aware", budget=7, seed=1).run()
    TuningSession(db, ENV, "test-cost-aware", budget=4, seed=1).run()
    longer = TuningSession(db, ENV, "test-cost-aware", budget=7, seed=1)
    result = longer.run()
    assert longer.session_id == 1 and longer.n_replayed == 4  # the same session, extended by 3 experiments
    assert _gains_costs(result) == _gains_costs(uninterrupted)
    counting = RaiseAt(gym.make(ENV), calls=range(1, 101), error=AssertionError("the plant must not run"))
    shorter = TuningSession(db, counting, "test-cost-aware", budget=2, seed=1, env_id=ENV)
    assert shorter.run().n_experiments == 7 and counting.count == 0  # nothing run, nothing deleted
    with SessionStore(db) as store:
        (info,) = store.sessions()
    assert (info.id, info.budget, info.done, info.status) == (1, 2, 7, "done")
    TuningSession(db, ENV, "test-cost-aware", budget=8, seed=1).run()
    assert [r.experiment for r in _plant(db)] == list(range(1, 9))


@pytest.mark.parametrize("cut", ["ctrl-c", "crash-before-commit", "crash-before-twin-commit"])
def test_resume_after_an_interruption_equals_an_uninterrupted_run(tmp_path, monkeypatch, cut):
    uninterrupted = TuningSession(tmp_path / "ref.sqlite", ENV, "test-cost-aware", budget=8, seed=5).run()
    db = tmp_path / "cut.sqlite"
    if cut == "ctrl-c":
        env = RaiseAt(gym.make(ENV), calls=[4], error=KeyboardInterrupt())
        with pytest.raises(KeyboardInterrupt):
            TuningSession(db, env, "test-cost-aware", budget=8, seed=5, env_id=ENV).run()
        statuses = ["interrupted"]
    else:
        # the process dies on the 4th experiment: before its result is committed, or after it (and after
        # tell) but before the twin rows of its tell are committed
        original = SessionStore.finish_plant if cut == "crash-before-commit" else SessionStore.add_twins
        calls = []

        def dying(self, *args, **kwargs):
            calls.append(1)
            if len(calls) == 4:
                raise _Crash()
            return original(self, *args, **kwargs)

        name = "finish_plant" if cut == "crash-before-commit" else "add_twins"
        monkeypatch.setattr(SessionStore, name, dying)
        with pytest.raises(_Crash):
            TuningSession(db, ENV, "test-cost-aware", budget=8, seed=5).run()
        monkeypatch.setattr(SessionStore, name, original)
        statuses = ["running"] if cut == "crash-before-commit" else []
    assert [r.status for r in _plant(db, told=False)] == statuses
    assert len(_plant(db)) == (4 if cut == "crash-before-twin-commit" else 3)
    if cut == "crash-before-commit":
        with pytest.raises(TuningStopped, match="may have run it"):
            TuningSession(db, ENV, "test-cost-aware", budget=8, seed=5, on_crash="stop").run()
    session = TuningSession(db, ENV, "test-cost-aware", budget=8, seed=5)
    resumed = session.run()
    assert session.n_replayed == (4 if cut == "crash-before-twin-commit" else 3)
    assert _gains_costs(resumed) == _gains_costs(uninterrupted)
    assert [r["true_cost"] for r in resumed.plant_rows] == [r["true_cost"] for r in uninterrupted.plant_rows]
    assert [r.experiment for r in _plant(db)] == list(range(1, 9))
    if cut == "crash-before-commit":
        assert [r.status for r in _plant(db, told=False)] == ["lost-in-crash"]
    # twin rows: one per ask and per tell of each experiment, none lost or doubled by the replay
    assert resumed.n_twin == 16
    with SessionStore(db) as store:
        twins = [r for r in store.experiments(1, source="twin") if r.status == "ok"]
        assert store.integrity_check() == "ok"
    assert sorted((r.experiment, r.phase) for r in twins) == sorted(
        (k, phase) for k in range(1, 9) for phase in ("ask", "tell"))


def test_a_tuner_that_does_not_pickle_is_resumed_by_replay(tmp_path):
    uninterrupted = TuningSession(tmp_path / "ref.sqlite", ENV, "test-unpicklable", budget=6, seed=2).run()
    db = tmp_path / "cut.sqlite"
    env = RaiseAt(gym.make(ENV), calls=[4], error=KeyboardInterrupt())
    with pytest.raises(KeyboardInterrupt):
        TuningSession(db, env, "test-unpicklable", budget=6, seed=2, env_id=ENV).run()
    with SessionStore(db) as store:
        assert store.snapshot(1) is None
    session = TuningSession(db, ENV, "test-unpicklable", budget=6, seed=2)
    assert _gains_costs(session.run()) == _gains_costs(uninterrupted)
    assert (session.n_replayed, session.n_asked) == (3, 3)


def test_a_snapshot_that_does_not_load_is_replaced_by_a_replay(tmp_path, caplog):
    uninterrupted = TuningSession(tmp_path / "ref.sqlite", ENV, "test-cost-aware", budget=5, seed=4).run()
    db = tmp_path / "runs.sqlite"
    TuningSession(db, ENV, "test-cost-aware", budget=3, seed=4).run()
    conn = sqlite3.connect(db)
    conn.execute("UPDATE snapshots SET tuner = ?", (b"written by other code",))
    conn.commit()
    conn.close()
    session = TuningSession(db, ENV, "test-cost-aware", budget=5, seed=4)
    assert _gains_costs(session.run()) == _gains_costs(uninterrupted)
    assert session.n_asked == 3 and "replaying the session instead" in caplog.text


def test_a_snapshot_of_an_older_tuner_version_is_replaced_by_a_replay(tmp_path, caplog):
    """A snapshot pickled before the class gained an attribute loads, but the state lacks it (guided BO's
    ``keeper_`` raised AttributeError on resume): it must be replayed instead."""
    from evaluation.sessions.snapshot import restore_tuner, tuner_snapshot

    env = gym.make(ENV)
    older = agents.make("guided-bo", grid_points=30)
    older.setup(agents.GainSpace.from_env(env), seed=0, env=env)
    del older.__dict__["keeper_"]  # as an older GuidedBO would have pickled itself
    tuner = agents.make("guided-bo", grid_points=30)
    tuner.setup(agents.GainSpace.from_env(env), seed=0, env=env)
    state = tuner_snapshot(older, env)
    assert state is not None
    with caplog.at_level(logging.WARNING):
        assert not restore_tuner(tuner, state, env)
    assert "lacks keeper_" in caplog.text and "keeper_" in tuner.__dict__


def _drop_snapshots(db) -> None:
    conn = sqlite3.connect(db)
    conn.execute("DELETE FROM snapshots")
    conn.commit()
    conn.close()


def test_a_replay_without_snapshot_fails_loudly_on_a_nondeterministic_or_tampered_session(tmp_path):
    db = tmp_path / "runs.sqlite"
    TuningSession(db, ENV, "random", budget=3, seed=0).run()
    conn = sqlite3.connect(db)
    conn.execute("UPDATE experiments SET gains = '[0.5, 1.0]' WHERE seq = 2")
    conn.commit()
    conn.close()
    _drop_snapshots(db)
    with pytest.raises(ReplayMismatch, match="not deterministic"):
        TuningSession(db, ENV, "random", budget=3, seed=0).run()
    for name, snapshot in (("with.sqlite", True), ("without.sqlite", False)):
        db = tmp_path / name
        env = RaiseAt(gym.make(ENV), calls=[3], error=KeyboardInterrupt())
        with pytest.raises(KeyboardInterrupt):
            TuningSession(db, env, "test-global-random", budget=4, seed=0, env_id=ENV).run()
        stored = [r.gains for r in _plant(db)]
        if snapshot:  # the snapshot holds the tuner's state: it resumes without asking for anything again
            session = TuningSession(db, ENV, "test-global-random", budget=4, seed=0)
            session.run()
            assert session.n_asked == 0 and [r.gains for r in _plant(db)][:2] == stored
        else:
            _drop_snapshots(db)
            with pytest.raises(ReplayMismatch):
                TuningSession(db, ENV, "test-global-random", budget=4, seed=0).run()


def test_env_error_is_recorded_and_the_session_can_go_on(tmp_path):
    db = tmp_path / "runs.sqlite"
    env = RaiseAt(gym.make(ENV), calls=[3], error=RuntimeError("amplifier tripped"))
    with pytest.raises(RuntimeError, match="amplifier"):
        TuningSession(db, env, "random", budget=5, seed=0, env_id=ENV).run()
    failed = _plant(db, told=False)
    assert [(r.status, r.reason) for r in failed] == [("failed", "RuntimeError: amplifier tripped")]
    with SessionStore(db) as store:
        info = store.session(1)
    assert info.status == "failed" and "amplifier" in info.message and info.done == 2
    result = TuningSession(db, ENV, "random", budget=5, seed=0).run()
    assert result.n_experiments == 5 and [r.experiment for r in _plant(db)] == [1, 2, 3, 4, 5]


def _rig(fail_calls):
    """An external rig (the DC motor loop) whose listed calls (1-based) raise."""
    loop = gym.make(ENV, noise=False).unwrapped.loop
    calls = []

    def run_experiment(gains):
        calls.append(1)
        if len(calls) in fail_calls:
            raise ConnectionError(f"link lost on call {len(calls)}")
        response = loop.simulate(np.asarray(gains)[None, :])
        return response.t, response.r, response.u[0], response.y[0]

    return run_experiment


def _external(fail_calls, on_failure):
    normalizers = gym.make(ENV).unwrapped.normalizers
    return ExternalPlantEnv(_rig(fail_calls), {"Kp": (0.11, 1.10), "Ki": (0.87, 2.08)}, controller=PIController(),
                            experiment=StepExperiment((245.0, 306.0), dt=0.002, duration=5.0),
                            cost=CostSpec(normalizers=normalizers),
                            failure_policy=FailurePolicy(on_failure=on_failure, failure_cost=5.0))


def test_failure_policies(tmp_path):
    db = tmp_path / "runs.sqlite"
    # penalize: the tuner learns the penalty, the failure counts against the budget
    result = TuningSession(db, _external({2, 3}, "penalize"), "random", budget=5, seed=0, env_id="rig").run()
    rows = _plant(db, session_id=1)
    assert [r.status for r in rows] == ["ok", "failed", "failed", "ok", "ok"]
    assert [r.told_cost for r in rows if r.status == "failed"] == [5.0, 5.0]
    assert all("ConnectionError: link lost" in r.reason for r in rows if r.status == "failed")
    assert [row["cost"] for row in result.plant_rows][1:3] == [5.0, 5.0]
    # skip: recorded, not told, proposed again: 5 experiments learned from, 2 failed rows besides
    session = TuningSession(db, _external({2, 3}, "skip"), "random", budget=5, seed=0, env_id="rig-skip")
    session.run()
    told, untold = _plant(db, session.session_id), _plant(db, session.session_id, told=False)
    assert [r.status for r in told] == ["ok"] * 5 and [r.status for r in untold] == ["failed", "failed"]
    assert [r.experiment for r in told] == [1, 2, 3, 4, 5] and [r.experiment for r in untold] == [2, 2]
    again = TuningSession(db, _external(set(), "skip"), "random", budget=5, seed=0, env_id="rig-skip")
    again.run()
    assert again.n_replayed == 5 and again.session_id == session.session_id
    # stop: recorded, then a clear error; rerunning after the fix resumes
    stopping = TuningSession(db, _external({3}, "stop"), "random", budget=4, seed=0, env_id="rig-stop")
    with pytest.raises(TuningStopped, match="experiment 3 failed .*ConnectionError"):
        stopping.run()
    with SessionStore(db) as store:
        info = store.session(stopping.session_id)
    assert (info.status, info.done, info.failed) == ("stopped", 2, 1)
    TuningSession(db, _external(set(), "stop"), "random", budget=4, seed=0, env_id="rig-stop").run()
    assert [r.experiment for r in _plant(db, stopping.session_id)] == [1, 2, 3, 4]
    # a plant that always fails stops the session instead of looping
    with pytest.raises(TuningStopped, match="3 failed experiments in a row"):
        TuningSession(db, _external(set(range(1, 99)), "skip"), "random", budget=4, seed=0, env_id="dead",
                      max_consecutive_skips=3).run()
    with SessionStore(db) as store:
        assert store.integrity_check() == "ok"


def test_a_live_owner_blocks_a_second_runner(tmp_path):
    db = tmp_path / "runs.sqlite"
    session = TuningSession(db, ENV, "random", budget=2, seed=0)
    session.run()
    conn = sqlite3.connect(db)
    conn.execute("UPDATE sessions SET owner_host = ?, owner_pid = ?", (socket.gethostname(), os.getppid()))
    conn.commit()
    conn.close()
    with pytest.raises(SessionBusy, match="being run by process"):
        TuningSession(db, ENV, "random", budget=2, seed=0).run()
    taken = TuningSession(db, ENV, "random", budget=2, seed=0, force=True)
    assert taken.run().n_experiments == 2 and taken.n_replayed == 2


def test_cli_tune_sessions_export(tmp_path, capsys):
    db, csv = str(tmp_path / "runs.sqlite"), str(tmp_path / "out" / "data.csv")
    assert gbo(["tune", "--env", ENV, "--tuner", "random", "--budget", "3", "--db", db, "--seed", "2",
                "--env-kwargs", '{"noise": false}', "--no-progress"]) == 0
    assert "3/3 plant experiments" in capsys.readouterr().out
    assert gbo(["tune", "--env", ENV, "--tuner", "test-cost-aware", "--budget", "2", "--db", db,
                "--no-progress"]) == 0
    assert gbo(["tune", "--env", ENV, "--tuner", "random", "--budget", "3", "--db", db, "--seed", "2",
                "--env-kwargs", '{"noise": false}', "--no-progress"]) == 0
    assert "(resumed after 3)" in capsys.readouterr().out
    assert gbo(["sessions", "--db", db]) == 0
    table = capsys.readouterr().out.splitlines()
    assert table[0].split() == ["id", "env", "tuner", "seed", "budget", "done", "failed", "best", "cost", "status",
                                "created", "updated"]
    assert table[2].split()[:7] == ["1", ENV, "random", "2", "3", "3", "0"]
    assert table[3].split()[:7] == ["2", ENV, "test-cost-aware", "0", "2", "2", "0"]
    assert gbo(["export", "--db", db, "--session", "1", "--csv", csv]) == 0
    frame = pd.read_csv(csv)
    assert list(frame.columns) == ["experiment", "t", "r", "u", "y", "Kp", "Ki", "source", "cost"]
    assert len(frame) == 3 * 2501 and sorted(frame["experiment"].unique()) == [1, 2, 3]
    rows = _plant(db)
    first = frame[frame["experiment"] == 1]
    np.testing.assert_array_equal(first["y"].to_numpy(), rows[0].arrays()["y"])
    assert first["Kp"].iloc[0] == rows[0].gains[0] and (frame["source"] == "plant").all()
    from agents.twin.csvio import read_csv
    from agents.twin.records import as_records

    assert len(as_records(frame)) == 3  # the twin workbench reads it
    back = read_csv(csv, gain_names=("Kp", "Ki"))
    assert back == [row.to_experiment().replace(metrics={}, index=row.experiment - 1) for row in rows]  # 0-based
    capsys.readouterr()
    assert gbo(["export", "--db", db, "--csv", csv]) == 0  # default: the latest updated session (1, resumed last)
    assert "of session 1 " in capsys.readouterr().out and pd.read_csv(csv)["experiment"].nunique() == 3
    assert gbo(["export", "--db", db, "--session", "9", "--csv", csv]) == 2  # no such session: bad input


@pytest.mark.slow
def test_concurrent_sessions_in_one_database(tmp_path):
    db = tmp_path / "shared.sqlite"
    procs = [subprocess.Popen([sys.executable, "-m", "evaluation.cli", "tune", "--env", ENV, "--tuner", "random",
                               "--budget", "15", "--seed", str(seed), "--db", str(db), "--no-progress"],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for seed in range(3)]
    outputs = [proc.communicate(timeout=300) for proc in procs]
    assert [proc.returncode for proc in procs] == [0, 0, 0], outputs
    with SessionStore(db) as store:
        assert store.integrity_check() == "ok"
        sessions = store.sessions()
        assert sorted(s.seed for s in sessions) == [0, 1, 2]
        for info in sessions:
            rows = store.experiments(info.id, source="plant")
            assert (info.done, info.status) == (15, "done")
            assert [r.experiment for r in rows] == list(range(1, 16))
            reference = agents.make("random").run(gym.make(ENV), budget=15, seed=info.seed)
            assert [r.gains for r in rows] == [tuple(row[n] for n in ("Kp", "Ki")) for row in reference.plant_rows]
    with SessionStore(db) as store:
        _, count = export_csv(store, tmp_path / "one.csv", session_id=2)
    assert count == 15


def test_cli_tune_prints_when_the_twin_changes(tmp_path, capsys):
    db = str(tmp_path / "runs.sqlite")
    assert gbo(["tune", "--env", ENV, "--tuner", "guided-bo", "--budget", "2", "--db", db,
                "--tuner-kwargs", '{"grid_points": 30}', "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert "guided-bo: twin: linear, RMSE" in out and "(after 1 experiment)" in out
    # the twin is simulated on the acquisition grid (the prior), which the stored rows do not show:
    # the count is the tuner's own (it printed "0 twin evaluations")
    assert "2/2 plant experiments, 0 failed, 0 twin evaluations" not in out
    assert re.search(r"2/2 plant experiments, 0 failed, [1-9]\d* twin evaluations", out)
    events = logging.getLogger("agents.base")  # the process's logger is left as it was
    assert not [h for h in events.handlers if type(h).__name__ == "_PrintEvents"]
    agents.make("guided-bo", grid_points=30).run(gym.make(ENV), budget=2, seed=0)
    assert "twin" not in capsys.readouterr().out  # a later run in the same process prints nothing


def test_force_takes_a_session_over_and_fences_its_previous_owner(tmp_path, monkeypatch):
    # the previous owner is still running when another process takes the session over (gbo tune --force):
    # its next write must stop it, instead of interleaving experiments (an IntegrityError once both told the same)
    db = tmp_path / "runs.sqlite"
    uninterrupted = TuningSession(tmp_path / "ref.sqlite", ENV, "test-cost-aware", budget=6, seed=1).run()
    original, taken = SessionStore.add_twins, []

    def add_twins_then_taken_over(self, session_id, experiment, *args, **kwargs):
        original(self, session_id, experiment, *args, **kwargs)
        if experiment == 3 and not taken:
            taken.append(TuningSession(db, ENV, "test-cost-aware", budget=6, seed=1, force=True).run())

    monkeypatch.setattr(SessionStore, "add_twins", add_twins_then_taken_over)
    with pytest.raises(SessionBusy, match="session 1 was taken over by another process"):
        TuningSession(db, ENV, "test-cost-aware", budget=6, seed=1).run()
    assert _gains_costs(taken[0]) == _gains_costs(uninterrupted)
    assert [r.experiment for r in _plant(db, told=None)] == list(range(1, 7))  # each once, none begun after
    with SessionStore(db) as store:
        (info,) = store.sessions()
        assert (info.status, info.done) == ("done", 6) and store.integrity_check() == "ok"


# -- issue 57: a damaged database is refused unchanged; reading leaves no -wal or -shm behind ---------------------
def _damage(path) -> None:
    """Overwrite the start of pages 2-4 (the tables' b-trees) of an SQLite file."""
    data = bytearray(path.read_bytes())
    size = int.from_bytes(data[16:18], "big") or 65536
    for page in (2, 3, 4):
        data[size * (page - 1) : size * (page - 1) + 100] = b"\xff" * 100
    path.write_bytes(bytes(data))


def test_a_damaged_database_is_refused_before_anything_is_written(tmp_path, capsys):
    import hashlib

    db = tmp_path / "runs.sqlite"
    TuningSession(db, ENV, "random", budget=3, seed=0, env_kwargs={"noise": False}).run()
    _damage(db)
    before = hashlib.sha256(db.read_bytes()).hexdigest()
    argv = ["tune", "--tuner", "random", "--budget", "5", "--db", str(db), "--env-kwargs", '{"noise": false}',
            "--no-progress"]
    capsys.readouterr()
    assert gbo(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"gbo tune: error: {db}: the database is damaged") and "not changed" in err, err
    assert gbo(["sessions", "--db", str(db)]) == 2
    assert f"gbo sessions: error: {db}: the database is damaged" in capsys.readouterr().err
    assert hashlib.sha256(db.read_bytes()).hexdigest() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["runs.sqlite"]  # no -wal or -shm left either


def test_gbo_sessions_and_export_leave_the_folder_as_they_found_it(tmp_path, capsys):
    import hashlib

    db = tmp_path / "runs.sqlite"
    TuningSession(db, ENV, "random", budget=2, seed=0, env_kwargs={"noise": False}).run()
    before = hashlib.sha256(db.read_bytes()).hexdigest()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["runs.sqlite"]
    assert gbo(["sessions", "--db", str(db)]) == 0
    assert gbo(["export", "--db", str(db), "--csv", str(tmp_path / "out" / "s.csv")]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out", "runs.sqlite"]
    assert hashlib.sha256(db.read_bytes()).hexdigest() == before
