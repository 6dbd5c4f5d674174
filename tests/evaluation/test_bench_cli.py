"""``gbo bench``'s defaults: where reports go and what a missing pyarrow says."""

from __future__ import annotations

import sys
from pathlib import Path

from evaluation.cli import main
from evaluation.study import load_study
from evaluation.study_runner import default_out_dir


def test_default_output_is_under_the_working_directory_not_the_package():
    out = default_out_dir(load_study("smoke"))
    assert out == Path("out") / "studies" / "smoke"
    assert not out.is_absolute()


def test_bench_without_pyarrow_stops_and_says_how_to_install_it(monkeypatch, tmp_path, capsys):
    monkeypatch.setitem(sys.modules, "pyarrow", None)  # what importlib sees when pyarrow is not installed
    assert main(["bench", "smoke", "--out", str(tmp_path / "o"), "--quiet"]) == 2
    assert "pip install pyarrow" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()
