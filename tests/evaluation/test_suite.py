"""``gbo bench suite``: the leaderboard's numbers, resume after an interrupt, stale references, a user's tuner."""

from __future__ import annotations

import hashlib
import importlib
import json
import textwrap

import numpy as np
import pandas as pd
import pytest

import agents
import evaluation.study_runner as study_runner
from evaluation import behaviour, fingerprint
from evaluation.cli import main
from evaluation.curves import CURVES_FILE, load_curves, read_curves
from evaluation.leaderboard import Leaderboard, PlantTarget, write_leaderboard
from evaluation.references import REFERENCES_DIR, load_references, rebuild, reference_file, suite_optima
from evaluation.study import TunerEntry, parse_study
from evaluation.suite import load_suite, run_suite


def tiny_suite(tuners=None, kwargs=None):
    """Two short plants (one changes at experiment 3) on an 8 x 8 truth grid, 3 seeds, reference tuners."""
    return parse_study({
        "study": {"name": "tiny-suite", "batches": 3, "resolution": 8},
        "plants": [{"label": "DC", "id": "gbo_envs/DCMotor-v0", "kwargs": kwargs or {}, "thresholds": [1.3],
                    "budget": 4},
                   {"label": "DCStep", "id": "gbo_envs/DCMotorStep-v0", "kwargs": {"change_at": 2},
                    "thresholds": [1.3], "budget": 5, "phase": "after-change"}],
        "tuners": tuners or [{"name": "random", "label": "bo"}, {"name": "grid"}]})


def curves(rows):
    return pd.DataFrame([{"tuner": t, "plant": p, "seed": s, "curve": np.asarray(c, float),
                          "instant": np.asarray(i if i is not None else c, float)} for t, p, s, c, i in rows])


# -- the leaderboard's numbers ------------------------------------------------------------------------
def test_leaderboard_counts_targets_misses_ratios_and_the_ecdf():
    plants = [PlantTarget("A", 1.05, budget=4), PlantTarget("B", 1.01, budget=5, start=2)]
    rows = [("bo", "A", 0, [1.2, 1.04, 1.0, 1.0], None),   # reaches 1.05 at 2
            ("bo", "A", 1, [1.2, 1.2, 1.2, 1.06], None),    # never: 4 + 1 = 5
            ("me", "A", 0, [1.04, 1.0, 1.0, 1.0], None),    # 1
            ("me", "A", 1, [1.1, 1.1, 1.03, 1.0], None),    # 3
            # after the change at index 2 only experiments 3.. count, judged by their own ratio
            ("bo", "B", 0, [1.0] * 5, [1.0, 1.0, 1.3, 1.005, 1.0]),   # 2 (the old 1.0 does not count)
            ("bo", "B", 1, [1.0] * 5, [1.0, 1.0, 1.3, 1.2, 1.1]),     # never: 5 - 2 + 1 = 4
            ("me", "B", 0, [1.0] * 5, [1.0, 1.0, 1.0, 1.0, 1.0]),     # 1
            ("me", "B", 1, [1.0] * 5, [1.0, 1.0, 1.2, 1.2, 1.0])]     # 3
    board = Leaderboard(reference="bo", n_bootstrap=200).fit(curves(rows), plants, order=["me", "bo"])
    counts = board.counts_.set_index(["tuner", "plant", "seed"])["count"].to_dict()
    assert counts == {("bo", "A", 0): 2, ("bo", "A", 1): 5, ("me", "A", 0): 1, ("me", "A", 1): 3,
                      ("bo", "B", 0): 2, ("bo", "B", 1): 4, ("me", "B", 0): 1, ("me", "B", 1): 3}
    table = board.to_pandas().set_index(["tuner", "plant"])
    assert table.loc[("bo", "A"), "mean"] == 3.5 and table.loc[("bo", "A"), "misses"] == 1
    assert table.loc[("me", "A"), "vs_reference"] == pytest.approx(2.0 / 3.5)
    assert table.loc[("me", "B"), "vs_reference"] == pytest.approx(2.0 / 3.0)
    low, high = table.loc[("me", "A"), ["ci_low", "ci_high"]]
    assert (low, high) == (1.0, 3.0)  # the bootstrap percentile interval of the counts 1 and 3
    aggregate = board.aggregate_.set_index("tuner")
    assert list(board.aggregate_["tuner"]) == ["me", "bo"] and list(board.aggregate_["rank"]) == [1, 2]
    assert aggregate.loc["me", "geo_mean_vs_reference"] == pytest.approx(np.sqrt(2 / 3.5 * 2 / 3))
    assert aggregate.loc["bo", "geo_mean_vs_reference"] == 1.0 and aggregate.loc["bo", "ci_low"] == 1.0
    assert aggregate.loc["me", "ci_low"] <= aggregate.loc["me", "geo_mean_vs_reference"] <= aggregate.loc["me",
                                                                                                        "ci_high"]
    assert aggregate.loc["me", "solved"] == 1.0 and aggregate.loc["bo", "solved"] == 0.5
    ecdf = board.ecdf().set_index(["tuner", "experiments"])["fraction"]
    assert [ecdf[("me", x)] for x in (1, 2, 3, 4)] == [0.5, 0.5, 1.0, 1.0]
    assert [ecdf[("bo", x)] for x in (1, 2, 3, 4)] == [0.0, 0.5, 0.5, 0.5]  # two misses: it ends at 0.5


