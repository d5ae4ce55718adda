"""Pushes and the elastic band as users drive them: `python -m zensim sim --clock lockstep --band`, plain zenoh
clients on loopback sending JSON to ctl/push and ctl/band.

Lockstep makes the checks exact: a push of 20 ms acts on exactly the 10 steps of one advance, and the states
before and after it are the instants the advance replies with. What is measured is the whole robot's linear
momentum, worked out from those states alone (the base pose and twist, every joint's q and dq, put into
MuJoCo's kinematics of the same robot here): the pelvis is pushed, but the limbs hang on joints, so the pelvis
alone never carries the whole impulse. The robot hangs limp on the band, so no contact acts; gravity and the
band's pull (known from the states: its anchor, length and rates are in the reply) are the only other forces.
"""

from __future__ import annotations

import json

import mujoco
import numpy as np
import pytest
import zenoh

from support import Latest, ctl
from test_lockstep_process import advance
from test_sim_process import robot_info, wait_alive
from zensim.robots import robot_files
from zensim.robots.builder import build
from zensim.schemas import Keys, SimStatus

DT = 0.002


class Kinematics:
    """The G1 as the sim builds it, to turn published states into positions and momentum."""

    def __init__(self) -> None:
        self.robot = build(robot_files("g1"), "floating")
        self.model = self.robot.model
        self.data = mujoco.MjData(self.model)
        self.mass = float(self.model.body_subtreemass[self.robot.base_body_id])
        self.feet = [self.model.body(name).id for name in ("left_ankle_roll_link", "right_ankle_roll_link")]

    def load(self, reply: dict) -> None:
        robot, data = self.robot, self.data
        odom, joints = reply["odom"], reply["joints"]
        data.qpos[robot.free_qpos_adr:robot.free_qpos_adr + 7] = [*odom["pos"], *odom["quat_wxyz"]]
        data.qvel[robot.free_dof_adr:robot.free_dof_adr + 6] = [*odom["lin_vel_world"], *odom["ang_vel_body"]]
        data.qpos[robot.qpos_adr] = joints["q"]
        data.qvel[robot.dof_adr] = joints["dq"]
        mujoco.mj_forward(self.model, data)
        mujoco.mj_subtreeVel(self.model, data)

    def momentum(self, reply: dict) -> np.ndarray:
        """The whole robot's linear momentum at a state, kg m/s, world frame."""
        self.load(reply)
        return self.mass * self.data.subtree_linvel[self.robot.base_body_id].copy()

    def lowest_foot_z(self, reply: dict) -> float:
        """Height of the lower ankle link's origin (the sole is 3-4 cm below it), m."""
        self.load(reply)
        return float(min(self.data.xpos[b][2] for b in self.feet))


def band_pull(band: dict, odom: dict) -> np.ndarray:
    """The band's force on the base at a state, as services/sim/disturbances.py works it out."""
    delta = np.array(band["anchor"]) - np.array(odom["pos"])
    distance = float(np.linalg.norm(delta))
    direction = delta / distance
    pull = band["stiffness_n_m"] * (distance - band["length_m"]) - band["damping_n_s_m"] * float(
        np.array(odom["lin_vel_world"]) @ direction)
    return max(pull, 0.0) * direction if distance > band["length_m"] else np.zeros(3)


def limp(n: int) -> dict:
    """Zero gains on every joint: the robot hangs like a rag doll."""
    return {"q": [0.0] * n, "kp": [0.0] * n, "kd": [0.0] * n}


@pytest.fixture(scope="module")
def kinematics() -> Kinematics:
    return Kinematics()


