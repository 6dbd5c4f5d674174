"""Bad input ends every ``gbo`` command with exit status 2 and one line on stderr (issue 19, items 5, 8, 9, 10).

Each test feeds one defect of the issue's attack to the public entry point
where it lives (the CLI's ``main``, ``gym.make``, ``read_csv``, ``diagnose``,
``run_study``) and checks the refusal: a one-line message naming the argument,
file or value, and no traceback; the Python API raises ``ValueError`` or
``TypeError`` with the same text.
"""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest

import gbo_envs  # noqa: F401  (registers the envs)
from agents.twin.csvio import read_csv, write_csv
from agents.twin.records import Batch
from agents.twin.workbench import diagnose
from evaluation.cli import main
from evaluation.study import StudySpecError, parse_study
from evaluation.study_runner import run_study
from tests.support import loop_records

ENV = "gbo_envs/DCMotor-v0"


def refused(capsys, argv: list[str], *words: str) -> str:
    """Run ``gbo argv``; assert exit status 2, one line on stderr containing ``words``, no traceback."""
    capsys.readouterr()
    try:
        status = main(argv)
    except SystemExit as exc:  # argparse refuses while parsing
        status = exc.code
    err = capsys.readouterr().err
    assert status == 2, (status, err)
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    for word in words:
        assert word in err, (word, err)
    return err


@pytest.fixture(scope="module")
def csv_path(tmp_path_factory):
    records = loop_records(gains=np.array([[0.3, 1.0], [0.9, 1.2], [1.05, 2.0]]), duration=0.5, start_index=4)
    return write_csv(records, tmp_path_factory.mktemp("twin") / "three.csv")


# -- item 5: --folds ------------------------------------------------------------------------------------
@pytest.mark.parametrize("folds", ["0", "-1", "1"])
def test_folds_below_two_are_refused(capsys, csv_path, folds):
    refused(capsys, ["twin", "diagnose", str(csv_path), "--folds", folds], "--folds", ">= 2")


def test_folds_above_the_number_of_experiments_are_refused(capsys, csv_path):
    refused(capsys, ["twin", "diagnose", str(csv_path), "--folds", "4"], "--folds", "number of experiments (3)")
    data = Batch.from_records(read_csv(csv_path))
    with pytest.raises(ValueError, match=r"n_folds.*from 2 to the number of experiments \(3\), got 0"):
        diagnose(data, n_folds=0)


# -- item 8: names and ids ------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["..", ".", "a.b", "../x", "a b", ""])
def test_study_names_are_letters_digits_underscore_dash(name):
    spec = {"study": {"name": name, "batches": 1, "budget": 2}, "env": {"id": ENV}, "tuners": [{"name": "random"}]}
    with pytest.raises(StudySpecError, match=r"\[study\] name"):
        parse_study(spec)


