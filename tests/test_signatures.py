"""No public callable of gbo_envs, agents or evaluation takes more than 12 parameters (issue 53, point 6).

The public API is the ``__all__`` of every package and subpackage, and the env classes that ``gym.make``
reaches from :data:`gbo_envs.ENV_IDS`: its functions, its classes'
constructors and their public methods (static and class methods included), counted by
:func:`inspect.signature` without ``self``/``cls`` and without ``*args``/``**kwargs``. Settings
that belong together are grouped in keyword-only option objects instead
(:class:`agents.twin.DiagnosisRules`, :class:`agents.twin.IdentifyOptions` and its groups,
:class:`gbo_envs.CostSpec`, :class:`gbo_envs.StepExperiment`, ...).
"""

from __future__ import annotations

import importlib
import inspect
import pkgutil

import gymnasium as gym
import pytest

import gbo_envs

ROOTS = ("gbo_envs", "agents", "evaluation")
LIMIT = 12

def _packages():
    for root in ROOTS:
        package = importlib.import_module(root)
        yield package
        for info in pkgutil.walk_packages(package.__path__, f"{root}."):
            if info.ispkg:
                yield importlib.import_module(info.name)


def _ours(obj) -> bool:
    return (getattr(obj, "__module__", None) or "").split(".")[0] in ROOTS


def _count(fn, bound: bool) -> int:
    parameters = [p for p in inspect.signature(fn).parameters.values()
                  if p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)]
    return len(parameters) - (1 if bound and parameters else 0)


def _callables(obj):
    """``(qualified name, parameter count)`` of a public function, or of a class's constructor and public methods."""
    if not inspect.isclass(obj):
        yield f"{obj.__module__}.{obj.__qualname__}", _count(obj, bound=False)
        return
    name = f"{obj.__module__}.{obj.__qualname__}"
    if not issubclass(obj, BaseException) or "__init__" in vars(obj):  # an exception may keep the builtin's
        yield name, _count(obj, bound=False)  # the constructor, as a caller sees it (no self)
    for attr in dir(obj):
        if attr.startswith("_"):
            continue
        member = inspect.getattr_static(obj, attr)
        if isinstance(member, staticmethod):
            fn, bound = member.__func__, False
        elif isinstance(member, classmethod):
            fn, bound = member.__func__, True
        elif inspect.isfunction(member):
            fn, bound = member, True
        else:
            continue  # properties, attributes, nested classes
        if _ours(fn):
            yield f"{name}.{attr}", _count(fn, bound)


def public_callables() -> dict[str, int]:
    """Every public callable of the three packages and its parameter count."""
    found = {}
    for package in _packages():
        for symbol in getattr(package, "__all__", ()):
            obj = getattr(package, symbol)
            if (inspect.isclass(obj) or inspect.isfunction(obj)) and _ours(obj):
                found.update(_callables(obj))
    for env_id in gbo_envs.ENV_IDS:  # the env classes behind gym.make, whether or not a package exports them
        module, _, name = gym.spec(env_id).entry_point.partition(":")
        found.update(_callables(getattr(importlib.import_module(module), name)))
    return found


CALLABLES = public_callables()


def test_the_walk_reaches_the_public_api():
    """The walk finds the known long-signature candidates, so a broken walk cannot pass the rule below."""
    for name in ("agents.twin.diagnose.diagnose", "agents.twin.linear_twin.LinearTwin",
                 "gbo_envs.envs.external.ExternalPlantEnv", "gbo_envs.envs.base.ControllerTuningEnv",
                 "gbo_envs.envs.base.ControllerTuningEnv.step", "agents.bo.BayesianOptimization",
                 "gbo_envs.envs.linear_motor_cascade.LinearMotorCascadeEnv", "gbo_envs.envs.rigs.DCMotorRigEnv"):
        assert name in CALLABLES, name
    assert len(CALLABLES) > 200


@pytest.mark.parametrize("name", sorted(CALLABLES))
def test_at_most_twelve_parameters(name):
    assert CALLABLES[name] <= LIMIT, f"{name} takes {CALLABLES[name]} parameters (at most {LIMIT}): group its " \
                                     "settings in keyword-only option objects"


@pytest.mark.parametrize(("path", "positional"), [
    ("agents.twin.diagnose.diagnose", ("data", "effects")),
    ("agents.twin.linear_twin.LinearTwin", ("options",)),
    ("gbo_envs.envs.external.ExternalPlantEnv", ("run_experiment", "gain_bounds")),
    ("gbo_envs.envs.base.ControllerTuningEnv", ("loop", "gain_low", "gain_high")),
    ("gbo_envs.envs.dc_motor.DCMotorEnv", ()),
    ("gbo_envs.envs.linear_motor.LinearMotorEnv", ()),
])
def test_settings_after_the_first_arguments_are_keyword_only(path, positional):
    module, _, name = path.rpartition(".")
    parameters = inspect.signature(getattr(importlib.import_module(module), name)).parameters.values()
    assert tuple(p.name for p in parameters if p.kind is p.POSITIONAL_OR_KEYWORD) == positional


@pytest.mark.parametrize(("env_id", "flat", "grouped"), [
    ("gbo_envs/DCMotor-v0", {"gain": 10.0, "output_noise_std": 0.5},
     {"plant": gbo_envs.DCMotorPlant(gain=10.0), "measurement_noise": gbo_envs.MeasurementNoise(output_noise_std=0.5)}),
    ("gbo_envs/LinearMotor-v0", {"current_limit": None, "damping": 0.5},
     {"drive": gbo_envs.LinearMotorDrive(current_limit=None), "plant": gbo_envs.LinearMotorPlant(damping=0.5)}),
    ("gbo_envs/LinearMotorCascade-v0", {"anti_windup": "none"}, {"drive": gbo_envs.CascadeDrive(anti_windup="none")}),
])
def test_an_option_field_given_by_name_makes_the_same_env(env_id, flat, grouped):
    """The grouped settings keep their gym.make names: both spellings give the same plant and cost."""
    envs = [gym.make(env_id, noise=False, **kwargs) for kwargs in (flat, grouped)]
    for env in envs:
        env.reset(seed=0)
    box = envs[0].unwrapped.action_space
    costs = [env.step((box.low + box.high) / 2)[4]["cost"] for env in envs]
    assert costs[0] == costs[1] and envs[0].unwrapped.plant_params == envs[1].unwrapped.plant_params


def test_an_unknown_env_setting_is_refused_naming_the_option_fields():
    with pytest.raises(TypeError, match=r"\['gian'\].*plant=DCMotorPlant.*'gain'"):
        gym.make("gbo_envs/DCMotor-v0", gian=10.0)
    with pytest.raises(ValueError, match="current_limit: must be > 0 or None"):
        gbo_envs.LinearMotorDrive(current_limit=-1.0)
    with pytest.raises(TypeError, match="drive: the cascade's drive is a CascadeDrive"):
        gym.make("gbo_envs/LinearMotorCascade-v0", drive=gbo_envs.LinearMotorDrive())