def test_leaderboard_files_hold_the_ranking_the_plants_and_units(tmp_path):
    plants = [PlantTarget("A", 1.05, budget=4)]
    rows = [("bo", "A", s, [1.2, 1.04, 1.0, 1.0], None) for s in range(3)] + \
           [("me", "A", s, [1.04, 1.0, 1.0, 1.0], None) for s in range(3)]
    board = Leaderboard(n_bootstrap=50).fit(curves(rows), plants, status={("bo", "A"): "stale"}, order=["me", "bo"])
    paths = write_leaderboard(board, tmp_path, title="T", notes=["stale reference: bo on A: x"], highlight="me")
    md = paths["md"].read_text()
    assert "| 1 | **me** ◀ yours | 0.50 | [0.50, 0.50] | 100 % of 3 | 1 | current |" in md
    assert "| 2 | bo | 1.00 | [1.00, 1.00] | 100 % of 3 | 1 | stale |" in md
    assert "| **me** ◀ yours | 1.0 [1.0, 1.0] | 0 | 0.50 | 3 | current |" in md and "stale reference: bo on A" in md
    csv = pd.read_csv(paths["csv"])
    assert set(csv["kind"]) == {"suite", "plant"} and len(csv) == 4
    assert csv.loc[(csv["kind"] == "plant") & (csv["tuner"] == "me"), "vs_reference"].item() == 0.5
    html = paths["html"].read_text()
    assert html.count("data:image/png;base64,") == 1 and "<table>" in html
    ax = board.plot(highlight="me").axes[0]
    assert ax.get_xscale() == "log"
    assert ax.get_xlabel() == "real experiments to the target (count)"
    assert ax.get_ylabel() == "fraction of (plant, seed) pairs at the target (-)"
    assert board.plot(plant="A").axes[0].get_ylabel() == "fraction of seeds at the target (-)"


# -- resume -------------------------------------------------------------------------------------------
def test_an_interrupted_suite_resumes_without_losing_or_repeating_a_run(tmp_path, monkeypatch):
    suite = tiny_suite()
    real, calls = study_runner.run_batch, []

    def interrupted(task):
        if len(calls) == 3:
            raise KeyboardInterrupt
        calls.append(task.filename)
        return real(task)

    monkeypatch.setattr(study_runner, "run_batch", interrupted)
    first = run_suite("random", suite=suite, out=tmp_path / "a", workers=1, references=tmp_path / "refs")
    assert first.run.interrupted and first.leaderboard is None and first.run.completed == 3
    saved = {p.name for p in (tmp_path / "a" / "random" / "results").glob("*.parquet")}
    assert saved == set(calls)  # every finished run was written at once
    monkeypatch.setattr(study_runner, "run_batch", lambda task: calls.append(task.filename) or real(task))
    second = run_suite("random", suite=suite, out=tmp_path / "a", workers=1, references=tmp_path / "refs")
    assert (second.run.skipped, second.run.completed, second.run.total) == (3, 3, 6)
    assert len(calls) == len(set(calls)) == 6  # nothing run twice
    fresh = run_suite("random", suite=suite, out=tmp_path / "b", workers=1, references=tmp_path / "refs")
    a, b = (load_curves(tmp_path / name / "random", fresh_study(suite)) for name in ("a", "b"))
    for column in ("curve", "instant"):
        assert all(np.array_equal(x, y) for x, y in zip(a[column], b[column]))
    assert second.leaderboard.counts_.equals(fresh.leaderboard.counts_)


