"""The sample-by-sample open-loop simulation of many rows at once equals each row simulated alone."""

from __future__ import annotations

import numpy as np

from agents.twin.open_loop import simulate_open_loop
from gbo_envs.physics import ContinuousPlant
from gbo_envs.physics.effects import build_effects

SPEED = ContinuousPlant(num=(9.544,), den=(1.0, 4.145, 4.199), delay=0.002)
POSITION = ContinuousPlant(num=(3.0,), den=(1.0, 2.5, 0.0), delay=0.0031, output="position")


def _rows():
    """Stepping rows: friction, backlash, cogging and stiction, two plants, two sample delays."""
    chains = [build_effects({"coulomb_friction": {"torque": t}}) for t in (1.0, 4.0)]
    chains += [build_effects({"backlash": {"width": 3.0}}), build_effects({"cogging": {"amplitude": 2.0}})]
    chains += [build_effects({"stiction": {"breakaway": 6.0}, "saturation": {"limit": 30.0}}),
               build_effects({"viscous_friction": {"coefficient": 0.2}})]
    plants = [SPEED, SPEED.__class__(num=SPEED.num, den=SPEED.den, delay=0.0051), SPEED, SPEED, SPEED, SPEED]
    rng = np.random.default_rng(3)
    u = np.cumsum(rng.normal(0.0, 2.0, (len(chains), 400)), axis=1)  # drifting commands, speed reversals
    return plants, chains, u, rng.normal(0.0, 5.0, len(chains)), rng.normal(0.0, 1.0, len(chains))


def test_stepping_rows_together_equal_each_row_alone():
    plants, chains, u, y0, bias = _rows()
    batch = simulate_open_loop(plants, u, 0.002, chains, y0=y0, bias=bias)
    for row, (plant, chain) in enumerate(zip(plants, chains)):
        alone = simulate_open_loop(plant, u[row], 0.002, build_effects(_spec(chain)), y0=y0[row], bias=bias[row])
        for name in ("y", "y_true", "v"):
            np.testing.assert_allclose(getattr(batch, name)[row], getattr(alone, name)[0], rtol=1e-12, atol=1e-9)


def test_position_rows_use_the_speed_for_their_friction():
    chains = [build_effects({"coulomb_friction": {"torque": t}}) for t in (0.5, 1.5)]
    u = np.sin(np.linspace(0.0, 12.0, 300))[None, :] * np.array([[2.0], [3.0]])
    batch = simulate_open_loop(POSITION, u, 0.002, chains, y0=np.array([1.0, -2.0]))
    for row, chain in enumerate(chains):
        alone = simulate_open_loop(POSITION, u[row], 0.002, build_effects(_spec(chain)), y0=batch.y[row, 0])
        np.testing.assert_allclose(batch.y[row], alone.y[0], rtol=1e-12, atol=1e-9)
    # friction against the speed: the larger torque leaves a smaller swing of the position
    assert np.ptp(batch.y[1] / 3.0) < np.ptp(batch.y[0] / 2.0)


def _spec(chain) -> dict:
    """The effect spec of a chain of blocks (fresh blocks: the batch's have run)."""
    return {block.name: {p: getattr(block, p) for p in block.param_names} for block in chain}


def test_candidate_fits_of_one_effect_merge_into_one_block_with_per_row_parameters():
    """The replays of a diagnosis stack many fits of one effect; a class whose block cannot hold per-row
    parameters falls back to one slice per row (a cogging block whose ``stochastic`` compared an array
    amplitude with 0 did, and a DCMotorRig-v0 guided-BO run took 3-4 s longer)."""
    from agents.twin.open_loop import _merged

    rng = np.random.default_rng(0)
    for spec in ({"cogging": {"amplitude": 2.0}}, {"cogging": {"amplitude": 5.0, "period": 0.5}},
                 {"coulomb_friction": {"torque": 3.0}}, {"saturation": {"limit": 40.0}}):
        name, params = next(iter(spec.items()))
        blocks = [build_effects({name: {**params, **{key: value * scale for key, value in params.items()}}})[0]
                  for scale in (1.0, 1.5, 2.0)]
        assert _merged(blocks, rng, column=False) is not None, name


