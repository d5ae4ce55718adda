"""`zensim bridge` as users run it: real processes (router, sim, bridge), real Zenoh on loopback.

Inputs are written from a plain zenoh session, JSON built with the json module, as a
client with no zensim installed would.
"""

from __future__ import annotations

import json
import math
import signal
import threading
import time
from collections.abc import Callable
from typing import Generic, TypeVar

import msgspec
import pytest
import zenoh

from support import TWO_JOINT_ARM, Service, wait_for
from zensim.common.wire import payload_of
from zensim.schemas import (
    BridgeReport,
    Codec,
    CtlReply,
    JointState,
    JointTargets,
    Keys,
    Message,
    MotorCommand,
    Odometry,
    RobotInfo,
    SimStatus,
)

M = TypeVar("M", bound=Message)

ARM = ("left_shoulder_pitch_joint", "left_elbow_joint")
ELBOW = "left_elbow_joint"
STANDING_Z_M = 0.6
"""Pelvis height above which the floating G1 counts as up (it stands at ~0.73-0.79 m)."""


class Collector(Generic[M]):
    """Every message of one type seen on a key, with its arrival time."""

    def __init__(self, session: zenoh.Session, key: str, message_type: type[M]) -> None:
        self._codec = Codec(message_type)
        self._lock = threading.Lock()
        self._items: list[tuple[float, M]] = []
        self._sub = session.declare_subscriber(key, self._on)

    def _on(self, sample: zenoh.Sample) -> None:
        message = self._codec.decode(*payload_of(sample))
        with self._lock:
            self._items.append((time.monotonic(), message))

    def items(self) -> list[tuple[float, M]]:
        with self._lock:
            return list(self._items)

    def messages(self) -> list[M]:
        return [m for _, m in self.items()]

    def latest(self) -> M | None:
        with self._lock:
            return self._items[-1][1] if self._items else None

    def count(self) -> int:
        with self._lock:
            return len(self._items)


def is_alive(session: zenoh.Session, key: str) -> bool:
    return any(reply.ok is not None for reply in session.liveliness().get(key, timeout=0.5))


def robot_info(session: zenoh.Session, keys: Keys) -> RobotInfo:
    def ask() -> RobotInfo | None:
        for reply in session.get(keys.robot_info, timeout=2.0):
            if reply.ok is not None:
                return Codec(RobotInfo).decode(*payload_of(reply.ok))
        return None

    return wait_for(ask, 30, "the sim's info/robot")


def ctl(session: zenoh.Session, keys: Keys, verb: str) -> CtlReply:
    replies = [r for r in session.get(keys.ctl(verb), timeout=10.0) if r.ok is not None]
    assert replies, f"no reply on ctl/{verb}"
    return Codec(CtlReply).decode(*payload_of(replies[0].ok))


def put_json(session: zenoh.Session, key: str, value: object) -> None:
    session.put(key, json.dumps(value).encode(), encoding=zenoh.Encoding("application/json"))


class Rig:
    """A router, a sim and a bridge for one test, with the test's session watching."""

    def __init__(self, start_service: Callable[..., Service], zsession: zenoh.Session, robot_id: str,
                 sim_args: tuple[str, ...]) -> None:
        self.start_service = start_service
        self.session = zsession
        self.keys = Keys(robot_id)
        self.sim = start_service("sim", *sim_args)
        self.info = robot_info(zsession, self.keys)
        self.index = {name: i for i, name in enumerate(self.info.joint_names)}
        self.default_q = self.info.default_q[self.info.mode]
        self.motors = Collector(zsession, self.keys.motors, MotorCommand)
        self.joints = Collector(zsession, self.keys.joints, JointState)
        self.status = Collector(zsession, self.keys.sim_status, SimStatus)
        self.reports = Collector(zsession, self.keys.bridge_report, BridgeReport)

    def start_bridge(self, *args: str) -> Service:
        bridge = self.start_service("bridge", *args)
        wait_for(lambda: is_alive(self.session, self.keys.alive("bridge")) or not bridge.alive(),
                 30, "alive/bridge")
        assert bridge.alive(), bridge.log()
        return bridge

    def q(self, joint: str) -> float:
        state = self.joints.latest()
        assert state is not None
        return state.q[self.index[joint]]

    def commanded(self, joint: str) -> float | None:
        command = self.motors.latest()
        return None if command is None else command.q[self.index[joint]]

    def tracks(self, joint: str, target: float, tol: float = 0.05) -> bool:
        return self.joints.count() > 0 and abs(self.q(joint) - target) < tol

    def next_report(self, after: int) -> BridgeReport:
        wait_for(lambda: self.reports.count() > after, 5, "a bridge report")
        return self.reports.messages()[after]

    def motors_after(self, n: int) -> list[MotorCommand]:
        """Wait for `n` more motor commands than there are now; return them."""
        start = self.motors.count()
        wait_for(lambda: self.motors.count() >= start + n, 5, f"{n} more motor commands")
        return self.motors.messages()[start:]


