"""Source fingerprints of tuners and plants (evaluation.fingerprint)."""

from __future__ import annotations

import agents
from evaluation import fingerprint
from evaluation.references import plant_hash


def test_a_tuners_modules_are_its_class_module_and_what_it_imports():
    random = fingerprint.tuner_modules("random")
    assert "agents.baselines" in random and "agents.base" in random and "agents.bo" not in random
    assert "gbo_envs.plotting" not in random and "agents.run_display" not in random  # they only draw
    bo = fingerprint.tuner_modules("bo")
    assert {"agents.bo", "agents.metric_surrogate", "agents.space"} <= set(bo)
    guided = fingerprint.tuner_modules("guided-bo")
    assert "agents.twin.prior" in guided  # imported inside a function: counted
    assert "gbo_envs.metrics" in guided  # `from gbo_envs import METRIC_NAMES`: the module that defines it
    assert "gbo_envs" not in guided and "agents" not in guided  # not the whole packages


def test_a_plants_modules_hold_its_env_and_the_ground_truth():
    rig = fingerprint.plant_modules("gbo_envs/DCMotorRig-v0")
    assert {"gbo_envs.envs.rigs", "gbo_envs.physics.encoder", "gbo_envs.ground_truth"} <= set(rig)
    assert "gbo_envs.envs.time_varying" not in rig
    assert fingerprint.truth_table_path("gbo_envs/DCMotorRig-v0") == "gbo_envs/data/ground_truth/DCMotorRig-v0.npz"
    assert fingerprint.truth_table_path("gbo_envs/DCMotor-v0") is None
    assert plant_hash("gbo_envs/DCMotorRig-v0") != plant_hash("gbo_envs/DCMotor-v0")


def test_editing_a_module_of_the_tuner_changes_its_hash(tmp_path, monkeypatch):
    package = tmp_path / "fp_pkg"
    package.mkdir()
    (package / "__init__.py").write_text("")
    (package / "helper.py").write_text("STEP = 0.1\n")
    (package / "tuner.py").write_text("from agents.baselines import RandomSearch\nfrom fp_pkg.helper import STEP\n\n\n"
                                      "class T(RandomSearch):\n    pass\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    from fp_pkg.tuner import T

    monkeypatch.setitem(agents.registry._REGISTRY, "fp-test", T)
    modules = fingerprint.tuner_modules("fp-test")
    assert {"fp_pkg.tuner", "fp_pkg.helper", "agents.baselines"} <= set(modules)
    before = fingerprint.source_hash(modules, fingerprint.SourceTree())
    (package / "helper.py").write_text("STEP = 0.2\n")
    assert fingerprint.source_hash(modules, fingerprint.SourceTree()) != before


def test_sources_at_a_commit_are_read_from_git():
    commit = fingerprint.git_commit()
    assert commit is None or len(commit.removesuffix("-dirty")) == 40
    if commit is not None:
        old = fingerprint.SourceTree("3345589")  # the commit the suite was built on
        assert old.read("agents.baselines")[1].startswith(b'"""')
        assert old.read("evaluation.suite") is None  # it did not exist yet