def test_a_tuner_entry_brings_its_label_and_kwargs(tmp_path):
    entry = TunerEntry(name="grid", label="grid of 9", params={"budget": 9})
    result = run_suite(entry, suite=tiny_suite(), out=tmp_path, workers=1, references=tmp_path / "refs")
    assert result.label == "grid of 9" and "grid of 9" in set(result.leaderboard.counts_["tuner"])
    runs = load_curves(tmp_path / "grid-of-9", fresh_study(tiny_suite(), entry))
    assert len(runs) == 6 and set(runs["params"]) == {'{"budget": 9}'}  # the kwargs reached every run


def test_plants_run_and_rank_one_suite_plant_only(tmp_path):
    result = run_suite("random", suite=tiny_suite().subset(plants=["DCStep"]), out=tmp_path, workers=1,
                       references=tmp_path / "refs")
    assert result.run.total == 3 and set(result.leaderboard.counts_["plant"]) == {"DCStep"}


def fresh_study(suite, tuner="random"):
    from evaluation.suite import tuner_study

    return tuner_study(suite, tuner)


# -- stale references ---------------------------------------------------------------------------------
TUNER_MODULE = '''
import agents
from agents.baselines import RandomSearch


class Mine(RandomSearch):
    """Random search under another name."""


agents.register("stale-test-tuner", Mine)
'''