class TestPushAndBand:
    def test_a_push_changes_the_momentum_by_its_impulse_and_the_band_holds_then_drops(
            self, start_service, zsession, robot_id, kinematics) -> None:
        keys = Keys(robot_id)
        status = Latest(zsession, keys.sim_status, SimStatus)
        start_service("sim", "--clock", "lockstep", "--band", "true")
        wait_alive(zsession, keys)
        n = len(robot_info(zsession, keys)["joint_names"])
        band = ctl(zsession, keys.ctl("band"))["band"]  # an empty request: the state, nothing changed
        assert band["on"] is True and band["stiffness_n_m"] == 200.0 and band["damping_n_s_m"] == 100.0
        # 3 s limp on the band: the robot hangs with its feet well off the floor.
        for _ in range(150):
            state = advance(zsession, keys, limp(n))
        assert kinematics.lowest_foot_z(state) > 0.3, "the band holds the feet off the floor"
        assert state["odom"]["pos"][2] > 1.0
        seen = status.wait(lambda s: s.band is not None and s.steps >= 1500, what="the band in state/sim")
        assert seen.band.on and seen.band.force_n[2] > 0.8 * kinematics.mass * 9.8, "it carries the weight"

        # A 200 N push along (1, 1, 0.5) for 20 ms: one advance of 10 steps.
        pushed = ctl(zsession, keys.ctl("push"), {"direction": [1, 1, 0.5], "magnitude_n": 200, "duration_s": 0.02})
        assert pushed["ok"] is True, pushed
        push = pushed["push"]
        assert push["body"] == "pelvis" and push["duration_s"] == pytest.approx(0.02, abs=1e-12)
        assert push["start_s"] == pytest.approx(state["sim_time_s"], abs=1e-12)
        assert np.linalg.norm(push["force_n"]) == pytest.approx(200.0)
        after = advance(zsession, keys, limp(n))
        change = kinematics.momentum(after) - kinematics.momentum(state)
        span_s = after["sim_time_s"] - state["sim_time_s"]
        others = ((band_pull(band, state["odom"]) + band_pull(band, after["odom"])) / 2
                  + kinematics.mass * np.array([0.0, 0.0, -9.81])) * span_s
        expected = np.array(push["impulse_n_s"]) + others
        error = np.linalg.norm(change - expected) / np.linalg.norm(push["impulse_n_s"])
        assert error < 0.02, f"momentum change {change}, expected {expected} ({error:.2%} off)"
        # Without the push the same check is off by the whole impulse: the check can fail.
        assert np.linalg.norm(change - others) / np.linalg.norm(push["impulse_n_s"]) > 0.9
        shown = status.wait(lambda s: s.pushes_applied == 1, what="the push in state/sim")
        assert shown.last_push is not None and shown.last_push.body == "pelvis" and shown.pushes == ()

        # Lowered 0.1 m, then let go: it drops to the floor.
        lowered = ctl(zsession, keys.ctl("band"), {"verb": "lower"})
        assert lowered["ok"] and lowered["band"]["length_m"] == pytest.approx(0.1)
        released = ctl(zsession, keys.ctl("band"), {"verb": "off"})
        assert released["ok"] and released["band"]["on"] is False
        for _ in range(50):
            state = advance(zsession, keys, limp(n))
        assert state["odom"]["pos"][2] < 0.6, "released, the robot fell"
        status.wait(lambda s: s.band is None and s.steps >= 2010, what="the band gone from state/sim")

    def test_bad_push_and_band_requests_are_refused_whole_and_counted(self, start_service, zsession, robot_id) -> None:
        keys = Keys(robot_id)
        status = Latest(zsession, keys.sim_status, SimStatus)
        start_service("sim", "--paused", "true")
        wait_alive(zsession, keys)
        good = {"direction": [1, 0, 0], "magnitude_n": 50, "duration_s": 0.1}
        bad_pushes: list[tuple[dict, str]] = [
            ({**good, "body": "tail_link"}, "tail_link"),
            ({**good, "magnitude_n": 1e9}, "weight"),
            ({**good, "magnitude_n": float("inf")}, ""),  # JSON has no inf or NaN: the text is refused
            ({**good, "direction": [float("nan"), 0, 0]}, ""),
            ({**good, "direction": [0, 0, 0]}, "zero"),
            ({**good, "direction": [1, 0]}, "direction"),
            ({**good, "duration_s": 0}, "duration_s"),
            ({**good, "duration_s": 60}, "duration_s"),
            ({**good, "force": 3}, "force"),
            ({"magnitude_n": 50, "duration_s": 0.1}, "direction"),
        ]
        for payload, why in bad_pushes:
            reply = ctl(zsession, keys.ctl("push"), payload)
            assert reply["ok"] is False and why in reply["error"], (payload, reply)
        bad_bands: list[tuple[dict, str]] = [({"verb": "sideways"}, "verb"), ({"length_m": -1}, "length_m"), ({"length_m": 99}, "length_m"),
                     ({"verb": "lower", "length_m": 1.0}, "not both"), ({"verb": "raise"}, "shortest")]
        for payload, why in bad_bands:
            reply = ctl(zsession, keys.ctl("band"), payload)
            assert reply["ok"] is False and why in reply["error"], (payload, reply)
        refused = len(bad_pushes) + len(bad_bands)
        seen = status.wait(lambda s: s.rejected_requests >= refused, what="the refusals counted")
        assert seen.rejected_requests == refused and seen.pushes_applied == 0 and seen.last_push is None
        assert seen.band is None and seen.pushes == ()
        # A wildcard query reaches every ctl verb: it pushes nothing.
        list(zsession.get(f"{keys.root}/ctl/*", payload=json.dumps(good), timeout=3.0))
        # The same requests, sane, are carried out: the refusals were about what was wrong.
        assert ctl(zsession, keys.ctl("push"), {**good, "body": "left_wrist_yaw_link"})["ok"] is True
        assert ctl(zsession, keys.ctl("band"), {"verb": "on", "length_m": 0.5})["band"]["on"] is True
        seen = status.wait(lambda s: s.pushes_applied == 1 and s.band is not None, what="the good requests")
        assert seen.pushes[0].body == "left_wrist_yaw_link" and seen.band.length_m == 0.5
        assert seen.pushes[0].remaining_s == pytest.approx(0.1), "paused: the push waits for time to move"

    def test_the_band_is_refused_in_the_fixed_mode_and_a_reset_ends_a_push(self, start_service, zsession,
                                                                          robot_id) -> None:
        keys = Keys(robot_id)
        start_service("sim", "--mode", "fixed", "--paused", "true")
        wait_alive(zsession, keys)
        reply = ctl(zsession, keys.ctl("band"), {"verb": "on"})
        assert reply["ok"] is False and "fixed" in reply["error"]
        pushed = ctl(zsession, keys.ctl("push"), {"direction": [0, 0, 1], "magnitude_n": 20, "duration_s": 5,
                                                   "body": "left_elbow_link"})
        assert pushed["ok"] is True
        status = Latest(zsession, keys.sim_status, SimStatus)
        assert status.wait(lambda s: len(s.pushes) == 1, what="the push acting").pushes[0].remaining_s == 5.0
        ctl(zsession, keys.ctl("step"), {"n": 100})
        status.wait(lambda s: s.pushes and s.pushes[0].remaining_s == pytest.approx(4.8), what="0.2 s of it gone")
        ctl(zsession, keys.ctl("reset"))
        seen = status.wait(lambda s: s.resets >= 1 and s.pushes == (), what="the push ended by the reset")
        assert seen.pushes_applied == 1
