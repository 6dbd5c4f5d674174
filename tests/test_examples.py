"""The bundled example data is what its script writes with today's code."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pandas as pd

EXAMPLE_DATA = Path(__file__).resolve().parents[1] / "examples" / "data"


def test_the_bundled_rig_data_is_what_make_dc_rig_writes(tmp_path):
    spec = importlib.util.spec_from_file_location("make_dc_rig", EXAMPLE_DATA / "make_dc_rig.py")
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    fresh = pd.read_csv(script.main(tmp_path / "dc_rig.csv"))
    shipped = pd.read_csv(EXAMPLE_DATA / "dc_rig.csv")
    assert list(fresh.columns) == list(shipped.columns) and len(fresh) == len(shipped)
    assert fresh["source"].equals(shipped["source"])
    numbers = fresh.columns.drop("source")
    # the last bits may differ between numerical stacks; a changed cost or response may not
    np.testing.assert_allclose(fresh[numbers].to_numpy(float), shipped[numbers].to_numpy(float), rtol=1e-9,
                               atol=1e-9)