@pytest.fixture
def fixed_rig(start_service: Callable[..., Service], zsession: zenoh.Session, robot_id: str) -> Rig:
    """Fixed base, gravity off: joints track targets with no balance to lose."""
    return Rig(start_service, zsession, robot_id, ("--mode", "fixed", "--rtf", "1"))


def test_json_targets_move_the_arm_slew_limited_and_the_floating_g1_stays_up(
    start_service: Callable[..., Service], zsession: zenoh.Session, robot_id: str
) -> None:
    rig = Rig(start_service, zsession, robot_id, ("--mode", "floating", "--rtf", "1"))
    odom = Collector(zsession, rig.keys.odom, Odometry)
    ghost = Collector(zsession, rig.keys.bridge_targets, JointTargets)
    rig.start_bridge("--slew-rad-s", "2")
    wait_for(lambda: rig.commanded(ELBOW) is not None, 5, "motor commands")
    start_at = time.monotonic()
    target = {ARM[0]: -0.8, ARM[1]: 0.9}
    put_json(zsession, rig.keys.joint_targets, {"names": list(target), "q": list(target.values())})

    wait_for(lambda: all(rig.tracks(j, q, 0.08) for j, q in target.items()), 15, "the arm to reach its target")
    # The joint can be within 0.08 of its target while the commanded q still closes the last hundredths.
    wait_for(lambda: rig.commanded(ARM[0]) == target[ARM[0]], 5, "the commanded shoulder at its target")
    # Slew limit, seen in the published commands: 0.8 rad at 2 rad/s takes 0.4 s, in small steps.
    shoulder = [(t, m.q[rig.index[ARM[0]]]) for t, m in rig.motors.items() if t >= start_at]
    arrived = next(t for t, q in shoulder if abs(q - target[ARM[0]]) < 1e-9)
    moving = [t for t, q in shoulder if q < rig.default_q[rig.index[ARM[0]]] - 1e-9]
    assert arrived - moving[0] >= 0.3
    steps = [abs(b - a) for (_, a), (_, b) in zip(shoulder, shoulder[1:])]
    assert max(steps) <= 2.0 * 0.1 + 1e-9  # never more than MAX_TICK_S worth
    assert sorted(steps)[len(steps) // 2] <= 0.03  # typically 2 rad/s * 10 ms
    # Held for the viewer's ghost: every joint, the commanded q.
    held = wait_for(ghost.latest, 5, "state/targets")
    assert held.names == rig.info.joint_names
    # Standing all along (pelvis z from ground truth), and the bridge kept the sim fed.
    heights = [m.pos[2] for t, m in odom.items() if t >= start_at]
    assert heights and min(heights) > STANDING_Z_M, min(heights)
    status = rig.status.latest()
    assert status is not None and not status.watchdog and not status.fallen


def test_every_joint_to_zero_at_once_leaves_the_floating_g1_standing(
    start_service: Callable[..., Service], zsession: zenoh.Session, robot_id: str
) -> None:
    """What joint_state_publisher_gui's first message does (every joint 0), or the viewer's sliders all at 0:
    from the squat, the bridge moves every joint along one straight line (all arrive together), and the
    G1 stands up straight. Each joint at 2 rad/s on its own took the pelvis from 0.725 m to 0.07 m."""
    rig = Rig(start_service, zsession, robot_id, ("--mode", "floating", "--rtf", "1"))
    odom = Collector(zsession, rig.keys.odom, Odometry)
    rig.start_bridge()
    wait_for(lambda: rig.commanded(ELBOW) is not None, 5, "motor commands")
    names = list(rig.info.joint_names)
    start_at = time.monotonic()
    put_json(zsession, rig.keys.joint_targets, {"names": names, "q": [0.0] * len(names)})
    wait_for(lambda: all(abs(q) < 1e-9 for q in rig.motors.latest().q), 10, "the commands to reach zero")
    time.sleep(1.0)  # a fall shows within a second of the arrival (measured: 1.5 s after the put)
    heights = [m.pos[2] for t, m in odom.items() if t >= start_at]
    assert min(heights) > STANDING_Z_M, f"the pelvis went down to {min(heights):.2f} m"
    assert heights[-1] > 0.76, f"standing straight: {heights[-1]:.3f} m"
    status = rig.status.latest()
    assert status is not None and not status.fallen


def test_scalar_keys_validation_and_clamping(fixed_rig: Rig, zsession: zenoh.Session) -> None:
    rig = fixed_rig
    rig.start_bridge("--slew-rad-s", "0")
    elbow_key = rig.keys.joint_target(ELBOW)

    # A bare number, as JSON and as plain text (what z_put sends: no encoding at all).
    put_json(zsession, elbow_key, 0.6)
    wait_for(lambda: rig.tracks(ELBOW, 0.6), 10, "the elbow to reach 0.6 (JSON)")
    zsession.put(elbow_key, b" 0.3\n")
    wait_for(lambda: rig.tracks(ELBOW, 0.3), 10, "the elbow to reach 0.3 (plain text)")
    zsession.put(elbow_key, b"0.1", encoding=zenoh.Encoding("text/plain"))
    wait_for(lambda: rig.commanded(ELBOW) == 0.1, 5, "the elbow command 0.1 (text/plain)")

    # Rejected whole: an unknown joint beside a valid one, a NaN (msgpack), a non-number, garbage.
    shoulder = ARM[0]
    before = rig.commanded(shoulder)
    bad: list[tuple[str, bytes]] = [
        (rig.keys.joint_targets, json.dumps({"names": [shoulder, "tail_joint"], "q": [0.5, 0.0]}).encode()),
        (rig.keys.joint_targets, msgspec.msgpack.encode({"names": [shoulder], "q": [math.nan]})),
        (rig.keys.joint_targets, json.dumps({"names": [shoulder], "q": ["up"]}).encode()),
        (rig.keys.joint_target(shoulder), b"nan"),
        (rig.keys.joint_target("tail_joint"), b"0.5"),
    ]
    for i, (key, payload) in enumerate(bad):
        seen = rig.reports.count()
        zsession.put(key, payload)
        report = rig.next_report(seen)
        assert (report.key, report.accepted, report.rejected_total) == (key, False, i + 1), report
        assert report.error
    assert "tail_joint" in rig.reports.messages()[0].error
    assert all(m.q[rig.index[shoulder]] == before for m in rig.motors_after(5)), "a rejected input was applied"

    # Clamped to the joint limit, applied and reported.
    seen = rig.reports.count()
    put_json(zsession, rig.keys.joint_targets, {"names": [ELBOW, shoulder], "q": [50.0, 0.2]})
    report = rig.next_report(seen)
    assert report.accepted and report.clamped == (ELBOW,) and report.clamped_total == 1
    q_max = rig.info.q_max[rig.index[ELBOW]]
    wait_for(lambda: rig.commanded(ELBOW) == q_max and rig.commanded(shoulder) == 0.2, 5, "clamped command")


def test_watchdog_on_kill_resume_on_restart_and_default_pose_after_reset(fixed_rig: Rig, zsession: zenoh.Session) -> None:
    rig = fixed_rig
    bridge = rig.start_bridge()
    put_json(zsession, rig.keys.joint_targets, {"names": [ELBOW], "q": [1.0]})
    wait_for(lambda: rig.tracks(ELBOW, 1.0), 10, "the elbow to track the target")

    bridge.kill()  # SIGKILL: no goodbye, the sim must notice the silence itself
    wait_for(lambda: (s := rig.status.latest()) is not None and s.watchdog, 5, "the sim's watchdog")

    rig.start_bridge()
    wait_for(lambda: (s := rig.status.latest()) is not None and not s.watchdog, 5, "the watchdog to release")
    put_json(zsession, rig.keys.joint_targets, {"names": [ELBOW], "q": [1.0]})
    wait_for(lambda: rig.tracks(ELBOW, 1.0), 10, "the elbow to track the target after the restart")

    assert ctl(zsession, rig.keys, "reset").ok
    default = rig.default_q[rig.index[ELBOW]]
    wait_for(lambda: rig.commanded(ELBOW) == default, 5, "the bridge to command the default pose")
    wait_for(lambda: rig.tracks(ELBOW, default, 0.02), 10, "the elbow back at its default")
    # Held there, not drifting back to the stale target.
    assert all(m.q[rig.index[ELBOW]] == default for m in rig.motors_after(30))
    assert rig.tracks(ELBOW, default, 0.02)


def test_waits_for_the_sim_then_exits_0_on_sigterm(
    start_service: Callable[..., Service], zsession: zenoh.Session, robot_id: str
) -> None:
    keys = Keys(robot_id)
    bridge = start_service("bridge", "--info-timeout-s", "0.3")
    wait_for(lambda: "no sim answers" in bridge.log() or not bridge.alive(), 20, "the bridge to wait for the sim")
    assert bridge.alive() and not is_alive(zsession, keys.alive("bridge"))

    start_service("sim", "--mode", "fixed", "--rtf", "1")
    wait_for(lambda: is_alive(zsession, keys.alive("bridge")), 30, "alive/bridge once the sim answers")
    motors = Collector(zsession, keys.motors, MotorCommand)
    wait_for(lambda: motors.count() >= 10, 5, "motor commands")

    started = time.monotonic()
    bridge.signal(signal.SIGTERM)
    assert bridge.proc.wait(5) == 0, bridge.log()
    assert time.monotonic() - started < 2.0
    wait_for(lambda: not is_alive(zsession, keys.alive("bridge")), 5, "alive/bridge to disappear")


def test_a_restarted_sim_is_learned_again_even_with_another_robot(fixed_rig: Rig, zsession: zenoh.Session, tmp_path) -> None:
    """A new sim run (new run_id) is not the sim the bridge knew: no stale targets, no stale joint list."""
    rig = fixed_rig
    rig.start_bridge("--slew-rad-s", "0")
    put_json(zsession, rig.keys.joint_targets, {"names": [ELBOW], "q": [1.0]})
    wait_for(lambda: rig.commanded(ELBOW) == 1.0, 5, "the G1's elbow commanded to 1.0")
    old_run = rig.info.run_id
    assert old_run, "info/robot carries the sim's run id"

    assert rig.sim.stop() == 0
    urdf = tmp_path / "arm.urdf"
    urdf.write_text(TWO_JOINT_ARM)
    rig.start_service("sim", "--urdf", str(urdf), "--mode", "fixed", "--rtf", "1")
    new_run = wait_for(lambda: (s := rig.status.latest()) is not None and s.run_id != old_run and s.run_id, 30,
                       "state/sim from the new sim")
    commands = wait_for(lambda: [m for m in rig.motors_after(1) if len(m.q) == 2], 10,
                        "motor commands for the two-joint arm")
    assert commands[-1].q == (0.0, 0.0), "the bridge holds the new robot's default pose, not stale targets"

    # The new sim obeys the bridge: its watchdog lets go and it stops rejecting commands.
    def settled() -> SimStatus | None:
        status = rig.status.latest()
        return status if status is not None and status.run_id == new_run and not status.watchdog else None

    first = wait_for(settled, 10, "the new sim fed by the bridge")
    # Five statuses later (~0.5 s at 10 Hz): still fed, and no command refused meanwhile.
    def five_statuses_later() -> SimStatus | None:
        status = rig.status.latest()
        return status if status is not None and status.seq >= first.seq + 5 else None

    later = wait_for(five_statuses_later, 10, "five more statuses from the new sim")
    assert not later.watchdog
    assert later.rejected_commands == first.rejected_commands, later.last_error


def test_gains_are_left_to_the_sim_unless_the_bridge_was_given_its_own(fixed_rig: Rig) -> None:
    rig = fixed_rig
    bridge = rig.start_bridge()
    commands = rig.motors_after(5)
    assert all(c.kp is None and c.kd is None for c in commands), "the bridge sent the sim's own gains back"
    # With local robot files the gains are the user's (control.toml), so they are sent.
    bridge.stop()
    rig.start_bridge("--robot", "g1")
    later = rig.motors_after(5)[-1]
    assert later.kp is not None and len(later.kp) == len(rig.info.joint_names)
