"""Property tests of the bad-input policy (hypothesis): only ``ValueError``/``TypeError``, or exit 2 and one line.

Random bad values go to the public entry points: ``env.step`` (gains),
``build_effect`` and ``gym.make(effects=...)`` (effect parameters outside their
declared ranges, of the wrong type or non-finite), ``read_csv`` (random rows),
``agents.make`` (random keyword arguments) and the CLI's ``main`` (random bad
arguments). The API may accept a value or refuse it with ``ValueError`` or
``TypeError``; nothing else may come out. The CLI must refuse with exit status
2 and exactly one line on stderr, without a traceback. Every bad value drawn is
refused before any simulation runs, so the tests stay fast.
"""

from __future__ import annotations

import contextlib
import inspect
import io
import json
import math
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import agents
import gbo_envs  # noqa: F401  (registers the envs)
from agents.twin.csvio import REQUIRED_COLUMNS, read_csv
from evaluation.cli import main
from gbo_envs.physics import EFFECT_NAMES, EFFECTS, build_effect

ENV = "gbo_envs/DCMotor-v0"
FAST = settings(max_examples=30, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture])

#: Values no numeric parameter may take (any parameter also gets values outside its declared range).
junk = st.one_of(st.just(math.nan), st.complex_numbers(allow_nan=False, min_magnitude=1e-3).filter(
    lambda z: z.imag != 0), st.text(max_size=5), st.none(), st.booleans(), st.lists(st.floats(), max_size=2),
    st.dictionaries(st.text(max_size=3), st.integers(), max_size=2))
any_float = st.floats(allow_nan=True, allow_infinity=True)


def api_refuses_or_accepts(call) -> None:
    """``call()`` either returns or raises ``ValueError``/``TypeError`` with a message."""
    try:
        call()
    except (ValueError, TypeError) as exc:
        assert str(exc).strip(), f"{type(exc).__name__} without a message"


@pytest.fixture(scope="module")
def env():
    env = gym.make(ENV, noise=False)
    env.reset(seed=0)
    return env


in_range_complex = st.tuples(st.floats(0.2, 1.0), st.floats(0.9, 2.0), st.floats(1e-9, 1.0)).map(
    lambda v: np.array([complex(v[0], v[2]), v[1]]))  # in-range Kp, Ki; Kp complex
gains = st.one_of(
    in_range_complex,
    st.lists(any_float, min_size=0, max_size=4),
    st.lists(st.complex_numbers(allow_nan=True), min_size=2, max_size=2),
    st.lists(st.one_of(any_float, junk), min_size=2, max_size=2),
    junk,
)


@FAST
@given(action=gains)
def test_env_step_takes_gains_or_refuses_them(env, action):
    """Accepted gains are used as given (a complex gain is not truncated to its real part)."""
    try:
        info = env.step(action)[4]
    except (ValueError, TypeError) as exc:
        assert str(exc).strip()
        return
    assert np.array_equal(info["gains"], np.asarray(action)), (action, info["gains"])


def bad_parameter_value(parameter) -> st.SearchStrategy:
    """Values outside ``parameter``'s declared range, non-finite where it must be finite, or of a wrong type."""
    options = [junk]
    if np.isfinite(parameter.low):
        options.append(st.floats(max_value=parameter.low, exclude_max=True, allow_nan=False, allow_infinity=False))
    if np.isfinite(parameter.high):
        options.append(st.floats(min_value=parameter.high, exclude_min=True, allow_nan=False,
                                 allow_infinity=False))
    return st.one_of(options)


@st.composite
def bad_effect(draw):
    name = draw(st.sampled_from(EFFECT_NAMES))
    parameter = draw(st.sampled_from(EFFECTS[name].parameters))
    return name, {parameter.name: draw(bad_parameter_value(parameter))}


@FAST
@given(case=bad_effect())
def test_bad_effect_parameters_are_refused_with_value_or_type_error(case):
    name, params = case
    with pytest.raises((ValueError, TypeError)):
        build_effect(name, params)
    with pytest.raises((ValueError, TypeError)):
        gym.make(ENV, noise=False, effects={name: params})


@FAST
@given(params=st.dictionaries(st.text(max_size=8), st.one_of(any_float, junk), max_size=3),
       name=st.one_of(st.sampled_from(EFFECT_NAMES), st.text(max_size=8)))
def test_build_effect_with_random_parameters_refuses_or_accepts(name, params):
    api_refuses_or_accepts(lambda: build_effect(name, params))