def test_references_go_stale_when_a_fingerprint_input_changes_and_rebuild_fixes_them(tmp_path, monkeypatch):
    monkeypatch.setattr(agents.registry, "_REGISTRY", dict(agents.registry._REGISTRY))  # the module registers
    monkeypatch.syspath_prepend(str(tmp_path))
    (tmp_path / "stale_test_tuner.py").write_text(TUNER_MODULE)
    import stale_test_tuner  # noqa: F401  (registers the tuner)

    suite = tiny_suite([{"name": "stale-test-tuner", "label": "bo"}])
    refs = tmp_path / "refs"
    done = rebuild(suite, out=tmp_path / "work", folder=refs, workers=1)
    assert done == {"bo": ["DC", "DCStep"]}
    budgets = {"DC": 4, "DCStep": 5}
    optima = suite_optima(suite, budgets, refs)
    loaded = load_references(suite, optima, refs)
    assert not loaded.stale and not loaded.missing and len(loaded.curves) == 6
    assert set(loaded.curves["commit"].str.len()) <= {40, 46}  # a commit hash, "-dirty" where sources differ
    assert rebuild(suite, out=tmp_path / "work", folder=refs, workers=1) == {"bo": []}  # current: nothing rerun

    # the plant's kwargs
    other = tiny_suite([{"name": "stale-test-tuner", "label": "bo"}], kwargs={"output_noise_std": 0.1})
    changed = load_references(other, suite_optima(other, budgets, refs, tmp_path / "optima.json"), refs)
    assert list(changed.stale) == [("bo", "DC")]  # its output noise changes J* too
    assert changed.stale[("bo", "DC")][-1] == "the plant's env or kwargs changed"
    assert changed.stale[("bo", "DC")][0].startswith("J* changed (0.2695")
    # the tuner's source changed, what it does did not (a refactor): current, and a rebuild restamps, reruns nothing
    (tmp_path / "stale_test_tuner.py").write_text(TUNER_MODULE + "\n# an edit\n")
    fingerprint.reread_sources()  # a new command would read them anew
    assert not load_references(suite, optima, refs).stale
    old_hash = pd.read_parquet(reference_file("bo", refs))["tuner_hash"].unique().tolist()
    assert rebuild(suite, out=tmp_path / "work", folder=refs, workers=1) == {"bo": []}
    new_hash = pd.read_parquet(reference_file("bo", refs))["tuner_hash"].unique().tolist()
    assert len(old_hash) == len(new_hash) == 1 and old_hash != new_hash  # stamped with the source as it is now
    # ... and what it does: stale
    other = 'def ask(self):\n        super().ask()\n        return super().ask()'  # every other draw
    changed = TUNER_MODULE.replace('"""Random search under another name."""', other)
    (tmp_path / "stale_test_tuner.py").write_text(changed)
    importlib.reload(stale_test_tuner)
    fingerprint.reread_sources()
    behaviour.forget()
    stale = load_references(suite, optima, refs)
    assert set(stale.stale) == {("bo", "DC"), ("bo", "DCStep")}
    assert all(reasons[0].startswith("the tuner's behaviour changed since") for reasons in stale.stale.values())
    # a run without a behaviour fingerprint (made before them): stale when its source changed
    frame = pd.read_parquet(reference_file("bo", refs))
    frame.drop(columns=["tuner_behaviour", "plant_behaviour"]).to_parquet(reference_file("bo", refs))
    stale = load_references(suite, optima, refs)
    assert all(reasons[0].startswith("the tuner's source changed since") for reasons in stale.stale.values())
    frame.to_parquet(reference_file("bo", refs))
    # J* of one plant (a truth table that changed)
    (tmp_path / "stale_test_tuner.py").write_text(TUNER_MODULE)
    importlib.reload(stale_test_tuner)
    fingerprint.reread_sources()
    behaviour.forget()
    frame = pd.read_parquet(reference_file("bo", refs))
    frame.loc[frame["plant"] == "DC", "optimum"] *= 1.01
    frame.to_parquet(reference_file("bo", refs))
    stale = load_references(suite, optima, refs)
    assert list(stale.stale) == [("bo", "DC")] and stale.stale[("bo", "DC")][0].startswith("J* changed")
    # one command rebuilds what is stale, and only that
    assert rebuild(suite, out=tmp_path / "work2", folder=refs, workers=1) == {"bo": ["DC"]}
    assert not load_references(suite, optima, refs).stale


def test_a_rebuild_on_chosen_plants_reruns_only_those_and_names_an_unknown_plant(tmp_path):
    suite = tiny_suite([{"name": "random", "label": "bo"}])
    refs = tmp_path / "refs"
    assert rebuild(suite, out=tmp_path / "work", folder=refs, workers=1, plants=["DCStep"]) == {"bo": ["DCStep"]}
    loaded = load_references(suite, suite_optima(suite, {"DC": 4, "DCStep": 5}, refs), refs)
    assert loaded.missing == [("bo", "DC")] and set(loaded.curves["plant"]) == {"DCStep"}
    assert rebuild(suite, out=tmp_path / "work", folder=refs, workers=1, plants=["DC"]) == {"bo": ["DC"]}
    assert set(read_curves(reference_file("bo", refs))["plant"]) == {"DC", "DCStep"}  # the first plant's rows kept
    with pytest.raises(ValueError, match=r"--plant: \['Nope'\] are not plants of 'tiny-suite'; its plants: DC, DCStep"):
        rebuild(suite, out=tmp_path / "work", folder=refs, workers=1, plants=["Nope"])


def test_an_interrupted_rebuild_names_no_plant_rebuilt_and_writes_nothing(tmp_path, monkeypatch):
    import types

    import evaluation.references as references

    suite = tiny_suite([{"name": "random", "label": "bo"}])
    refs = tmp_path / "refs"
    monkeypatch.setattr(references, "run_study", lambda *a, **k: types.SimpleNamespace(interrupted=True, failed=[]))
    done = rebuild(suite, out=tmp_path / "work", folder=refs, workers=1)
    assert done == {"interrupted": True}  # the CLI printed "bo: rebuilt on DC, DCStep" after a Ctrl-C
    assert not reference_file("bo", refs).exists()


