"""benchmarks/reference_reproduction.py: the shipped references rerun seed by seed on this machine."""

from __future__ import annotations

import platform
import sys

import pytest

from evaluation import references
from tests.support import benchmark_module


def _main(monkeypatch, *argv) -> None:
    monkeypatch.setattr(sys, "argv", ["reference_reproduction.py", *argv])
    benchmark_module(monkeypatch, "reference_reproduction").main()


def test_two_curves_part_at_the_first_experiment_beyond_the_tolerance(monkeypatch):
    first_parting = benchmark_module(monkeypatch, "reference_reproduction").first_parting
    assert first_parting([1.2, 1.1, 1.0], [1.2, 1.1, 1.0], 1e-6) is None
    assert first_parting([1.2, 1.1, 1.0], [1.2, 1.1000001, 1.0], 1e-9) == 2
    assert first_parting([1.2, 1.1, 1.0], [1.2, 1.1000001, 1.0], 1e-6) is None
    assert first_parting([1.2, 1.1], [1.2, 1.1, 1.0], 1e-6) == 3  # the shorter curve lacks the third


def test_a_reference_without_each_experiments_ratio_is_compared_by_its_best_ratio_curve(monkeypatch):
    curves = benchmark_module(monkeypatch, "reference_reproduction")._curves
    rerun = {"curve": [1.3, 1.1], "instant": [1.3, 1.2]}
    assert curves(rerun, {"curve": [1.3, 1.1], "instant": None}) == ([1.3, 1.1], [1.3, 1.1])
    assert curves(rerun, {"curve": [1.3, 1.1], "instant": [1.3, 1.2]}) == ([1.3, 1.2], [1.3, 1.2])


@pytest.mark.skipif(platform.machine() != "x86_64", reason="the Makefile pins OpenBLAS's kernels on x86-64 only")
def test_the_tests_run_with_the_kernels_of_the_references():
    """make test pins OpenBLAS's kernels (OPENBLAS_CORETYPE); without the pin an AVX-512 CPU runs others."""
    assert references.kernel_warning() is None


def test_other_kernels_are_named_in_the_warning(monkeypatch):
    monkeypatch.setattr(references, "blas_kernels", lambda: {"SkylakeX", "Haswell"})
    assert "its SkylakeX kernels here, the references Haswell's" in references.kernel_warning()
    monkeypatch.setattr(references, "blas_kernels", lambda: {"Haswell"})
    assert references.kernel_warning() is None


@pytest.mark.parametrize("plant", ["DCMotor-v0", "LinearMotorCascade-v0"])
def test_the_bo_reference_reproduces_on_this_stack(monkeypatch, capsys, tmp_path, plant):
    """bo's seed 0, on the grid path (2 gains) and on the multistart L-BFGS-B path (4 gains), as shipped:
    a change of the numerical stack that moves the references fails here, not silently in the leaderboard."""
    _main(monkeypatch, "--tuner", "bo", "--plant", plant, "--out", str(tmp_path))
    assert f"| bo | {plant} | 1 of 1 | - |" in capsys.readouterr().out
    assert len(list((tmp_path / "results").glob("*.parquet"))) == 1


def test_an_unknown_plant_is_refused_naming_the_suite(monkeypatch, capsys, tmp_path):
    with pytest.raises(SystemExit) as stop:
        _main(monkeypatch, "--plant", "DCMotor-v9", "--out", str(tmp_path))
    assert stop.value.code == 2
    assert "--plant: ['DCMotor-v9'] are not plants of 'suite'; its plants: DCMotor-v0," in capsys.readouterr().err