def test_a_study_name_cannot_reach_outside_the_shipped_folder(capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    refused(capsys, ["bench", "../studies/smoke", "--quiet"], "no such file and no shipped study")
    refused(capsys, ["bench", "."], "is a folder")


def test_env_accepts_registered_ids_only(capsys, tmp_path):
    db = str(tmp_path / "r.sqlite")
    refused(capsys, ["tune", "--env", "gbo_envs/Nope-v0", "--budget", "1", "--db", db], "--env", "registered",
            ENV)
    refused(capsys, ["tune", "--env", "json:Env-v0", "--budget", "1", "--db", db], "--import json")
    assert not (tmp_path / "r.sqlite").exists()


def test_import_of_a_missing_module_names_it(capsys, tmp_path):
    refused(capsys, ["tune", "--import", "no_such_module_xyz", "--budget", "1", "--db", str(tmp_path / "r.sqlite")],
            "--import no_such_module_xyz", "no module named 'no_such_module_xyz'")


def test_import_finds_a_module_in_the_current_folder(capsys, tmp_path, monkeypatch):
    (tmp_path / "my_rig_h19a.py").write_text(
        "import gymnasium as gym\n"
        "gym.register('my_rig_h19a/Rig-v0', entry_point='gbo_envs.envs.dc_motor:DCMotorEnv')\n")
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr("sys.path", [p for p in __import__("sys").path if p not in ("", str(tmp_path))])
    assert main(["tune", "--import", "my_rig_h19a", "--env", "my_rig_h19a/Rig-v0", "--tuner", "random",
                 "--budget", "1", "--db", str(tmp_path / "r.sqlite"), "--no-progress"]) == 0
    assert "1/1 plant experiments" in capsys.readouterr().out


# -- item 9: silently wrong or unclear ------------------------------------------------------------------
def test_unknown_env_in_a_study_is_refused_before_anything_is_written(capsys, tmp_path):
    spec = tmp_path / "s.toml"
    spec.write_text('[study]\nbatches = 1\nbudget = 2\n[env]\nid = "gbo_envs/Nope-v0"\n[[tuners]]\nname = "random"\n')
    out = tmp_path / "out"
    refused(capsys, ["bench", str(spec), "--out", str(out), "--quiet"], "[env] id 'gbo_envs/Nope-v0'", ENV)
    assert not out.exists()


def test_workers_below_one_are_refused(capsys, tmp_path):
    refused(capsys, ["bench", "smoke", "--workers", "0", "--out", str(tmp_path / "o")], "--workers", ">= 1")
    study = parse_study({"study": {"name": "w", "batches": 1, "budget": 2}, "env": {"id": ENV},
                         "tuners": [{"name": "random"}]})
    with pytest.raises(ValueError, match="workers must be an integer >= 1, got 0"):
        run_study(study, tmp_path / "o", workers=0, progress=False)
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("gains", [np.array([0.5 + 1e-3j, 1.2]), [0.5, 1.2 + 0j]])
def test_complex_gains_are_refused_not_truncated(gains):
    env = gym.make(ENV, noise=False)
    env.reset(seed=0)
    with pytest.raises(TypeError, match=r"gains \('Kp', 'Ki'\) must be real numbers"):
        env.step(gains)


def test_nan_output_noise_is_refused_not_taken_as_no_noise():
    with pytest.raises(ValueError, match="output_noise_std: must be a finite number >= 0"):
        gym.make(ENV, output_noise_std=math.nan)


@pytest.mark.parametrize("value", [0.0, -1.0, -0.0])
def test_normalizers_at_or_below_zero_are_refused_not_floored(value):
    with pytest.raises(ValueError, match="normalizers: every entry must be > 0"):
        gym.make(ENV, normalizers=[1.0, 1.0, value, 1.0])


# -- item 10: no raw tracebacks -------------------------------------------------------------------------
@pytest.mark.parametrize("flag", ["--tuner-kwargs", "--env-kwargs"])
@pytest.mark.parametrize("text", ["{bad", "[1, 2]", "3"])
def test_bad_json_kwargs_name_the_argument(capsys, tmp_path, flag, text):
    refused(capsys, ["tune", flag, text, "--budget", "1", "--db", str(tmp_path / "r.sqlite")], flag)


def test_kwargs_a_tuner_rejects_are_one_line(capsys, tmp_path):
    refused(capsys, ["tune", "--tuner", "random", "--tuner-kwargs", '{"no_such_option": 1}', "--budget", "1",
                     "--db", str(tmp_path / "r.sqlite"), "--no-progress"], "no_such_option")


def test_a_folder_as_the_csv_is_named(capsys, tmp_path):
    refused(capsys, ["twin", "compare", str(tmp_path)], str(tmp_path), "is a folder")
    with pytest.raises(ValueError, match="is a folder"):
        read_csv(tmp_path)


@pytest.mark.parametrize(("content", "what"), [(b"experiment,t,r,u,y\n1,0,1,0,\xe9\n", "not UTF-8 text"),
                                               (bytes(range(256)) * 8, "a binary file")])
def test_binary_and_latin1_files_name_the_file(capsys, tmp_path, content, what):
    path = tmp_path / "data.csv"
    path.write_bytes(content)
    refused(capsys, ["twin", "resid", str(path)], str(path), what)
    with pytest.raises(ValueError, match=what):
        read_csv(path)


def test_all_zero_data_says_there_is_no_excitation(capsys, tmp_path):
    t = np.arange(200) * 0.01
    lines = ["experiment,t,r,u,y"] + [f"{e},{v},0,0,0" for e in range(3) for v in t]
    path = tmp_path / "zero.csv"
    path.write_text("\n".join(lines) + "\n")
    refused(capsys, ["twin", "compare", str(path)], "no excitation")


def _workbench_csv(path, experiments) -> str:
    """A workbench CSV of ``{number: (t, r, u, y)}``."""
    lines = ["experiment,t,r,u,y"] + [f"{number},{t},{r},{u},{y}" for number, signals in experiments.items()
                                      for t, r, u, y in zip(*signals)]
    path.write_text("\n".join(lines) + "\n")
    return str(path)


@pytest.mark.parametrize("command", ["compare", "resid", "diagnose", "report"])
def test_data_errors_of_the_workbench_name_the_file(capsys, tmp_path, command):
    """Every data error of ``gbo twin`` names the file (the records' checks do not know it), and the experiment
    where one is at fault; an unknown ``--effects`` is an argument error, not the file's."""
    t = np.arange(200) * 0.01
    step, zero = np.r_[0.0, np.ones(199)], np.zeros(200)
    response, command_u = 1.0 - np.exp(-t), 0.5 + np.exp(-t)
    out = ["--out", str(tmp_path / "out")] if command in ("compare", "report") else []
    zeros = _workbench_csv(tmp_path / "zero.csv", {1: (t, zero, zero, zero), 2: (t, zero, zero, zero)})
    err = refused(capsys, ["twin", command, zeros, *out], "no excitation")
    assert err.startswith(f"gbo twin {command}: error: {zeros}: the input u is constant"), err
    flat = _workbench_csv(tmp_path / "flat.csv", {1: (t, step, command_u, zero), 2: (t, step, command_u, zero)})
    refused(capsys, ["twin", command, flat, *out], f"{flat}: the output y is constant")
    mixed = _workbench_csv(tmp_path / "mixed.csv", {3: (t, step, command_u, response),
                                                    4: (2 * t, step, command_u, response)})
    refused(capsys, ["twin", command, mixed, *out], f"{mixed}: every experiment must have the same sample time",
            "experiment 3 has 0.01 s, experiment 4 0.02 s")
    few = _workbench_csv(tmp_path / "few.csv", {1: (t[:4], step[:4], command_u[:4], response[:4])})
    refused(capsys, ["twin", command, few, *out], f"{few}: experiment 1 has 4 samples", "needs at least 7")
    err = refused(capsys, ["twin", command, mixed, "--effects", "saturation,friction", *out], "--effects",
                  "'friction'")
    assert str(mixed) not in err


def test_debug_shows_the_traceback(tmp_path):
    with pytest.raises(ValueError, match="is a folder"):
        main(["--debug", "twin", "compare", str(tmp_path)])
    with pytest.raises(ValueError, match="is a folder"):
        main(["twin", "compare", str(tmp_path), "--debug"])


# -- gbo bench suite ------------------------------------------------------------------------------------
@pytest.mark.parametrize("argv, words", [
    (["--suite", "large"], ("--suite", "'large'", "standard", "quick")),
    (["--seeds", "0"], ("--seeds", ">= 1")),
    (["--tuner-kwargs", "{bad"], ("--tuner-kwargs", "not valid JSON")),
    ([], ("give one --tuner NAME",)),
    (["--tuner", "no-such-tuner"], ("--tuner 'no-such-tuner'", "registered", "bo", "--import")),
    (["--tuner", "random", "--tuner-kwargs", '{"speed": 2}'], ("--tuner random / --tuner-kwargs", "speed")),
    (["--tuner", "random", "--batches", "2"], ("--batches", "only with a study")),
    (["--tuner", "random", "--force"], ("--force", "only with --rebuild-references")),
    (["--tuner", "random", "--plant", "DCMotor"], ("--plant", "['DCMotor']", "not plants of 'suite'",
                                                    "DCMotor-v0")),
    (["--rebuild-references", "--plant", "DCMotor"], ("--plant", "['DCMotor']", "not plants of 'suite'", "DCMotor-v0")),
    (["--rebuild-references", "--tuner", "nope"], ("--tuner", "['nope']", "not tuners of 'suite'", "guided-bo")),
    (["--rebuild-references", "--seeds", "3"], ("--seeds", "not with --rebuild-references")),
    (["--import", "no_such_module_xyz", "--tuner", "random"], ("--import no_such_module_xyz",)),
])
def test_bench_suite_refuses_bad_input_in_one_line(capsys, tmp_path, argv, words):
    out = tmp_path / "o"
    refused(capsys, ["bench", "suite", "--out", str(out), "--quiet", *argv], *words)
    assert not out.exists()


def test_suite_options_are_refused_with_a_study(capsys, tmp_path):
    refused(capsys, ["bench", "smoke", "--tuner", "random", "--seeds", "2", "--out", str(tmp_path / "o")],
            "--tuner, --seeds only with `gbo bench suite`")


@pytest.mark.parametrize("spec, words", [
    ({"plants": [{"id": ENV, "label": "a"}, {"id": ENV, "label": "a"}]}, ("plants: labels must be unique",)),
    ({"plants": [{"id": ENV, "phase": "later"}]}, ("plants[0] phase", "after-change")),
    ({"plants": [{"id": ENV}], "env": {"id": ENV}}, ("exactly one of [env]",)),
    ({"plants": [{"id": ENV}], "tuner_plants": ["DCMotor"]}, ("plants: ['DCMotor'] are not plant labels",
                                                              "DCMotor-v0")),
])
def test_study_plants_are_checked(spec, words):
    data = {"study": {"name": "p", "batches": 1}, "tuners": [{"name": "random"}], **spec}
    if "tuner_plants" in data:
        data["tuners"][0]["plants"] = data.pop("tuner_plants")
    with pytest.raises(StudySpecError) as info:
        parse_study(data)
    for word in words:
        assert word in str(info.value), (word, str(info.value))