def test_the_shipped_references_cover_the_quick_suite():
    suite = load_suite("quick")
    budgets = {"DCMotor-v0": 35, "DCMotorRig-v0": 35, "LinearMotor-v0": 25}
    refs = load_references(suite, suite_optima(suite, budgets), REFERENCES_DIR)
    assert not refs.missing
    assert set(refs.curves["tuner"]) == set(suite.labels)
    assert refs.curves.groupby(["tuner", "plant"]).size().eq(3).all()


# -- a researcher's tuner -----------------------------------------------------------------------------
USER_MODULE = textwrap.dedent('''
    import numpy as np
    import agents


    class LocalRandomSearch(agents.Tuner):
        name = "local-random"

        def __init__(self, *, step: float = 0.1) -> None:
            self.step = step
            self._params = {"step": step}

        def _setup(self) -> None:
            self.best_gains, self.best_cost = None, np.inf

        def _ask(self):
            if self.best_gains is None:
                return self.rng.uniform(self.space.low, self.space.high)
            step = self.step * (self.space.high - self.space.low) * self.rng.standard_normal(self.space.dim)
            return np.clip(self.best_gains + step, self.space.low, self.space.high)

        def _tell(self, gains, cost, record) -> None:
            if cost < self.best_cost:
                self.best_gains, self.best_cost = gains, cost


    agents.register("local-random", LocalRandomSearch)
''')


def _digest(folder) -> str:
    return hashlib.sha256(b"".join(p.read_bytes() for p in sorted(folder.glob("*")))).hexdigest()


@pytest.mark.slow
def test_a_tuner_from_the_users_module_gets_a_leaderboard_with_the_references(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(agents.registry, "_REGISTRY", dict(agents.registry._REGISTRY))  # the module registers
    (tmp_path / "my_tuner.py").write_text(USER_MODULE)
    before = _digest(REFERENCES_DIR)
    argv = ["bench", "suite", "--import", "my_tuner", "--tuner", "local-random", "--tuner-kwargs", '{"step": 0.05}',
            "--suite", "quick", "--seeds", "1", "--workers", "2", "--out", "out", "--quiet"]
    assert main(argv) == 0  # two worker processes: each imports my_tuner from the working folder
    out = capsys.readouterr().out
    assert "3 of 3 runs of local-random finished (3 now" in out and "leaderboard: out/leaderboard.md" in out
    assert sorted(p.name for p in (tmp_path / "out").iterdir() if p.is_dir()) == ["local-random"]  # no reference run
    assert _digest(REFERENCES_DIR) == before
    md = (tmp_path / "out" / "leaderboard.md").read_text()
    assert "3 plants (DCMotor-v0, DCMotorRig-v0, LinearMotor-v0), seeds 0-0," in md  # what ran, and nothing else:
    assert "30 seeds" not in md and "every registered env" not in md  # not the standard suite's scope
    assert "| **local-random** ◀ yours |" in md  # the user's tuner, marked
    for tuner in ["bo", "guided-bo", "random", "botorch", "nominal"]:
        assert f"| {tuner} |" in md, tuner
    csv = pd.read_csv(tmp_path / "out" / "leaderboard.csv")
    mine = csv[(csv["tuner"] == "local-random") & (csv["kind"] == "plant")]
    assert list(mine["plant"]) == ["DCMotor-v0", "DCMotorRig-v0", "LinearMotor-v0"] and set(mine["seeds"]) == {1}
    meta = json.loads((tmp_path / "out" / "leaderboard.json").read_text())
    assert meta["tuner"] == {"label": "local-random", "name": "local-random", "params": {"step": 0.05},
                             "imports": ["my_tuner"], "runs": 3}
    assert main(argv) == 0 and "0 now" in capsys.readouterr().out  # rerun: resumed, nothing run again
    kept = read_curves(tmp_path / "out" / "local-random" / CURVES_FILE)
    assert kept.empty
