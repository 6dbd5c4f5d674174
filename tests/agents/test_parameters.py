"""agents.parameters: the one validation system of the tuners, the twin estimators and the option objects."""

from __future__ import annotations

import ast
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np
import pytest

from agents.parameters import ArrayLike, Boolean, InstanceOf, Interval, Options, check_fields

ROOT = Path(__file__).resolve().parents[2]


def test_boolean_instance_and_array_forms():
    assert Boolean().admits(True) and Boolean().admits(np.False_) and not Boolean().admits(1)
    assert type(Boolean().convert(np.True_)) is bool and str(Boolean()) == "a bool"
    form = InstanceOf((list, dict))
    assert form.admits([]) and form.admits({}) and not form.admits("ab")
    assert str(form) == "an instance of list or dict"
    assert ArrayLike().admits([1.0]) and ArrayLike().admits(np.zeros((2, 2))) and ArrayLike().admits((1, 2))
    assert not ArrayLike().admits("ab") and not ArrayLike().admits(1.0) and not ArrayLike().admits(np.float64(1))


def test_finite_interval_refuses_infinity_where_a_bound_is_open():
    finite = Interval(float, 0.0, None, closed="left", finite=True)
    assert finite.admits(0.0) and finite.admits(1e300) and not finite.admits(np.inf)
    assert str(finite) == "a finite float in [0, inf)"
    assert Interval(float, 0.0, None).admits(np.inf)  # unbounded and not finite: inf is a value


@dataclass(frozen=True)
class _Settings:
    n: int = 1
    rate: float = 0.5
    mode: str = "a"

    _parameter_constraints: ClassVar[dict[str, list]] = {
        "n": [Interval(int, 1, None)], "rate": [Interval(float, 0.0, 1.0)], "mode": [Options(("a", "b"))]}

    def __post_init__(self) -> None:
        check_fields(self)


def test_check_fields_converts_and_names_the_field():
    settings = _Settings(n=np.int64(3), rate=1)
    assert type(settings.n) is int and type(settings.rate) is float and settings == _Settings(n=3, rate=1.0)
    with pytest.raises(ValueError, match=r"rate: must be a float in \[0, 1\], got 2"):
        _Settings(rate=2)
    with pytest.raises(ValueError, match=r"mode: must be one of \('a', 'b'\), got 'c'"):
        _Settings(mode="c")


def test_no_module_uses_scikit_learns_private_validation():
    """One validation system: the tuners' and the twins' parameters are both checked by agents.parameters."""
    users = []
    for path in sorted((ROOT / "agents").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("sklearn.utils._param_validation"):
                users.append(str(path.relative_to(ROOT)))
    assert users == []


def test_identify_linear_names_a_bad_setting_and_converts_the_good_ones():
    from agents.twin.identify import checked_options

    options = checked_options({"n_poles": np.int64(3), "delay": 0, "start": None, "rest_levels": None}, "f")
    assert type(options.n_poles) is int and type(options.delay_search.delay) is float
    assert options.delay_search.delay == 0.0
    with pytest.raises(ValueError, match=r"max_delay: must be None or a finite float in \[0, inf\), got -1"):
        checked_options({"max_delay": -1}, "f")
    with pytest.raises(ValueError, match=r"start: must be None or an instance of tuple, got \[1\]"):
        checked_options({"start": [1]}, "f")
    with pytest.raises(TypeError, match=r"f\(\) got unexpected keyword argument\(s\) \['n_pole'\]"):
        checked_options({"n_pole": 2}, "f")
