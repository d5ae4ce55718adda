"""state/contacts from a real `zensim sim` process: the G1's feet carry its weight, and say when they do not.

What a contact estimator relies on: standing, the two feet's normal forces add up to the robot's weight
(total mass x g, from the model the sim builds); a foot in the air reads no contact and no force; on the
stand (fixed mode, the floor touches nothing) nothing is in contact. The message travels as msgpack and
decodes the same through JSON, and carries the seq of the joint state of the same instant.
"""

from __future__ import annotations

import math
import threading

import msgspec
import pytest

from support import Latest, wait_for
from test_sim_process import command_until, sim_keys, wait_alive
from zensim.robots import robot_files
from zensim.robots.builder import build
from zensim.schemas import Contacts, JointState

FEET = ("left_ankle_roll_link", "right_ankle_roll_link")


def weight_n() -> float:
    """The G1's weight from the model the sim builds: total mass x g."""
    model = build(robot_files(), "floating").model
    return float(model.body_subtreemass[0] * -model.opt.gravity[2])


class RawSamples:
    """Every payload on a key as it came off the wire, with its encoding."""

    def __init__(self, session, key: str) -> None:
        self._lock = threading.Lock()
        self.samples: list[tuple[bytes, str]] = []
        self._sub = session.declare_subscriber(key, self._on_sample)

    def _on_sample(self, sample) -> None:
        with self._lock:
            if len(self.samples) < 50:
                self.samples.append((sample.payload.to_bytes(), str(sample.encoding)))


def test_standing_feet_carry_the_weight_and_states_agree(start_service, zsession, robot_id) -> None:
    keys = sim_keys(robot_id)
    contacts = Latest(zsession, keys.contacts, Contacts)
    joints = Latest(zsession, keys.joints, JointState)
    raw = RawSamples(zsession, keys.contacts)
    contacts.keep_history = joints.keep_history = True
    start_service("sim", "--rtf", "0", "--state-rate-hz", "100")
    contacts.wait(lambda m: m.sim_time_s >= 3.0, timeout_s=60, what="3 s of sim time")
    weight = weight_n()
    settled = [m for m in list(contacts.history) if 2.0 <= m.sim_time_s <= 3.0]
    assert len(settled) > 50
    for m in settled:
        assert m.links == FEET and m.in_contact == (True, True) and min(m.points) >= 1, m
        assert sum(m.normal_force_n) == pytest.approx(weight, rel=0.05), (m, weight)
        # On the flat floor the total force is vertical: the normal forces, little friction.
        assert sum(f[2] for f in m.force_world) == pytest.approx(weight, rel=0.05), m
        assert all(abs(f[0]) + abs(f[1]) < 0.1 * f[2] for f in m.force_world), m
        assert min(m.normal_force_n) > 0.3 * weight, m  # both feet stand, not one
    # The seq is the joint state's of the same instant.
    joint_times = {m.seq: m.sim_time_s for m in list(joints.history)}
    shared = [m for m in settled if m.seq in joint_times]
    assert len(shared) > 0.8 * len(settled)
    assert all(joint_times[m.seq] == m.sim_time_s for m in shared)
    # The wire: msgpack by default; the same message through JSON decodes equal.
    payload, encoding = wait_for(lambda: raw.samples[-1] if raw.samples else None, 5, "a raw sample")
    assert "msgpack" in encoding
    message = msgspec.msgpack.decode(payload, type=Contacts)
    assert msgspec.json.decode(msgspec.json.encode(message), type=Contacts) == message
    assert msgspec.msgpack.decode(msgspec.msgpack.encode(message), type=Contacts) == message
    assert msgspec.json.decode(msgspec.json.encode(message))["type"] == "contacts"


def test_a_lifted_foot_leaves_contact(start_service, zsession, robot_id) -> None:
    keys = sim_keys(robot_id)
    contacts = Latest(zsession, keys.contacts, Contacts)
    contacts.keep_history = True
    start_service("sim", "--rtf", "1", "--state-rate-hz", "100")
    wait_alive(zsession, keys)
    contacts.wait(lambda m: m.sim_time_s >= 1.0 and m.in_contact == (True, True), timeout_s=30, what="standing")
    # The left leg folds up (hip and knee flexed): its foot rises off the floor, the right one stands.
    lift = {"names": ["left_hip_pitch_joint", "left_knee_joint", "left_ankle_pitch_joint"], "q": [-1.0, 1.8, -0.6]}

    def one_foot_up() -> bool:
        return any(m.in_contact == (False, True) for m in list(contacts.history)[-20:])

    command_until(zsession, keys.motors, lift, one_foot_up, "the left foot off the floor")
    up = next(m for m in reversed(list(contacts.history)) if m.in_contact == (False, True))
    assert up.points[0] == 0 and up.normal_force_n[0] == 0.0 and up.force_world[0] == (0.0, 0.0, 0.0), up
    assert up.points[1] >= 1 and up.normal_force_n[1] > 0.0, up


def test_fixed_mode_nothing_touches(start_service, zsession, robot_id) -> None:
    keys = sim_keys(robot_id)
    contacts = Latest(zsession, keys.contacts, Contacts)
    contacts.keep_history = True
    start_service("sim", "--rtf", "0", "--state-rate-hz", "100", "--mode", "fixed")
    contacts.wait(lambda m: m.sim_time_s >= 1.0, timeout_s=60, what="1 s of sim time")
    seen = list(contacts.history)
    assert len(seen) > 50
    for m in seen:
        assert m.links == FEET and m.in_contact == (False, False) and m.points == (0, 0), m
        assert m.normal_force_n == (0.0, 0.0) and all(f == (0.0, 0.0, 0.0) for f in m.force_world), m
        assert all(math.isfinite(x) for f in m.force_world for x in f)
