"""The one URDF reader (robots/description.py): what it makes of a URDF, and what it refuses."""

from __future__ import annotations

import math
import time
import warnings
from pathlib import Path

import numpy as np
import pytest
import yourdfpy

from zensim.robots import robot_files
from zensim.robots.description import RobotModelError, load_description, parse_urdf

with warnings.catch_warnings():  # meshcat imports pyzmq's deprecated ioloop; the tests turn warnings into errors
    warnings.simplefilter("ignore", DeprecationWarning)
    from zensim.viz.scene import build_drawing

ARM = """<robot name="arm">
  <material name="red"><color rgba="1 0 0 1"/></material>
  <link name="base"><visual><geometry><box size="1 2 3"/></geometry><material name="red"/></visual></link>
  <link name="upper">
    <visual><geometry><mesh filename="meshes/upper.stl"/></geometry><material name="own"><color rgba="0 0 1 0.5"/></material></visual>
    <collision><geometry><mesh filename="meshes/upper_collision.stl"/></geometry></collision>
  </link>
  <link name="lower"><visual><geometry><mesh filename="meshes/upper.stl" scale="2"/></geometry></visual></link>
  <link name="tip"/>
  <joint name="elbow" type="revolute"><parent link="upper"/><child link="lower"/>
    <origin xyz="0 0 0.5"/><axis xyz="0 2 0"/><limit lower="-1" upper="2" effort="0" velocity="3"/></joint>
  <joint name="shoulder" type="continuous"><parent link="base"/><child link="upper"/><limit effort="40"/></joint>
  <joint name="slide" type="prismatic"><parent link="lower"/><child link="tip"/></joint>
</robot>"""


def test_joints_limits_colours_and_meshes() -> None:
    d = parse_urdf(ARM)
    assert (d.name, d.root_link, d.links) == ("arm", "base", ("base", "upper", "lower", "tip"))
    elbow, shoulder, slide = d.actuated_joints  # document order: the canonical joint order
    assert (elbow.name, shoulder.name, slide.name) == ("elbow", "shoulder", "slide")
    assert (elbow.lower, elbow.upper, elbow.velocity) == (-1.0, 2.0, 3.0)
    assert elbow.effort == math.inf, "an effort of 0 means no limit"
    assert (shoulder.lower, shoulder.upper, shoulder.effort) == (-math.inf, math.inf, 40.0), "continuous"
    assert (slide.lower, slide.upper, slide.effort, slide.velocity) == (-math.inf, math.inf, math.inf, math.inf)
    assert elbow.axis.tolist() == [0.0, 1.0, 0.0] and elbow.origin[:3, 3].tolist() == [0.0, 0.0, 0.5]
    assert [j.name for j in d.joints_from_root()] == ["shoulder", "elbow", "slide"], "parents first"
    assert d.visuals["base"][0].rgba == (1.0, 0.0, 0.0, 1.0), "a named robot-level material"
    assert d.visuals["upper"][0].rgba == (0.0, 0.0, 1.0, 0.5), "an inline colour"
    assert d.visuals["lower"][0].scale == (2.0, 2.0, 2.0)
    assert d.mesh_filenames == ("meshes/upper.stl", "meshes/upper_collision.stl"), "visual and collision, once each"


def test_the_viewer_gives_a_joint_without_limits_one_turn() -> None:
    drawing = build_drawing(parse_urdf(ARM), {}, ghost=False)
    limits = {j["name"]: (j["lower"], j["upper"]) for j in drawing.meta["joints"]}
    assert limits == {"elbow": (-1.0, 2.0), "shoulder": (-math.pi, math.pi), "slide": (-math.pi, math.pi)}


@pytest.mark.parametrize("text, why", [
    ("<robot name='r'><link name='a'>", "not valid XML"),
    ("<model name='r'><link name='a'/></model>", "expected <robot>"),
    ("<robot name='r'/>", "no <link>"),
    ("<robot name='r'><link name='a'/><link name='b'/></robot>", "exactly one root link"),
    ("<robot name='r'><link name='a'/><joint name='j' type='fixed'><parent link='a'/><child link='x'/></joint></robot>",
     "does not exist"),
    ("<robot name='r'><link name='a'/><link name='b'/><joint type='fixed'><parent link='a'/><child link='b'/></joint></robot>",
     "name"),
    ("<robot name='r'><link name='a'><visual><geometry/></visual></link></robot>", "cannot be read"),
    ("<robot name='r'><link name='a'/><link name='b'/><joint name='j' type='revolute'><parent link='a'/>"
     "<child link='b'/><limit lower='abc'/></joint></robot>", "cannot be read"),
])
def test_a_broken_urdf_is_refused_with_a_reason(text: str, why: str) -> None:
    with pytest.raises(RobotModelError, match=why):
        parse_urdf(text)


def test_an_entity_bomb_is_refused_at_once() -> None:
    """The viewer parses URDF text from the network: a billion-laughs document must cost nothing."""
    entities = ['<!ENTITY e0 "lol">'] + [f'<!ENTITY e{i} "{f"&e{i - 1};" * 10}">' for i in range(1, 10)]
    bomb = f'<?xml version="1.0"?><!DOCTYPE robot [{"".join(entities)}]><robot name="&e9;"><link name="a"/></robot>'
    started = time.monotonic()
    with pytest.raises(RobotModelError, match="amplification|DTD"):
        parse_urdf(bomb)
    assert time.monotonic() - started < 1.0
    # A harmless entity is refused too: nothing may reach yourdfpy's parser, which expands entities.
    small = '<!DOCTYPE robot [<!ENTITY n "arm">]><robot name="&n;"><link name="a"/></robot>'
    with pytest.raises(RobotModelError, match="DTD"):
        parse_urdf(small)


def assert_reads_as_yourdfpy(path: Path) -> None:
    d = load_description(path)
    raw = yourdfpy.URDF.load(str(path), build_scene_graph=False, load_meshes=False)
    assert [j.name for j in d.actuated_joints] == raw.actuated_joint_names
    assert len(d.actuated_joints) == 29 and d.root_link == "pelvis"
    for joint in d.actuated_joints:
        limit = raw.joint_map[joint.name].limit
        assert (joint.lower, joint.upper, joint.effort, joint.velocity) == (
            limit.lower, limit.upper, limit.effort, limit.velocity)
        assert np.array_equal(joint.origin, raw.joint_map[joint.name].origin)


def test_the_bundled_g1_reads_as_yourdfpy_reads_it() -> None:
    assert_reads_as_yourdfpy(robot_files("g1").urdf)


def test_the_official_g1_reads_as_yourdfpy_reads_it(official_g1_dir: Path) -> None:
    assert_reads_as_yourdfpy(official_g1_dir / "g1_29dof.urdf")
    assert len(load_description(official_g1_dir / "g1_29dof.urdf").mesh_filenames) > 20
