"""Unit tests of the bridge's pure logic (services/bridge/targets.py) and its settings; no network."""

from __future__ import annotations

import math

import msgspec
import numpy as np
import pytest

from zensim.bridge.settings import BridgeSettings
from zensim.bridge.targets import HeldTargets, RobotModel, UnusableRobotInfo, carries_targets
from zensim.common.settings import SettingsError, load_settings
from zensim.schemas import Codec, DecodeError, Gains, JointTargets, RobotInfo

NAMES = ("hip", "knee", "elbow")


def robot_info(mode: str = "floating") -> RobotInfo:
    """A three-joint robot with distinct poses and gains per mode."""
    return RobotInfo(
        robot="t", model="toy", schema_version=1, joint_names=NAMES,
        q_min=(-1.0, 0.0, -2.0), q_max=(1.0, 2.0, 2.0),
        effort_limit=(10.0,) * 3, velocity_limit=(5.0,) * 3,
        default_q={"floating": (-0.4, 0.9, 0.0), "fixed": (0.0, 0.0, 0.0)},
        gains={"floating": Gains(kp=(100.0, 100.0, 30.0), kd=(5.0, 5.0, 1.0)),
               "fixed": Gains(kp=(10.0, 10.0, 3.0), kd=(1.0, 1.0, 0.1))},
        base_height_m={"floating": 0.8, "fixed": 1.2}, mode=mode,  # type: ignore[arg-type]
        timestep_s=0.002, state_rate_hz=100.0, status_rate_hz=10.0, watchdog_timeout_s=0.5,
        run_id="run", episode="run.0",
    )


def held(slew: float = 0.0, mode: str = "floating") -> HeldTargets:
    return HeldTargets(RobotModel.from_info(robot_info(mode)), slew)


class TestRobotModel:
    def test_from_info(self) -> None:
        model = RobotModel.from_info(robot_info())
        assert model.joint_names == NAMES
        assert model.kp["fixed"].tolist() == [10.0, 10.0, 3.0]
        assert model.mode == "floating"

    @pytest.mark.parametrize("change, why", [
        ({"q_min": (0.0, 0.0)}, "q_min"),
        ({"default_q": {"floating": (0.0,)}}, "default_q"),
        ({"default_q": {"floating": (0.0, math.nan, 0.0)}}, "finite"),
        ({"joint_names": ("a", "a", "b")}, "more than once"),
    ])
    def test_an_inconsistent_info_does_not_decode(self, change: dict, why: str) -> None:
        """Shapes are the schema's to check, once: such a RobotInfo never reaches the bridge."""
        info = robot_info()
        fields = {f: getattr(info, f) for f in info.__struct_fields__}
        payload = msgspec.msgpack.encode({"type": "robot_info", **msgspec.to_builtins(info), **msgspec.to_builtins(change)})
        with pytest.raises(DecodeError, match=why):
            Codec(RobotInfo).decode(payload)
        with pytest.raises(ValueError, match=why):
            RobotInfo(**{**fields, **change})

    def test_an_info_without_the_current_mode_is_unusable(self) -> None:
        info = robot_info()
        fields = {f: getattr(info, f) for f in info.__struct_fields__}
        with pytest.raises(UnusableRobotInfo):
            RobotModel.from_info(RobotInfo(**{**fields, "gains": {"fixed": Gains(kp=(1.0,) * 3, kd=(1.0,) * 3)}}))


def targets(names: tuple, q: tuple, dq: tuple | None = None) -> JointTargets:
    return JointTargets(names=names, q=q, dq=dq)


