"""Variants of a robot (services/sim/variants.py) in a World, no network: from nominal, never compounding,
one robot of a world alone, and a friction factor below the floor's that the contacts really use."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest

from test_world import make_world
from zensim.robots import robot_files
from zensim.schemas import Randomize, ResetRequest
from zensim.sim.physics import Limits
from zensim.sim.variants import uniforms
from zensim.sim.world import World

MODEL_FIELDS = ("body_mass", "body_inertia", "body_ipos", "geom_friction", "geom_priority", "jnt_actfrcrange",
                "body_subtreemass", "body_invweight0", "dof_invweight0", "actuator_acc0")
"""What a variant writes, and what MuJoCo derives from the masses (mj_setConst)."""


def model_arrays(model: mujoco.MjModel) -> dict[str, np.ndarray]:
    return {name: getattr(model, name).copy() for name in MODEL_FIELDS}


def alone() -> World:
    return World.alone("g1", robot_files("unitree_g1"), "floating", Limits(5000.0, 500.0), 0.5)


def test_variants_are_drawn_from_nominal_and_a_plain_reset_restores_it_bit_for_bit() -> None:
    world = alone()
    sim = world.robots[0]
    nominal = model_arrays(world.model)
    request = Randomize(seed=11, friction=(0.5, 1.5), mass=(0.7, 1.3), com_offset_m=0.03, motor_strength=(0.5, 1.0))
    sim.reset(ResetRequest(randomize=request))
    first = model_arrays(world.model)
    for _ in range(3):  # again and again: the same arrays, not a variant of the variant
        sim.reset(ResetRequest(randomize=request))
    assert all(np.array_equal(first[name], world.model.__getattribute__(name)) for name in MODEL_FIELDS)
    assert not np.array_equal(first["body_mass"], nominal["body_mass"])
    assert not np.array_equal(first["body_subtreemass"], nominal["body_subtreemass"]), "mj_setConst ran"
    sim.reset(ResetRequest(randomize=Randomize(seed=12, mass=(0.7, 1.3))))
    sim.reset()
    now = model_arrays(world.model)
    assert all(np.array_equal(nominal[name], now[name]) for name in MODEL_FIELDS), \
        [name for name in MODEL_FIELDS if not np.array_equal(nominal[name], now[name])]
    assert sim.variants.variant is None and sim.variants.strength is None


def test_the_draw_is_splitmix64_and_independent_per_factor() -> None:
    u = uniforms(7, 2, 1000)
    assert ((u >= 0) & (u < 1)).all() and 0.45 < u.mean() < 0.55
    assert np.array_equal(u, uniforms(7, 2, 1000)) and not np.array_equal(u, uniforms(8, 2, 1000))
    assert not np.array_equal(u[:29], uniforms(7, 4, 29))
    # Adding a range leaves the other factors of a seed as they were.
    world = alone()
    sim = world.robots[0]
    sim.reset(ResetRequest(randomize=Randomize(seed=3, mass=(0.8, 1.2))))
    masses = sim.variants.variant.mass_scale
    sim.reset(ResetRequest(randomize=Randomize(seed=3, mass=(0.8, 1.2), motor_strength=(0.5, 0.9))))
    assert sim.variants.variant.mass_scale == masses


def test_a_robot_of_a_world_varies_alone(tmp_path: Path) -> None:
    world = make_world(tmp_path, '[[robots]]\nid = "a"\n[[robots]]\nid = "b"\nxy = [2.0, 0.0]\n')
    a, b = world.sims["a"], world.sims["b"]
    b_bodies = np.arange(world.model.nbody)[b.robot.slot.bodies]
    before = world.model.body_mass[b_bodies].copy(), world.model.body_invweight0[b_bodies].copy()
    a.reset(ResetRequest(randomize=Randomize(seed=1, mass=(1.2, 1.4), friction=(0.3, 0.3))))
    assert a.variants.variant.mass_kg > 1.19 * a.variants.nominal_mass_kg
    assert np.array_equal(world.model.body_mass[b_bodies], before[0])
    assert np.array_equal(world.model.body_invweight0[b_bodies], before[1])
    assert b.variants.variant is None


def test_low_friction_makes_the_feet_slide() -> None:
    """A factor of 0.1 on the G1's foot friction (1.5 -> 0.15, below the floor's 1.0) is the friction the contacts
    use: a sideways pull on the feet of 0.2 of the weight, which a nominal robot stands against, drags them."""
    slid = {}
    for name, randomize in (("nominal", None), ("slippery", Randomize(seed=0, friction=(0.1, 0.1)))):
        world = alone()
        sim = world.robots[0]
        sim.watchdog_timeout_s = 1e6
        sim.reset(ResetRequest(randomize=randomize))
        world.step(500)  # land and settle
        feet = [sim.disturbances.bodies[link] for link in sim.robot.foot_links]
        x0 = world.data.xpos[feet, 0].copy()
        for _ in range(250):  # 0.5 s, each foot pulled along +x at a tenth of the weight
            world.data.xfrc_applied[feet, 0] = 0.1 * sim.disturbances.weight_n
            world.step(1)
        slid[name] = float((world.data.xpos[feet, 0] - x0).mean())
    assert slid["slippery"] > 0.05 and slid["slippery"] > 5 * abs(slid["nominal"]), slid


@pytest.mark.parametrize("strength", [0.5])
def test_motor_strength_scales_the_torque(strength: float) -> None:
    world = alone()
    sim = world.robots[0]
    sim.reset()
    world.step(1)
    nominal = world.data.qfrc_actuator[sim.robot.dof_adr].copy()
    sim.reset(ResetRequest(randomize=Randomize(seed=0, motor_strength=(strength, strength))))
    world.step(1)
    varied = world.data.qfrc_actuator[sim.robot.dof_adr]
    assert varied == pytest.approx(strength * nominal, rel=1e-9, abs=1e-9)
    limits = world.model.jnt_actfrcrange[world.model.dof_jntid[sim.robot.dof_adr]]
    assert limits[:, 1] == pytest.approx(strength * sim.robot.effort_limit)


def test_a_world_comes_back_to_nominal_bit_for_bit(tmp_path: Path) -> None:
    world = make_world(tmp_path, '[[robots]]\nid = "a"\n[[robots]]\nid = "b"\nxy = [2.0, 0.0]\n')
    nominal = model_arrays(world.model)
    stat = (world.model.stat.meaninertia, world.model.stat.meanmass)
    world.sims["a"].reset(ResetRequest(randomize=Randomize(seed=1, mass=(0.8, 1.2), com_offset_m=0.02)))
    world.sims["b"].reset(ResetRequest(randomize=Randomize(seed=2, mass=(0.8, 1.2))))
    world.sims["a"].reset()
    world.sims["b"].reset()
    now = model_arrays(world.model)
    assert [name for name in MODEL_FIELDS if not np.array_equal(nominal[name], now[name])] == []
    assert (world.model.stat.meaninertia, world.model.stat.meanmass) == stat


def test_a_weak_motor_fault_scales_the_variants_torque_limit_not_the_nominal_one() -> None:
    """ctl/faults' torque_scale and a variant's motor_strength both write the joint's torque limit: a reset that
    draws a variant under a fault gets the variant's limit times the fault's scale (and nominal again after)."""
    from zensim.schemas import FaultsRequest, JointFault

    world = alone()
    sim = world.robots[0]
    joint = sim.robot.joint_names.index("left_knee_joint")
    jnt = int(world.model.actuator_trnid[sim.robot.actuator_ids[joint], 0])
    nominal = world.model.jnt_actfrcrange[jnt].copy()
    sim.faults.request(FaultsRequest(verb="set", joints=(JointFault(joint="left_knee_joint", torque_scale=0.5),)))
    assert np.allclose(world.model.jnt_actfrcrange[jnt], 0.5 * nominal)
    sim.reset(ResetRequest(randomize=Randomize(seed=5, motor_strength=(0.6, 0.9))))
    strength = float(sim.variants.strength[joint])
    assert 0.6 <= strength <= 0.9
    assert np.allclose(world.model.jnt_actfrcrange[jnt], 0.5 * strength * nominal)
    sim.reset()
    assert np.allclose(world.model.jnt_actfrcrange[jnt], 0.5 * nominal)
