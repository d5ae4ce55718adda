"""Unitree's open G1 walking policy (unitree_rl_gym `motion.pt`), run with numpy: no torch, no network.

The network is an LSTM (47 -> 64, one layer) followed by an MLP (64 -> 32, ELU, 32 -> 12); its weights
ship converted in the robot's folder (`robots/unitree_g1/policy/motion.npz`, named by its walking.toml;
robots/unitree_g1/policy/README.md says where they come from and how they were converted). One `act` is one 50 Hz policy step; the LSTM's state
carries over between calls, as in the TorchScript module, until `reset`.

The observation and action follow Unitree's reference loop (deploy_mujoco.py with configs/g1.yaml):

    obs[0:3]   base angular velocity (body, rad/s) x 0.25
    obs[3:6]   gravity in the body frame (unit vector)
    obs[6:9]   command (vx, vy, yaw rate) x (2, 2, 0.25)
    obs[9:21]  leg q - default
    obs[21:33] leg dq x 0.05
    obs[33:45] the previous action
    obs[45:47] sin, cos of the gait phase (period 0.8 s of sim time)
    target leg q = action x 0.25 + default
The scales below belong to the network (its inputs as trained), so they live beside it; the default
pose, gains and period are the robot's (walking.toml).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Final

import numpy as np

NUM_OBS: Final = 47
NUM_ACTIONS: Final = 12
"""The 12 leg joints: left then right hip pitch, hip roll, hip yaw, knee, ankle pitch, ankle roll."""
ANG_VEL_SCALE: Final = 0.25
DOF_VEL_SCALE: Final = 0.05
ACTION_SCALE: Final = 0.25
CMD_SCALE: Final = np.array([2.0, 2.0, 0.25])
GAIT_PERIOD_S: Final = 0.8
STANCE_FRACTION: Final = 0.55
"""Each foot is in stance for the first 55 % of its half of the gait (the left foot's phase is the gait's,
the right's half a period later; unitree_rl_gym's contact reward): both feet are down for the first
5 % of each half period."""
WEIGHTS: Final = ("lstm_weight_ih", "lstm_weight_hh", "lstm_bias_ih", "lstm_bias_hh",
                  "actor0_weight", "actor0_bias", "actor2_weight", "actor2_bias")


def gravity_in_body(quat_wxyz: np.ndarray) -> np.ndarray:
    """World gravity direction (0, 0, -1) seen in the body frame of orientation `quat_wxyz`."""
    w, x, y, z = quat_wxyz
    return np.array([2 * (-z * x + w * y), -2 * (z * y + w * x), 1 - 2 * (w * w + z * z)])


def observation(gyro: np.ndarray, quat_wxyz: np.ndarray, command: np.ndarray, leg_q: np.ndarray,
                leg_dq: np.ndarray, last_action: np.ndarray, sim_time_s: float, default_q: np.ndarray) -> np.ndarray:
    """The policy's 47-vector for one instant (see the module docstring)."""
    phase = (sim_time_s % GAIT_PERIOD_S) / GAIT_PERIOD_S
    obs = np.empty(NUM_OBS, dtype=np.float32)
    obs[0:3] = np.asarray(gyro) * ANG_VEL_SCALE
    obs[3:6] = gravity_in_body(np.asarray(quat_wxyz, float))
    obs[6:9] = np.asarray(command) * CMD_SCALE
    obs[9:21] = np.asarray(leg_q) - default_q
    obs[21:33] = np.asarray(leg_dq) * DOF_VEL_SCALE
    obs[33:45] = last_action
    obs[45:47] = (math.sin(2 * math.pi * phase), math.cos(2 * math.pi * phase))
    return obs


def double_support(sim_time_s: float) -> bool:
    """Whether the gait has both feet down at `sim_time_s` (STANCE_FRACTION): the instant to stop stepping."""
    half = GAIT_PERIOD_S / 2
    return (sim_time_s % half) / GAIT_PERIOD_S < STANCE_FRACTION - 0.5


def load_weights(path: Path) -> dict[str, np.ndarray]:
    """The weights in `path` (an .npz: float32 arrays by name)."""
    with path.open("rb") as f, np.load(f) as npz:
        return {name: np.array(npz[name], dtype=np.float32) for name in WEIGHTS}


def _sigmoid(x: np.ndarray) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-x))


class WalkPolicy:
    """The LSTM + MLP with its recurrent state.

    Args:
        weights: arrays named as in WEIGHTS (`load_weights(path)`).
        default_q: the leg stance, rad (action 0).
    """

    def __init__(self, weights: dict[str, np.ndarray], default_q: np.ndarray) -> None:
        w = weights
        self.default_q = np.asarray(default_q, float)
        self._w_ih, self._w_hh = w["lstm_weight_ih"], w["lstm_weight_hh"]
        self._b = w["lstm_bias_ih"] + w["lstm_bias_hh"]
        self._w0, self._b0 = w["actor0_weight"], w["actor0_bias"]
        self._w2, self._b2 = w["actor2_weight"], w["actor2_bias"]
        hidden = self._w_hh.shape[1]
        self._h = np.zeros(hidden, np.float32)
        self._c = np.zeros(hidden, np.float32)

    def reset(self) -> None:
        """Forget the recurrent state (the TorchScript module's reset_memory)."""
        self._h[:] = 0.0
        self._c[:] = 0.0

    def act(self, obs: np.ndarray) -> np.ndarray:
        """One step: the 12 actions for observation `obs` (float32), updating the LSTM state."""
        if obs.shape != (NUM_OBS,):
            raise ValueError(f"the observation has shape {obs.shape}, the policy takes ({NUM_OBS},)")
        gates = self._w_ih @ obs + self._w_hh @ self._h + self._b
        i, f, g, o = np.split(gates, 4)  # PyTorch's gate order: input, forget, cell, output
        self._c = _sigmoid(f) * self._c + _sigmoid(i) * np.tanh(g)
        self._h = _sigmoid(o) * np.tanh(self._c)
        x = self._w0 @ self._h + self._b0
        x = np.where(x > 0, x, np.expm1(np.minimum(x, 0)))  # ELU, alpha 1
        return (self._w2 @ x + self._b2).astype(np.float32)

    def leg_targets(self, action: np.ndarray) -> np.ndarray:
        """Leg joint targets (rad) for an action."""
        return action * ACTION_SCALE + self.default_q