def test_a_moving_start_of_a_plant_that_overflows_diverges_without_lapack(capfd):
    """A fit's trial point with a pole far in the right half-plane: e^{A dt} overflows. Its moving start went
    into ``lstsq`` with NaN ("On entry to DLASCL parameter number 4 had an illegal value", then LinAlgError in
    guided BO on a resonant plant); now that row's output is NaN (divergence) and the other row is untouched."""
    wild = ContinuousPlant(num=(9.5,), den=(1.0, -1e6, 4.2))
    good = ContinuousPlant(num=(9.544,), den=(1.0, 4.145, 4.199))
    u = np.ones((2, 50))
    with np.errstate(all="ignore"):
        res = simulate_open_loop([wild, good], u, 0.001, (), initial=np.array([[1.0], [2.0]]))
    alone = simulate_open_loop(good, u[:1], 0.001, (), initial=np.array([[2.0]]))
    assert np.isnan(res.y[0]).all() and np.array_equal(res.y[1], alone.y[0])
    assert "DLASCL" not in "".join(capfd.readouterr())


def test_plant_side_blocks_remembered_by_value_give_each_row_its_own_plant():
    """Rows whose plant-side blocks differ in any parameter, option or experiment get their own plant (the
    modified plants are remembered by the blocks' values): the same as each row simulated alone."""
    chains = [build_effects({"compliance": {"frequency": 40.0, "damping": d}}) for d in (0.05, 0.2)]
    chains += [build_effects({"compliance": {"frequency": 40.0, "damping": 0.05, "measured": "motor"}})]
    chains += [build_effects({"drift": {"rate": 0.1}})] * 2
    index = np.array([0, 0, 0, 1, 4])
    u = np.tile(np.where(np.arange(300) < 20, 0.0, 10.0), (len(chains), 1))
    for _ in range(2):  # the second pass reads the remembered plants
        batch = simulate_open_loop(SPEED, u, 0.002, chains, experiment_index=index)
        for row, chain in enumerate(chains):
            alone = simulate_open_loop(SPEED, u[row], 0.002, build_effects({b.name: b.params for b in chain}),
                                       experiment_index=int(index[row]))
            np.testing.assert_array_equal(batch.y[row], alone.y[0])
    assert len({round(float(batch.y[row, -1]), 9) for row in range(len(chains))}) == len(chains)


def test_a_plant_block_the_same_in_every_experiment_modifies_the_plant_once_for_all(monkeypatch):
    """A compliance (one plant in every experiment) is applied once for the rows of six experiments; a drift
    (a plant per experiment) once per experiment. Each row is as simulated alone."""
    from agents.twin import open_loop
    from gbo_envs.physics.compliance import Compliance
    from gbo_envs.physics.plant_effects import Drift

    calls = {Compliance: 0, Drift: 0}
    for cls in calls:
        def counted(self, plant, experiment_index, _original=cls.modify_plant, _cls=cls):
            calls[_cls] += 1
            return _original(self, plant, experiment_index)
        monkeypatch.setattr(cls, "modify_plant", counted)
    open_loop._modified_by_value.cache_clear()
    index = np.arange(6)
    u = np.tile(np.where(np.arange(300) < 20, 0.0, 10.0), (6, 1))
    for effects in ({"compliance": {"frequency": 40.0, "damping": 0.1}}, {"drift": {"rate": 0.1}}):
        batch = simulate_open_loop(SPEED, u, 0.002, build_effects(effects), experiment_index=index)
        for row in range(6):
            alone = simulate_open_loop(SPEED, u[row], 0.002, build_effects(effects), experiment_index=int(index[row]))
            np.testing.assert_array_equal(batch.y[row], alone.y[0])
    assert calls == {Compliance: 1, Drift: 6}


def test_the_row_order_does_not_depend_on_where_the_blocks_live_in_memory():
    """Rows of one block class are grouped by their blocks in the order the blocks first come, not by the blocks'
    addresses, which can change from run to run."""
    from agents.twin.open_loop import _sorted_rows
    from gbo_envs.physics.effects import build_effect

    a, b = (build_effect("saturation", {"limit": limit}) for limit in (10.0, 20.0))
    for first, second in ((a, b), (b, a)):  # one of the two puts the higher address first
        assert _sorted_rows([(first,), (second,), (first,)]).tolist() == [0, 2, 1]
