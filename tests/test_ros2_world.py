"""One `zensim ros2 --world` serves every robot of a world (`zensim sim --world`), each as a ROS 2 user expects
it: `/<robot>/joint_states`, `/<robot>/odom`, ... with frames `<robot>/pelvis`, one node per robot, one
shared /clock. Seen by real rclpy (the Kilted wheels, Fast DDS, tests/ros2_node.py) over DDS, and on
rmw_zenoh's liveliness tokens; a forward command in one robot's namespace moves that robot only."""

from __future__ import annotations

import os
import re
from pathlib import Path

import ros2_client  # real rclpy (tests/ros2_node.py), in its own process and venv
from support import Latest, ctl, wait_for
from zensim.schemas import JointState, Keys, Odometry, Ros2Status

DOMAIN = 20 + (os.getpid() + 57) % 200
"""A DDS and ROS domain of this run's own (other test runs on the machine use DDS too)."""
ELBOW = "left_elbow_joint"


def stamp_of(message: dict) -> float:
    stamp = message["header"]["stamp"] if "header" in message else message["clock"]
    return stamp["sec"] + stamp["nanosec"] * 1e-9


def test_one_ros2_face_serves_every_robot_of_a_world_in_its_namespace(start_service, zsession, robot_id,
                                                                      tmp_path: Path):
    world, a, b = f"{robot_id}-w", f"{robot_id}-a", f"{robot_id}-b"
    ns = {a: f"/{robot_id}_a", b: f"/{robot_id}_b"}
    (tmp_path / "world.toml").write_text(f'id = "{world}"\n[[robots]]\nid = "{a}"\n'
                                         f'[[robots]]\nid = "{b}"\nxy = [2.0, 0.0]\n')
    start_service("sim", "--world", str(tmp_path / "world.toml"), "--mode", "fixed")
    start_service("bridge", env={"ZENSIM_ROBOT_ID": b})  # only b is driven
    face = start_service("ros2", "--world", world, "--domain-id", str(DOMAIN), "--status-rate-hz", "10")
    wait_for(lambda: face.log().count("ros2 face up") == 2 or not face.alive(), 90, "a face for each robot")
    assert face.alive(), face.log()
    joints = {r: Latest(zsession, Keys(r).joints, JointState) for r in (a, b)}
    odoms = {r: Latest(zsession, Keys(r).odom, Odometry) for r in (a, b)}
    for latest in (*joints.values(), *odoms.values()):
        latest.keep_history = True
    lines = ros2_client.run_json("echo", "10", *ns.values(), domain=DOMAIN, timeout_s=120)
    by_topic: dict[str, list[dict]] = {}
    for line in lines:
        by_topic.setdefault(line.get("topic", ""), []).append(line)
    assert by_topic.get("/clock"), f"no /clock reached rclpy; got {sorted(by_topic)}"
    for robot, space in ns.items():
        keys = Keys(robot)
        for topic in ("joint_states", "odom", "imu", "robot_description"):
            assert by_topic.get(f"{space}/{topic}"), f"no {space}/{topic} reached rclpy; got {sorted(by_topic)}"
        urdf = next(iter(zsession.get(keys.urdf, timeout=10))).ok.payload.to_bytes().decode()
        assert by_topic[f"{space}/robot_description"][0]["data"] == urdf
        names = list(ctl(zsession, keys.robot_info)["joint_names"])
        assert all(js["name"] == names for js in by_topic[f"{space}/joint_states"])
        # Each namespace carries its own robot's ground truth: b stands 2 m from a.
        truth = {round(o.sim_time_s, 6): o.pos for o in odoms[robot].history}
        matched = [o for o in by_topic[f"{space}/odom"] if round(stamp_of(o), 6) in truth]
        assert matched, f"no {space}/odom at a sim time of {robot}'s state/odom"
        for o in matched:
            assert o["header"]["frame_id"] == "world" and o["child_frame_id"] == f"{space[1:]}/pelvis"
            p = o["pose"]["pose"]["position"]
            assert [p["x"], p["y"], p["z"]] == list(truth[round(stamp_of(o), 6)])
        assert by_topic[f"{space}/imu"][-1]["header"]["frame_id"] == f"{space[1:]}/imu_in_pelvis"
    # One rmw_zenoh node per robot, in its namespace, each with an id of its own.
    tokens = [str(r.ok.key_expr) for r in zsession.liveliness().get(f"@ros2_lv/{DOMAIN}/**", timeout=5)
              if r.ok is not None]
    nodes = {m[3]: (m[1], m[2]) for t in tokens
             if (m := re.match(rf"^@ros2_lv/{DOMAIN}/[0-9a-f]+/(\d+)/\1/NN/%/%([^/]+)/(\w+)$", t))}
    assert {name: space for name, (_, space) in nodes.items()} == {f"zensim_{s[1:]}": s[1:] for s in ns.values()}, tokens
    assert len({nid for nid, _ in nodes.values()}) == 2, f"two nodes with one id: {tokens}"
    # A forward command in b's namespace moves b's elbow, and a's face forwards nothing.
    info = ctl(zsession, Keys(b).robot_info)
    state = joints[b].wait(timeout_s=10, what=f"{b}'s state/joints")
    q = [min(max(v, lo), hi) for v, lo, hi in zip(state.q, info["q_min"], info["q_max"])]
    elbow = list(info["joint_names"]).index(ELBOW)
    q[elbow] = 0.9
    sent = ros2_client.run_json("forward", "4", ",".join(repr(v) for v in q), f"{ns[b]}/forward_position_controller/commands",
                                domain=DOMAIN, timeout_s=90)[-1]
    assert sent["matched"] >= 1, f"zensim ros2 subscribes {ns[b]}/forward_position_controller/commands over DDS"
    joints[b].wait(lambda s: abs(s.q[elbow] - 0.9) < 0.05, 30, f"{b}'s elbow to reach 0.9")
    assert abs(joints[a].wait(timeout_s=10).q[elbow] - 0.9) > 0.3, f"{a}'s elbow stayed"
    status_a = Latest(zsession, Keys(a).ros2_status, Ros2Status).wait(timeout_s=10, what=f"{a}'s state/ros2")
    status_b = Latest(zsession, Keys(b).ros2_status, Ros2Status).wait(lambda s: s.commands_forwarded > 0, 10,
                                                                      f"{b}'s state/ros2")
    assert status_a.commands_forwarded == 0 and status_b.rejected == 0
    assert face.alive()