class TestApply:
    def test_starts_at_the_default_pose_of_the_current_mode(self) -> None:
        assert held().q.tolist() == [-0.4, 0.9, 0.0]
        assert held(mode="fixed").q.tolist() == [0.0, 0.0, 0.0]

    def test_partial_targets_merge_and_hold_the_rest(self) -> None:
        h = held()
        assert h.apply(targets(("knee",), (1.2,))).accepted
        assert h.apply(targets(("elbow", "hip"), (0.5, 0.1))).accepted
        assert h.target_q.tolist() == [0.1, 1.2, 0.5]

    def test_an_unknown_joint_rejects_the_input_whole(self) -> None:
        h = held()
        before = h.target_q.copy()
        verdict = h.apply(targets(("knee", "wrist"), (1.0, 0.0)))
        assert not verdict.accepted
        assert "unknown joint" in (verdict.error or "") and "wrist" in (verdict.error or "")
        assert h.target_q.tolist() == before.tolist()

    @pytest.mark.parametrize("names, q, dq, why", [
        (("knee", "elbow"), (1.0, math.nan), None, "finite"),
        (("knee", "elbow"), (1.0, math.inf), None, "finite"),
        (("knee",), (1.0,), (math.nan,), "finite"),
        (("knee", "knee"), (1.0, 1.0), None, "more than once"),
        (("knee", "elbow"), (1.0,), None, "names"),
    ])
    def test_a_malformed_input_cannot_reach_the_held_targets(self, names: tuple, q: tuple, dq: tuple | None,
                                                              why: str) -> None:
        """Shape and finiteness are checked once, by the schema: such a JointTargets cannot be made,
        so neither a decoded message nor the bridge's own single-joint path can carry one."""
        with pytest.raises(ValueError, match=why):
            targets(names, q, dq)
        with pytest.raises(DecodeError, match=why):
            Codec(JointTargets).decode(msgspec.msgpack.encode({"names": names, "q": q, "dq": dq}))

    def test_a_value_that_is_not_a_number_does_not_decode(self) -> None:
        for q in (["x"], [True]):
            with pytest.raises(DecodeError):
                Codec(JointTargets).decode(msgspec.json.encode({"names": ["knee"], "q": q}), "application/json")

    def test_targets_beyond_the_limits_are_clamped_and_named(self) -> None:
        h = held()
        verdict = h.apply(targets(("hip", "knee", "elbow"), (-3.0, 1.0, 9.0)))
        assert verdict.accepted and verdict.clamped == ("hip", "elbow")
        assert h.target_q.tolist() == [-1.0, 1.0, 2.0]

    def test_dq_is_held_per_joint_and_cleared_by_a_position_only_input(self) -> None:
        h = held()
        h.apply(targets(("knee", "elbow"), (1.0, 0.0), (0.5, -0.5)))
        assert h.target_dq.tolist() == [0.0, 0.5, -0.5]
        h.apply(targets(("knee",), (1.1,)))
        assert h.target_dq.tolist() == [0.0, 0.0, -0.5]


class TestSlew:
    def test_off_jumps_to_the_target(self) -> None:
        h = held(slew=0.0)
        h.apply(targets(("elbow",), (1.5,)))
        assert h.step(0.01)[2] == 1.5

    def test_moves_at_most_slew_times_dt_per_tick(self) -> None:
        h = held(slew=2.0)
        h.apply(targets(("elbow", "hip"), (1.5, -0.5)))
        trajectory = [h.step(0.01).copy() for _ in range(100)]
        steps = np.abs(np.diff(np.array(trajectory)[:, 2]))
        assert steps.max() <= 0.02 + 1e-12
        assert trajectory[0][2] == pytest.approx(0.02)
        assert trajectory[-1][2] == 1.5  # arrives and stays
        assert trajectory[0][1] == 0.9  # untouched joints stay

    def test_the_joints_of_one_change_arrive_together(self) -> None:
        """Each joint covers the same fraction of its way per tick (a straight line in joint space): the
        floating G1 sent from its squat to all zeros fell over when the hips and ankles (0.45 rad away)
        arrived long before the knees (0.9 rad)."""
        h = held(slew=2.0)
        start = h.q.copy()
        h.apply(targets(("elbow", "hip"), (1.5, -0.5)))
        trajectory = np.array([h.step(0.01).copy() for _ in range(100)])
        way = np.array([1.5, -0.5]) - start[[2, 0]]
        fractions = (trajectory[:, [2, 0]] - start[[2, 0]]) / way
        assert np.allclose(fractions[:, 0], fractions[:, 1])
        assert fractions[0, 0] == pytest.approx(0.02 / 1.5)  # the largest move sets the pace: slew * dt
        assert np.abs(np.diff(trajectory, axis=0)).max() <= 0.02 + 1e-12
        assert trajectory[-1].tolist() == [-0.5, 0.9, 1.5]  # and all arrive

    def test_a_stall_does_not_turn_into_a_jump(self) -> None:
        h = held(slew=2.0)
        h.apply(targets(("elbow",), (1.5,)))
        assert h.step(5.0)[2] == pytest.approx(0.2)  # MAX_TICK_S worth, not 10 rad

    def test_negative_slew_is_refused(self) -> None:
        with pytest.raises(ValueError):
            held(slew=-1.0)


