"""The study runner: `gbo bench smoke` end to end, resume, failures, Ctrl-C, spec changes."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

import agents
from agents.base import Tuner
from evaluation import analysis
from evaluation.cli import main
from evaluation.study import load_study, parse_study
from evaluation.study_runner import RESULTS_DIR, finished_files, forget, plan_batches, run_study
from tests.support import TIMING_COLUMNS as TIMING


class _Fragile(Tuner):
    """Random gains; fails (``mode="raise"``) or is interrupted (``"interrupt"``) on seed 1."""

    name = "test-fragile"

    def __init__(self, *, mode: str = "raise", n_initial: int = 1) -> None:
        self.mode = mode
        self._params = {"mode": mode, "n_initial": n_initial}

    def _setup(self) -> None:
        if self.seed == 1:
            raise KeyboardInterrupt if self.mode == "interrupt" else RuntimeError("boom on seed 1")

    def _ask(self) -> np.ndarray:
        return self.rng.uniform(self.space.low, self.space.high)

    def _tell(self, gains, cost, record) -> None:
        pass


@pytest.fixture
def fragile(monkeypatch):
    """Register the fragile tuner for one test only (other tests iterate over the registry)."""
    from agents import registry

    monkeypatch.setitem(registry._REGISTRY, "test-fragile", _Fragile)
    assert "test-fragile" in agents.registered_names()


def tiny(tuners, batches=3, budget=3) -> object:
    return parse_study({"study": {"name": "tiny", "batches": batches, "budget": budget, "n_initial": 1,
                                  "resolution": 10},
                        "env": {"id": "gbo_envs/DCMotor-v0"}, "tuners": tuners, "thresholds": [1.5]})


def read(out, name) -> pd.DataFrame:
    return pd.read_parquet(out / RESULTS_DIR / name)


@pytest.mark.slow
def test_smoke_study_end_to_end_and_resume(tmp_path):
    out = tmp_path / "smoke"
    assert main(["bench", "smoke", "--out", str(out), "--workers", "2", "--quiet"]) == 0
    study = load_study("smoke")
    files = sorted(finished_files(out))
    assert len(files) == 8 and files == sorted(task.filename for task in plan_batches(study))
    frame = analysis.load_results(out, study)
    assert len(frame) == 2 * 4 * 8 and set(frame["source"]) == {"plant"}
    for column in ["study", "tuner", "tuner_name", "batch", "seed", "experiment", "source", "Kp", "Ki", "cost",
                   "best_cost", "true_cost", "unstable", "overshoot_pct", "wall_time", "params", "info"]:
        assert column in frame, column
    assert frame.groupby(["tuner", "batch"]).size().eq(8).all()
    assert (frame["seed"] == frame["batch"]).all()  # seed = base 0 + batch
    assert list(dict.fromkeys(frame["tuner"])) == ["random search", "BO"]
    assert not list((out / RESULTS_DIR).glob("*.tmp"))
    for name in ["report.md", "ratio_curves.png", "histogram.png", "cost_surface.png", "study.toml",
                 "ground_truth.npz"]:
        assert (out / name).is_file(), name
    report = (out / "report.md").read_text()
    assert "![ratio curves](ratio_curves.png)" in report and "| random search | phi=1.05 |" in report

    again = run_study(study, out, workers=2, progress=False)
    assert (again.skipped, again.completed, again.total) == (8, 0, 8)

    lost = files[3]
    before = read(out, lost)
    (out / RESULTS_DIR / lost).unlink()
    resumed = run_study(study, out, workers=1, progress=False)
    assert (resumed.skipped, resumed.completed) == (7, 1)
    pd.testing.assert_frame_equal(read(out, lost).drop(columns=TIMING), before.drop(columns=TIMING))


def test_only_the_first_batches_and_changed_specs_rerun(tmp_path):
    study = tiny([{"name": "random"}], batches=4)
    run = run_study(study.with_batches(2), tmp_path, workers=1, progress=False)
    assert (run.total, run.completed) == (2, 2)
    run = run_study(study, tmp_path, workers=1, progress=False)
    assert (run.skipped, run.completed) == (2, 2)
    changed = tiny([{"name": "random"}], batches=4, budget=4)  # another budget: other files
    assert run_study(changed, tmp_path, workers=1, progress=False).completed == 4
    assert len(analysis.load_results(tmp_path, changed)) == 16
    assert len(analysis.load_results(tmp_path)) == 12 + 16


def test_a_failing_batch_is_reported_and_not_written(tmp_path, fragile):
    study = tiny([{"name": "test-fragile", "label": "fragile"}])
    run = run_study(study, tmp_path, workers=1, progress=False, log=lambda message: None)
    assert run.completed == 2 and len(run.failed) == 1
    assert "boom on seed 1" in run.failed[0][1] and "__b0001__" in run.failed[0][0]
    assert not run.done and len(finished_files(tmp_path)) == 2


def test_ctrl_c_keeps_finished_batches(tmp_path, fragile):
    study = tiny([{"name": "test-fragile", "label": "fragile", "params": {"mode": "interrupt"}}])
    messages = []
    run = run_study(study, tmp_path, workers=1, progress=False, log=messages.append)
    assert run.interrupted and run.completed == 1
    assert [name.split("__")[1] for name in finished_files(tmp_path)] == ["b0000"]
    assert "rerun the same command to resume" in messages[-1]


def test_n_initial_goes_only_to_tuners_that_take_it():
    study = tiny([{"name": "random"}, {"name": "bo", "params": {"grid_points": 20}},
                  {"name": "bo", "label": "bo N0=3", "params": {"n_initial": 3}}])
    params = {task.label: task.params for task in plan_batches(study)}
    assert params == {"random": {}, "bo": {"grid_points": 20, "n_initial": 1}, "bo N0=3": {"n_initial": 3}}
    with pytest.raises(ValueError, match="tuner 'nope' .*unknown tuner"):
        plan_batches(tiny([{"name": "nope"}]))


def test_cli_errors(tmp_path, capsys):
    assert main(["bench", "no-such-study"]) == 2
    assert "shipped studies" in capsys.readouterr().err
    spec = tmp_path / "bad.toml"
    spec.write_text('[study]\nbatches = 1\nbudget = 2\n[env]\nid = "gbo_envs/DCMotor-v0"\n[[tuners]]\nname = "nope"\n')
    assert main(["bench", str(spec), "--out", str(tmp_path / "o"), "--quiet"]) == 2
    assert "unknown tuner 'nope'" in capsys.readouterr().err
    assert main(["bench", "smoke", "--address", "tcp://x:1"]) == 2
    assert main(["bench", "--list"]) == 0
    assert "performance" in capsys.readouterr().out


class _FakeGuided(Tuner):
    """Random gains plus ``round(10 / eta1)`` fake twin evaluations before every 2nd experiment."""

    name = "test-fake-guided"

    def __init__(self, *, eta1: float = 1.0, n_initial: int = 1) -> None:
        self.eta1 = eta1
        self._params = {"eta1": eta1, "n_initial": n_initial}

    def _setup(self) -> None:
        self.activations = 0

    def _ask(self) -> np.ndarray:
        gains = self.rng.uniform(self.space.low, self.space.high)
        if len(self._twin_log) == 0 and self.rng.random() < 0.5:
            self.activations += 1
            for _ in range(round(10 / self.eta1)):
                self.log_twin(self.rng.uniform(self.space.low, self.space.high), 0.5, activation=self.activations)
        return gains

    def _tell(self, gains, cost, record) -> None:
        pass

    def run_summary(self) -> dict:
        return {"activations": self.activations}


def test_report_with_twin_rows_sweep_and_paper_numbers(tmp_path, monkeypatch):
    from agents import registry

    monkeypatch.setitem(registry._REGISTRY, "test-fake-guided", _FakeGuided)
    study = parse_study({
        "study": {"name": "sweepy", "batches": 3, "budget": 6, "n_initial": 1, "resolution": 12},
        "env": {"id": "gbo_envs/DCMotor-v0"},
        "tuners": [{"name": "random", "label": "ref"},
                   {"name": "test-fake-guided", "label": "fake eta1={eta1}", "sweep": {"eta1": [1.0, 2.0, 5.0]}}],
        "thresholds": [{"label": "nominal", "gains": [0.85, 1.07], "paper_ratio": 1.71}, 1.5],
        "paper": {"thresholds": [{"tuner": "ref", "threshold": "nominal", "mean": 2}],
                  "metrics": [{"tuner": "fake eta1=1", "metric": "activations", "value": 12}],
                  "gains": [{"label": "Ground truth", "Kp": 0.54, "Ki": 1.16, "cost": 0.79}],
                  "text": "What the paper says."},
        "notes": {"text": "Where we differ."},
    })
    run = run_study(study, tmp_path, workers=1, progress=False)
    assert run.completed == 12
    frame = analysis.load_results(tmp_path, study)
    twin = frame[frame["source"] == "twin"]
    assert len(twin) and set(twin["tuner"]) <= {"fake eta1=1", "fake eta1=2", "fake eta1=5"}
    counts = analysis.twin_activations(frame, study.labels)
    fake = frame[frame["tuner"] == "fake eta1=1"]
    assert counts.set_index(["tuner", "batch"]).loc[("fake eta1=1", 0), "twin_evaluations"] == \
        ((fake["batch"] == 0) & (fake["source"] == "twin")).sum()

    path = __import__("evaluation.report", fromlist=["write_report"]).write_report(study, tmp_path)
    text = path.read_text()
    for name in ["ratio_curves.png", "histogram.png", "cost_surface.png", "activations.png", "sweep.png"]:
        assert (tmp_path / name).is_file(), name
        assert f"]({name})" in text
    assert "## Sweep over eta1" in text and "What the paper says." in text and "Where we differ." in text
    assert "| fake eta1=1 | activations | 12 |" in text
    assert "paper mean" in text and "| Ground truth | paper | 0.54 | 1.16 | 0.79 | 1 |" in text


def test_a_study_of_several_plants_runs_each_tuner_on_its_plants_and_rerun_forgets_one_tuner(tmp_path, capsys):
    study = parse_study({"study": {"name": "plants", "batches": 2, "budget": 2, "resolution": 5},
                         "plants": [{"label": "DC", "id": "gbo_envs/DCMotor-v0", "thresholds": [1.5]},
                                    {"label": "Lin", "id": "gbo_envs/LinearMotor-v0", "thresholds": [1.5],
                                     "batches": 1, "budget": 3}],
                         "tuners": [{"name": "random"}, {"name": "grid", "plants": ["DC"], "batches": 1}]})
    tasks = plan_batches(study)
    assert [(t.plant, t.label, t.batch, t.budget) for t in tasks] == [
        ("DC", "random", 0, 2), ("DC", "grid", 0, 2), ("Lin", "random", 0, 3), ("DC", "random", 1, 2)]
    assert tasks[0].filename.startswith("DC__random__b0000__")
    run = run_study(study, tmp_path, workers=1, progress=False)
    assert (run.completed, run.total) == (4, 4)
    frame = analysis.load_results(tmp_path)
    assert set(zip(frame["plant"], frame["tuner"])) == {("DC", "random"), ("DC", "grid"), ("Lin", "random")}
    assert main(["bench", str(_spec(tmp_path, study)), "--out", str(tmp_path), "--rerun", "grid", "--quiet",
                 "--workers", "1", "--no-report"]) == 0
    out = capsys.readouterr().out
    assert "deleted 1 saved runs of grid" in out and "4 of 4 batches finished (1 now" in out
    with pytest.raises(ValueError, match=r"--rerun: \['gird'\] are not tuners of 'plants'; its tuners: random, grid"):
        forget(study, tmp_path, ["gird"])


def _spec(tmp_path, study):
    path = tmp_path / "plants.toml"
    path.write_text('[study]\nname = "plants"\nbatches = 2\nbudget = 2\nresolution = 5\n'
                    '[[plants]]\nlabel = "DC"\nid = "gbo_envs/DCMotor-v0"\nthresholds = [1.5]\n'
                    '[[plants]]\nlabel = "Lin"\nid = "gbo_envs/LinearMotor-v0"\nthresholds = [1.5]\nbatches = 1\n'
                    'budget = 3\n[[tuners]]\nname = "random"\n[[tuners]]\nname = "grid"\nplants = ["DC"]\n'
                    'batches = 1\n')
    return path
