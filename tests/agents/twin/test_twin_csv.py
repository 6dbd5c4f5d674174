"""Workbench CSV: round trip with env records, and clear errors naming the row and the column."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import gbo_envs  # noqa: F401  (registers the envs)
from agents.twin.csvio import read_csv, records_from_env, write_csv
from gbo_envs.experiment import Experiment

HEADER = "experiment,t,r,u,y"


def _write(tmp_path, text: str):
    """``text`` as ``data.csv``, its last row ended with a line break as every CSV writer does."""
    path = tmp_path / "data.csv"
    path.write_text(text if not text or text.endswith("\n") else text + "\n")
    return path


def _good_rows(exp: int = 0, n: int = 4) -> list[str]:
    return [f"{exp},{0.002 * i:g},306,{100 + i},{245 + i}" for i in range(n)]


def test_round_trip_of_env_records(tmp_path):
    env = gym.make("gbo_envs/DCMotor-v0", noise=False)
    records = records_from_env(env, np.array([[0.5, 1.2], [0.8, 1.0]]), seed=0)
    assert all(isinstance(r, Experiment) for r in records)
    path = write_csv(records, tmp_path / "out" / "d.csv")
    back = read_csv(path)
    assert [r.index for r in back] == [0, 1]
    for rec, got in zip(records, back):
        for name in ("t", "r", "u", "y"):
            np.testing.assert_allclose(getattr(got, name), getattr(rec, name), rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(got.gains, rec.gains, rtol=1e-9)
        assert got.cost == pytest.approx(rec.cost, rel=1e-9) and got.source == "plant"
    assert path.read_text().splitlines()[0] == HEADER + ",gain0,gain1,source,cost"


def test_named_gains_twin_source_and_unknown_cost_round_trip(tmp_path):
    t = np.arange(5) * 0.01
    records = [Experiment(gains=[0.5, 1.5], t=t, r=np.full(5, 2.0), u=t + 1, y=t ** 2, cost=0.25, index=3),
               Experiment(gains=[0.7, 1.1], t=t, r=np.full(5, 2.0), u=-t, y=t, source="twin", index=8)]
    path = write_csv(records, tmp_path / "named.csv", gain_names=("Kp", "Ki"))
    assert path.read_text().splitlines()[0] == HEADER + ",Kp,Ki,source,cost"
    back = read_csv(path, gain_names=("Kp", "Ki"))
    assert [(r.index, r.source) for r in back] == [(3, "plant"), (8, "twin")]
    assert back[0].cost == 0.25 and np.isnan(back[1].cost)
    np.testing.assert_array_equal(back[1].gains, [0.7, 1.1])
    np.testing.assert_allclose(back[0].y, t ** 2, rtol=1e-9, atol=1e-15)
    assert read_csv(path)[0].gains.shape == (0,)  # without gain_names only gain0, gain1, ... are read


def test_writer_rejects_records_without_signals_and_wrong_gain_names(tmp_path):
    with pytest.raises(ValueError, match="has no t, r, u, y"):
        write_csv([Experiment(gains=[0.5], cost=1.0, source="twin")], tmp_path / "x.csv")
    t = np.arange(4) * 0.1
    with pytest.raises(ValueError, match="gain_names: 1 names"):
        write_csv([Experiment(gains=[0.5, 1.0], t=t, r=t, u=t, y=t)], tmp_path / "x.csv", gain_names=["Kp"])


def test_extra_columns_and_order_of_experiments(tmp_path):
    rows = [HEADER + ",Kp,note"] + [r + ",0.5,x" for r in _good_rows(7)] + [r + ",0.6,y" for r in _good_rows(3)]
    recs = read_csv(_write(tmp_path, "\n".join(rows)))
    assert [r.index for r in recs] == [6, 2]  # experiments 7 and 3 of the file: 0-based indices
    assert recs[0].u.tolist() == [100, 101, 102, 103]
    assert read_csv(_write(tmp_path, "\n".join(rows)), gain_names=["Kp"])[1].gains.tolist() == [0.6]


@pytest.mark.parametrize("text, message", [
    ("experiment,t,r,y\n0,0,1,2\n", "row 1 (header): missing column(s) ['u']"),
    (HEADER + "\n", "no data rows"),
    (HEADER + "\n" + "\n".join(_good_rows()[:2] + ["0,0.004,306,abc,247"]),
     "row 4, column 'u': non-numeric value 'abc'"),
    (HEADER + "\n" + "\n".join(_good_rows()[:3] + ["0,0.006,306,103,"]), "row 5, column 'y': missing value"),
    (HEADER + "\n" + "\n".join(_good_rows()[:1] + ["0,0.002,nan,101,246"]), "row 3, column 'r': missing value"),
    (HEADER + "\n" + "\n".join(_good_rows()[:2] + ["0,0.002,306,102,247"]),
     "row 4, column 't': experiment 0: must increase strictly, got 0.002 s at sample 2 after 0.002 s"),
    (HEADER + "\n" + "\n".join(_good_rows()[:3] + ["0,0.009,306,102,247"]),
     "row 5, column 't': experiment 0: must be uniformly spaced"),
    (HEADER + "\n" + "\n".join(_good_rows() + ["1,0,306,1,1"]),
     "row 6, column 'experiment': experiment 1: need at least 3 samples, got 1"),
    (HEADER + "\n" + "\n".join(_good_rows()[:1] + ["0.5,0.002,306,1,1"]),
     "row 3, column 'experiment': experiment id must be an integer"),
    (HEADER + "\n" + "\n".join(_good_rows()[:1] + ["0,0.002,306,inf,1"]), "row 3, column 'u': non-finite value"),
    (HEADER + ",gain0\n" + "\n".join(r + f",{0.5 + i}" for i, r in enumerate(_good_rows())),
     "row 3, column 'gain0': must be constant within experiment 0, got 1.5 after 0.5"),
    (HEADER + ",source\n" + "\n".join(r + ",rig" for r in _good_rows()),
     "row 2, column 'source': must be one of ('plant', 'twin'), got 'rig'"),
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


@pytest.mark.parametrize("cut", [1, 3, 9])
def test_a_file_cut_mid_row_is_an_error_naming_file_and_row(tmp_path, cut):
    # cut 1 leaves "246" of "2463": a cut number that every other check would take
    text = HEADER + "\n" + "\n".join(_good_rows(n=5)[:4] + ["0,0.008,306,104,2463.25"]) + "\n"
    path = tmp_path / "cut.csv"
    path.write_text(text[:-1 - cut])
    with pytest.raises(ValueError, match=r"cut\.csv, row 6: the last row ends without a line break"):
        read_csv(path)
    path.write_text(text)
    assert read_csv(path)[0].y[-1] == 2463.25
    path.write_text(text.replace("\n", "\r\n"))  # Windows line ends
    assert read_csv(path)[0].n_steps == 5


def test_csv_numbers_experiments_as_the_result_table_does(tmp_path):
    import pandas as pd

    import agents

    result = agents.make("random").run(gym.make("gbo_envs/DCMotor-v0", noise=False), budget=2, seed=0)
    path = write_csv(result.experiments, tmp_path / "run.csv")
    numbers = pd.read_csv(path)["experiment"].unique().tolist()
    assert numbers == result.to_pandas()["experiment"].tolist() == [1, 2]  # counted from 1 in both
    assert [r.index for r in read_csv(path)] == [r.index for r in result.experiments] == [0, 1]


def test_chunked_reading_matches_one_chunk_and_names_rows_in_later_chunks(tmp_path, monkeypatch):
    """Read in chunks of 5 rows (``CHUNK_ROWS``): the same records as in one chunk; a bad value in a later
    chunk is named by its file line; a cost blank in one chunk and numeric in another is read per experiment."""
    import agents.twin.csvio as csvio

    lines = [HEADER + ",gain0,source,cost"]
    for exp in range(4):
        cost = "" if exp % 2 else f"{1.5 + exp}"
        lines += [f"{row},{0.7 + exp},{'twin' if exp == 3 else 'plant'},{cost}" for row in _good_rows(exp, 6)]
    path = _write(tmp_path, "\n".join(lines) + "\n")
    whole = read_csv(path)
    monkeypatch.setattr(csvio, "CHUNK_ROWS", 5)
    chunked = read_csv(path)
    assert [r.index for r in chunked] == [r.index for r in whole] == [-1, 0, 1, 2]  # CSV numbers 0-3 count from 1
    for a, b in zip(whole, chunked):
        for name in ("t", "r", "u", "y", "gains"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
        assert a.source == b.source and (a.cost == b.cost or (np.isnan(a.cost) and np.isnan(b.cost)))
    assert [r.source for r in chunked] == ["plant", "plant", "plant", "twin"]
    assert [r.cost for r in chunked][::2] == [1.5, 3.5] and np.isnan(chunked[1].cost)
    lines[20] = lines[20].replace(",306,", ",abc,")  # line 21 of the file, in the 4th chunk
    path = _write(tmp_path, "\n".join(lines) + "\n")
    with pytest.raises(ValueError, match=r"row 21, column 'r': non-numeric value 'abc'"):
        read_csv(path)


def test_records_share_the_parsed_columns_instead_of_copying_them(tmp_path):
    """Memory linear in the data with a small constant: one float array per signal for all experiments."""
    rows = [row for exp in (1, 2, 3) for row in _good_rows(exp, n=5)]
    records = read_csv(_write(tmp_path, "\n".join([HEADER, *rows])))
    assert [rec.n_steps for rec in records] == [5, 5, 5]
    for name in ("t", "r", "u", "y"):
        first, second = getattr(records[0], name), getattr(records[1], name)
        assert first.base is not None and first.base is second.base and not first.flags.writeable  # one column
    np.testing.assert_array_equal(records[2].u, [100, 101, 102, 103, 104])


def test_experiments_listed_out_of_order_and_interleaved_read_alike(tmp_path):
    ordered = read_csv(_write(tmp_path, "\n".join([HEADER, *_good_rows(1), *_good_rows(2)])))
    rows_1, rows_2 = _good_rows(1), _good_rows(2)
    mixed = [rows_2[0], rows_1[0], rows_2[1], rows_1[1], *rows_2[2:], *rows_1[2:]]  # experiment 2 first
    shuffled = read_csv(_write(tmp_path, "\n".join([HEADER, *mixed])))
    assert [rec.index for rec in shuffled] == [1, 0]
    for a, b in zip(ordered, shuffled[::-1]):
        for name in ("t", "r", "u", "y"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