class TestFollowSim:
    def test_the_episode_the_robot_was_described_in_changes_nothing(self) -> None:
        h = held(slew=2.0)
        h.apply(targets(("elbow",), (1.5,)))
        assert not h.follow_sim("run.0", "floating")
        assert h.target_q[2] == 1.5

    def test_a_new_episode_holds_the_default_pose_not_stale_targets(self) -> None:
        h = held(slew=2.0)
        h.apply(targets(("elbow",), (1.5,)))
        h.step(0.1)
        assert h.follow_sim("run.1", "floating")
        assert h.target_q.tolist() == h.q.tolist() == [-0.4, 0.9, 0.0]
        h.apply(targets(("elbow",), (1.5,)))
        assert not h.follow_sim("run.1", "floating")  # the same episode again: targets stay
        assert h.target_q[2] == 1.5

    def test_a_mode_change_takes_the_new_pose_and_gains(self) -> None:
        h = held()
        h.apply(targets(("elbow",), (1.5,)))
        assert h.follow_sim("run.1", "fixed")
        assert h.q.tolist() == [0.0, 0.0, 0.0]
        assert h.gains()[0].tolist() == [10.0, 10.0, 3.0]

    def test_an_unknown_mode_keeps_the_targets(self) -> None:
        h = held()
        with pytest.raises(UnusableRobotInfo):
            h.follow_sim("run.1", "flying")  # type: ignore[arg-type]
        assert h.mode == "floating"
        assert h.episode == "run.0"


class TestSettings:
    def test_defaults(self) -> None:
        s = load_settings(BridgeSettings, [], env={})
        assert (s.rate_hz, s.slew_rad_s, s.targets_rate_hz) == (100.0, 2.0, 30.0)

    def test_env_and_flags(self) -> None:
        s = load_settings(BridgeSettings, ["--slew-rad-s", "0"], env={"ZENSIM_BRIDGE_RATE_HZ": "1000"})
        assert (s.rate_hz, s.slew_rad_s) == (1000.0, 0.0)

    @pytest.mark.parametrize("flag, value", [("--rate-hz", "1001"), ("--rate-hz", "0"), ("--slew-rad-s", "-1")])
    def test_out_of_range_names_the_flag(self, flag: str, value: str) -> None:
        with pytest.raises(SettingsError, match=flag):
            load_settings(BridgeSettings, [flag, value], env={})


class TestLocalFiles:
    def test_bundled_g1_gives_both_modes(self) -> None:
        model = RobotModel.from_files("g1", None, None)
        assert len(model.joint_names) == 29 and model.mode == "floating"
        assert model.has_mode("fixed") and model.has_mode("floating")
        knee = model.joint_names.index("left_knee_joint")
        assert model.default_q["floating"][knee] == pytest.approx(0.9)
        assert model.kp["floating"][knee] != model.kp["fixed"][knee]
        assert np.all(model.q_min < model.q_max)


class TestTargetsRate:
    """state/targets goes out at `targets_rate_hz` as the docs say, not at rate_hz / round(rate_hz / it)."""

    @pytest.mark.parametrize("rate_hz, targets_rate_hz", [(100.0, 30.0), (100.0, 100.0), (1000.0, 30.0), (50.0, 7.0)])
    def test_ticks_carrying_targets_make_the_documented_rate(self, rate_hz: float, targets_rate_hz: float) -> None:
        seconds = 10
        ticks = [t for t in range(int(rate_hz * seconds)) if carries_targets(t, rate_hz, targets_rate_hz)]
        assert len(ticks) == pytest.approx(targets_rate_hz * seconds, abs=1)
        assert ticks[0] == 0  # the first tick publishes: a viewer that joins sees the pose at once
        gaps = np.diff(ticks)
        assert gaps.max() - gaps.min() <= 1  # spread evenly, not bunched

    def test_default_is_30_hz_and_zero_turns_it_off(self) -> None:
        settings = BridgeSettings()
        assert settings.targets_rate_hz == 30.0
        assert sum(carries_targets(t, settings.rate_hz, settings.targets_rate_hz) for t in range(100)) == 30
        assert not any(carries_targets(t, 100.0, 0.0) for t in range(100))
