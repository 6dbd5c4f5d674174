"""``examples/twin_workbench.py`` says why its ladder stops: nothing improves, or the cap on effects."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

EXAMPLE = Path(__file__).resolve().parents[3] / "examples" / "twin_workbench.py"


@pytest.mark.slow
def test_cap_on_effects_is_not_reported_as_no_improvement(capsys):
    spec = importlib.util.spec_from_file_location("twin_workbench_example", EXAMPLE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    module.main(max_effects=0)  # saturation improves the rig's linear model, but no effect may be added
    out = capsys.readouterr().out
    assert "no effect improves" not in out and "none improves" not in out
    assert "saturation still improves the model (+ saturation (limit " in out and "stopping at 0 effects" in out
