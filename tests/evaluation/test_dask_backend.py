"""The dask backend on a real 2-worker LocalCluster gives the same results as local joblib processes."""

from __future__ import annotations

import pandas as pd
import pytest

from evaluation import analysis
from evaluation.study import parse_study
from evaluation.study_runner import run_study
from tests.support import TIMING_COLUMNS

distributed = pytest.importorskip("distributed")
pytestmark = pytest.mark.slow  # a 2-worker cluster per test


def study():
    return parse_study({"study": {"name": "dask-tiny", "batches": 2, "budget": 3, "seed": 11, "resolution": 10},
                        "env": {"id": "gbo_envs/DCMotor-v0"},
                        "tuners": [{"name": "random", "label": "random search"}]})


def test_dask_local_cluster_matches_local_backend(tmp_path):
    spec = study()
    local = run_study(spec, tmp_path / "local", backend="local", workers=2, progress=False)
    assert local.completed == 2
    with distributed.LocalCluster(n_workers=2, processes=True, threads_per_worker=1,
                                  dashboard_address=":0") as cluster:
        remote = run_study(spec, tmp_path / "dask", backend="dask", address=cluster.scheduler_address,
                           progress=False)
    assert remote.completed == 2 and not remote.failed
    a = analysis.load_results(tmp_path / "local", spec).drop(columns=TIMING_COLUMNS)
    b = analysis.load_results(tmp_path / "dask", spec).drop(columns=TIMING_COLUMNS)
    assert len(a) == 6 and a["seed"].tolist() == [11, 11, 11, 12, 12, 12]
    pd.testing.assert_frame_equal(a, b)


def test_dask_without_address_starts_its_own_cluster(tmp_path):
    spec = study()
    run = run_study(spec, tmp_path, backend="dask", workers=2, progress=False)
    assert run.completed == 2 and run.done
    assert len(analysis.load_results(tmp_path, spec)) == 6


def test_the_suite_on_dask_imports_the_users_tuner_in_every_worker(tmp_path, monkeypatch):
    import agents
    from evaluation.suite import run_suite

    monkeypatch.setattr(agents.registry, "_REGISTRY", dict(agents.registry._REGISTRY))  # the module registers
    monkeypatch.chdir(tmp_path)
    (tmp_path / "dask_user_tuner.py").write_text(
        "import agents\nfrom agents.baselines import RandomSearch\n\n\nclass Mine(RandomSearch):\n    pass\n\n\n"
        "agents.register('dask-user-tuner', Mine)\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    import dask_user_tuner  # noqa: F401  (registers it here; the workers import it from the task)

    suite = parse_study({"study": {"name": "tiny-suite", "batches": 2, "resolution": 8},
                         "plants": [{"label": "DC", "id": "gbo_envs/DCMotor-v0", "thresholds": [1.3], "budget": 3}],
                         "tuners": [{"name": "random", "label": "bo"}]})
    result = run_suite("dask-user-tuner", suite=suite, imports=["dask_user_tuner"], out=tmp_path / "out",
                       backend="dask", workers=2, references=tmp_path / "refs")
    assert result.run.completed == 2 and not result.run.failed
    assert set(result.leaderboard.counts_["tuner"]) == {"dask-user-tuner"}
