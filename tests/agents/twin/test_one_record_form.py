"""One record form through the twin: Experiments come in, one validated Batch lives inside, identify takes it;
no import cycle in agents.twin, function-local imports only for a heavy dependency."""

from __future__ import annotations

import ast
import dataclasses
import inspect
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import agents.twin
import gbo_envs  # noqa: F401  (registers the envs)
from agents.twin.identify import DelaySearch, IdentifyOptions, SrivcOptions, checked_options, identify, identify_linear
from agents.twin.records import Batch, as_records, decimate_records
from gbo_envs.experiment import Experiment, RecordError

TWIN = Path(agents.twin.__file__).parent
HEAVY = "# heavy dependency: "


@pytest.fixture(scope="module")
def records():
    env = gym.make("gbo_envs/DCMotor-v0", output_noise_std=0.05)
    env.reset(seed=0)
    return [Experiment.from_mapping(env.step(np.array(g))[4]) for g in ([0.5, 1.2], [0.9, 2.0], [0.7, 1.5])]


def test_identify_takes_the_batch_and_an_option_object(records):
    batch = Batch.from_records(records)
    options = IdentifyOptions(delay_search=DelaySearch(max_delay=0.006), solver=SrivcOptions(n_samples=200))
    fit = identify(batch, options)
    assert fit.n_records == 3 and fit.n_samples < batch.u.shape[1]  # decimated inside, from the batch
    np.testing.assert_array_equal(fit.params, identify_linear(records, max_delay=0.006, n_samples=200).params)
    assert len(inspect.signature(identify).parameters) <= 12
    assert checked_options(options.settings(), "f") == options  # the flat names, grouped back
    assert options.settings()["max_delay"] == 0.006 and options.settings()["n_samples"] == 200
    with pytest.raises(dataclasses.FrozenInstanceError):
        options.n_poles = 3  # type: ignore[misc]
    with pytest.raises(TypeError):
        IdentifyOptions(2)  # type: ignore[misc]  (keyword-only)


def test_identify_linear_refuses_an_unknown_setting(records):
    with pytest.raises(TypeError, match="n_pole"):
        identify_linear(records, n_pole=2)


def test_records_of_different_sample_times_are_refused_once(records):
    slow = records[0].replace(t=records[0].t * 2.0)
    with pytest.raises(ValueError, match="same sample time"):
        identify_linear([records[1], slow])


def test_thinned_keeps_the_samples_as_they_are_and_the_starts(records):
    batch = Batch.from_records(records)
    assert batch.thinned(None) is batch
    thin = batch.thinned(101)
    stride = (batch.lengths.min() - 1) // 100
    np.testing.assert_array_equal(thin.t[:, :101], batch.t[:, : 101 * stride : stride])
    np.testing.assert_array_equal(thin.u[:, :101], batch.u[:, : 101 * stride : stride])
    assert thin.initial is batch.initial and thin.record_dt(0) == pytest.approx(stride * batch.dt, rel=1e-12)


@pytest.mark.parametrize("mean_input", [False, True])
def test_thinned_takes_the_samples_decimate_records_keeps_of_the_records(mean_input):
    """Rows of three lengths, with a command that moves within the holds of the first stride (that of the shortest
    row, 12 samples): the thinned rows are :func:`decimate_records` of the records, bit for bit."""
    t = np.arange(2001) * 1e-3
    u = 1.0 + np.exp(-t / 0.05) * np.sin(t / 0.05 * 3)
    rows = [{"t": t[:m], "r": np.ones(m), "u": u[:m] * (1 + k), "y": np.cos(t[:m] * (k + 1))}
            for k, m in enumerate((2001, 1201, 1733))]
    batch = Batch.from_records(rows)
    thin = batch.thinned(101, mean_input)
    kept = decimate_records(as_records(rows), 101, mean_input)
    stride = round(kept[0].dt / 1e-3)
    assert 1 < stride < 12 and kept[0].n_steps == 1200 // stride + 1  # shortened, over the first stride's span
    assert thin.lengths.tolist() == [rec.n_steps for rec in kept] and thin.mask.all()
    assert thin.dt == batch.dt and thin.initial is batch.initial and thin.index is batch.index
    for k, rec in enumerate(kept):
        for name in ("r", "u", "y"):
            np.testing.assert_array_equal(getattr(thin, name)[k], getattr(rec, name))
        np.testing.assert_array_equal(thin.t[k], batch.t[k, : stride * rec.n_steps : stride])
        assert thin.record_dt(k) == rec.dt
    assert not thin.u.flags.writeable and not thin.mask.flags.writeable
    assert batch.thinned(5000, mean_input) is batch


def test_groups_are_the_rows_of_one_length(records):
    short = records[2].replace(t=records[2].t[:1000], r=records[2].r[:1000], u=records[2].u[:1000],
                               y=records[2].y[:1000])
    batch = Batch.from_records([records[0], short, records[1]])
    assert [rows.tolist() for rows in batch.groups()] == [[0, 2], [1]]
    assert [rows.tolist() for rows in batch.groups(max_samples=batch.lengths.max())] == [[0], [2], [1]]


def test_with_input_refuses_a_non_finite_plant_input(records):
    batch = Batch.from_records(records)
    u = np.array(batch.u)
    u[1, 5] = np.nan
    with pytest.raises(RecordError, match="experiment 2"):
        batch.with_input(u)
    assert batch.with_input(2.0 * batch.u).initial is batch.initial


def test_no_import_cycle_in_the_twin_counting_function_level_imports():
    grimp = pytest.importorskip("grimp")
    graph = grimp.build_graph("agents")
    modules = sorted(m for m in graph.modules if m.startswith("agents.twin."))
    cycles = [(a, b) for a in modules for b in modules if a < b
              and graph.chain_exists(importer=a, imported=b) and graph.chain_exists(importer=b, imported=a)]
    assert cycles == []


def _local_imports(path: Path):
    tree = ast.parse(path.read_text())
    for fn in ast.walk(tree):
        if isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
            for node in ast.walk(fn):
                if isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] in (
                        "agents", "gbo_envs", "evaluation"):
                    yield node


def test_a_function_local_project_import_only_keeps_a_heavy_dependency_off_the_start_up():
    bad = []
    for path in sorted(TWIN.rglob("*.py")):
        lines = path.read_text().splitlines()
        bad += [f"{path.name}:{node.lineno}" for node in _local_imports(path)
                if not lines[node.lineno - 2].strip().startswith(HEAVY)]
    assert bad == []