cell = st.one_of(st.sampled_from(["0", "1", "-1", "0.5", "1e308", "-1e308", "nan", "inf", "", "abc", "0x10",
                                  '"1"', "é", "1;2", " 2 "]),
                 st.floats(allow_nan=True, allow_infinity=True).map(repr))


@st.composite
def csv_text(draw):
    columns = draw(st.permutations([*REQUIRED_COLUMNS, "gain0", "source", "cost"]))
    columns = columns[: draw(st.integers(min_value=3, max_value=len(columns)))]
    rows = draw(st.lists(st.lists(cell, min_size=len(columns) - 1, max_size=len(columns) + 1), max_size=12))
    return "\n".join([",".join(columns), *(",".join(row) for row in rows)]) + "\n"


@FAST
@given(text=csv_text())
def test_read_csv_returns_records_or_names_the_bad_row(tmp_path_factory, text):
    path = tmp_path_factory.mktemp("csv") / "data.csv"
    path.write_text(text, encoding="utf-8")
    try:
        read_csv(path)
    except ValueError as exc:
        assert str(path) in str(exc), str(exc)


@pytest.fixture(scope="module")
def tuner_parameters() -> dict[str, list[str]]:
    """Constructor parameter names of every registered tuner."""
    return {name: [p for p in inspect.signature(type(agents.make(name)).__init__).parameters
                   if p not in ("self", "args", "kwargs")] for name in agents.registered_names()}


@FAST
@given(data=st.data())
def test_agents_make_takes_kwargs_or_refuses_them(tuner_parameters, data):
    name = data.draw(st.sampled_from(sorted(tuner_parameters)))
    keys = data.draw(st.lists(st.one_of(st.sampled_from(tuner_parameters[name] or ["x"]),
                                        st.text(min_size=1, max_size=6)), max_size=3))
    kwargs = {key: data.draw(st.one_of(any_float, junk, st.integers())) for key in keys}
    api_refuses_or_accepts(lambda: agents.make(name, **kwargs))


def run_cli(argv: list[str]) -> tuple[int, str]:
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            status = main(argv)
        except SystemExit as exc:
            status = exc.code
    return status, err.getvalue()


bad_int = st.one_of(st.integers(max_value=0).map(str), st.sampled_from(["x", "1.5", "", "nan", "1e3", "--"]))


def not_a_json_object(text: str) -> bool:
    try:
        return not isinstance(json.loads(text), dict)
    except ValueError:
        return True


@st.composite
def bad_command(draw, csv_file, db):
    kind = draw(st.sampled_from(["folds", "workers", "budget", "kwargs", "env", "import", "poles", "csv"]))
    if kind == "folds":
        folds = draw(st.one_of(st.integers(max_value=1).map(str), st.integers(min_value=4).map(str), bad_int))
        return ["twin", "diagnose", csv_file, f"--folds={folds}"]
    if kind == "workers":
        return ["bench", "smoke", f"--workers={draw(bad_int)}"]
    if kind == "budget":
        return ["tune", f"--budget={draw(bad_int)}", "--db", db]
    if kind == "kwargs":
        flag = draw(st.sampled_from(["--env-kwargs", "--tuner-kwargs"]))
        return ["tune", "--budget", "1", "--db", db, f"{flag}={draw(st.text(max_size=12).filter(not_a_json_object))}"]
    if kind == "env":
        name = draw(st.text(alphabet="abcXYZ019/:-_.", min_size=1, max_size=12).filter(lambda s: s not in gym.registry))
        return ["tune", "--budget", "1", "--db", db, f"--env={name}"]
    if kind == "import":
        return ["tune", "--budget", "1", "--db", db, "--import", f"no_such_{draw(st.integers(0, 10**6))}"]
    if kind == "poles":
        return ["twin", "compare", csv_file, f"--poles={draw(bad_int)}"]
    return ["twin", "compare", draw(st.sampled_from([db + ".missing", str(Path(db).parent)]))]


@pytest.fixture(scope="module")
def cli_files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("cli")
    csv_file = folder / "three.csv"
    t = np.arange(50) * 0.01
    csv_file.write_text("experiment,t,r,u,y\n" + "".join(f"{e},{v:.2f},1,{np.sin(7 * v + e)},{np.cos(5 * v)}\n"
                                                        for e in range(3) for v in t))
    return str(csv_file), str(folder / "runs.sqlite")


@settings(max_examples=40, deadline=None, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_cli_refuses_bad_arguments_with_one_line(cli_files, data):
    argv = data.draw(bad_command(*cli_files))
    status, err = run_cli(argv)
    assert status == 2, (argv, status, err)
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, (argv, err)
