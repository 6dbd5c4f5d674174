"""Workbench CSV: round trip with env records, and clear errors naming the row and the column."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import gbo_envs  # noqa: F401  (registers the envs)
from agents.twin.csvio import read_csv, records_from_env, write_csv

HEADER = "experiment,t,r,u,y"


def _write(tmp_path, text: str):
    path = tmp_path / "data.csv"
    path.write_text(text)
    return path


def _good_rows(exp: int = 0, n: int = 4) -> list[str]:
    return [f"{exp},{0.002 * i:g},306,{100 + i},{245 + i}" for i in range(n)]


def test_round_trip_of_env_records(tmp_path):
    env = gym.make("gbo_envs/DCMotor-v0", noise=False)
    records = records_from_env(env, np.array([[0.5, 1.2], [0.8, 1.0]]), seed=0)
    path = write_csv(records, tmp_path / "out" / "d.csv")
    back = read_csv(path)
    assert [r["experiment"] for r in back] == [0, 1]
    for rec, got in zip(records, back):
        for name in ("t", "r", "u", "y"):
            np.testing.assert_allclose(got[name], rec[name], rtol=1e-9, atol=1e-12)
    assert path.read_text().splitlines()[0] == HEADER + ",gain0,gain1"


def test_extra_columns_and_order_of_experiments(tmp_path):
    rows = [HEADER + ",Kp,note"] + [r + ",0.5,x" for r in _good_rows(7)] + [r + ",0.6,y" for r in _good_rows(3)]
    recs = read_csv(_write(tmp_path, "\n".join(rows)))
    assert [r["experiment"] for r in recs] == [7, 3]
    assert recs[0]["u"].tolist() == [100, 101, 102, 103]


@pytest.mark.parametrize("text, message", [
    ("experiment,t,r,y\n0,0,1,2\n", "row 1 (header): missing column(s) ['u']"),
    (HEADER + "\n", "no data rows"),
    (HEADER + "\n" + "\n".join(_good_rows()[:2] + ["0,0.004,306,abc,247"]),
     "row 4, column 'u': non-numeric value 'abc'"),
    (HEADER + "\n" + "\n".join(_good_rows()[:3] + ["0,0.006,306,103,"]), "row 5, column 'y': missing value"),
    (HEADER + "\n" + "\n".join(_good_rows()[:1] + ["0,0.002,nan,101,246"]), "row 3, column 'r': missing value"),
    (HEADER + "\n" + "\n".join(_good_rows()[:2] + ["0,0.002,306,102,247"]),
     "row 4, column 't': time 0.002 s does not increase within experiment 0"),
    (HEADER + "\n" + "\n".join(_good_rows()[:3] + ["0,0.009,306,102,247"]), "row 5, column 't': samples must be"),
    (HEADER + "\n" + "\n".join(_good_rows() + ["1,0,306,1,1"]), "row 6, column 'experiment': experiment 1 has 1"),
    (HEADER + "\n" + "\n".join(_good_rows()[:1] + ["0.5,0.002,306,1,1"]),
     "row 3, column 'experiment': experiment id must be an integer"),
    (HEADER + "\n" + "\n".join(_good_rows()[:1] + ["0,0.002,306,inf,1"]), "row 3, column 'u': non-finite value"),
])
def test_bad_data_names_row_and_column(tmp_path, text, message):
    with pytest.raises(ValueError) as info:
        read_csv(_write(tmp_path, text))
    assert message in str(info.value)


def test_missing_file_and_empty_file(tmp_path):
    with pytest.raises(FileNotFoundError):
        read_csv(tmp_path / "nope.csv")
    with pytest.raises(ValueError, match="empty"):
        read_csv(_write(tmp_path, ""))
