"""Answers to the G1's "sport" service (LocoClient of unitree_sdk2's `g1/loco`), without DDS.

The walking controller is `zensim loco`: this module parses each request and hands it to a `Walker`
(highlevel.py's forwards it over Zenoh: ctl/loco and cmd/velocity), then answers from what it says.

The request's `parameter` is JSON, as LocoClient writes it; answers are (status code, data):

    1      API version          0, "1.0.0.0"
    7001   GetFsmId             0, {"data": fsm id}
    7002   GetFsmMode           0, {"data": 0 standing still, 1 walking (a velocity in force)}
    7003   GetBalanceMode       0, {"data": balance mode}
    7101   SetFsmId             {"data": id}: 0 zero torque, 1 damp, 3 sit, 500 start, 702, 706 (zensim loco)
    7102   SetBalanceMode       {"data": 0 or 1}: stored and reported (the policy balances either way)
    7105   SetVelocity          {"velocity": [vx, vy, wz], "duration": s}
    7004, 7005, 7006            3203: swing/stand height and gait phase are not simulated
    7103, 7104, 7106            3203: swing height, stand height (Low/HighStand) and arm tasks (wave, shake hand)
    anything else               3203 (RPC_ERR_SERVER_API_NOT_IMPL)
A parameter that is not the JSON the call takes, or a value the controller refuses (an unknown FSM id,
a non-finite velocity), or a number it cannot represent (an integer beyond int32, a number beyond
+-MAX_NUMBER, a parameter longer than MAX_PARAMETER_CHARS) gets 3204 (RPC_ERR_SERVER_API_PARAMETER) and
changes nothing. Codes are the SDK's (unitree_sdk2py/rpc/internal.py); 3202 (RPC_ERR_SERVER_INTERNAL)
is the adapter's answer when handling a request failed in a way this module did not foresee; 3203 also
answers every request while no walking controller (`zensim loco`) answers for the robot.
"""

from __future__ import annotations

import json
import math
from typing import Final, Protocol

from zensim.schemas import LocoStatus

API_VERSION: Final = "1.0.0.0"
RPC_OK: Final = 0
RPC_ERR_SERVER_INTERNAL: Final = 3202
RPC_ERR_SERVER_API_NOT_IMPL: Final = 3203
RPC_ERR_SERVER_API_PARAMETER: Final = 3204

API_ID_VERSION: Final = 1
GET_FSM_ID: Final = 7001
GET_FSM_MODE: Final = 7002
GET_BALANCE_MODE: Final = 7003
SET_FSM_ID: Final = 7101
SET_BALANCE_MODE: Final = 7102
SET_VELOCITY: Final = 7105
MAX_PARAMETER_CHARS: Final = 4096
"""Longest parameter parsed: LocoClient's are a few dozen characters."""


class ParameterError(ValueError):
    """A request parameter the call cannot take."""


class NoWalker(RuntimeError):
    """No walking controller answers for the robot."""


class Walker(Protocol):
    """The walking controller as the sport service reaches it (highlevel.py: over Zenoh)."""

    def status(self) -> LocoStatus:
        """The controller's newest state. Raises NoWalker."""
        ...

    def request(self, fsm_id: int | None = None, balance_mode: int | None = None) -> LocoStatus:
        """Apply an FSM id or a balance mode; the controller's state after it (`ok` false: refused). Raises NoWalker."""
        ...

    def velocity(self, vx: float, vy: float, wz: float, duration_s: float) -> None:
        """Walk at (vx, vy, wz) for `duration_s` of sim time. Raises NoWalker."""
        ...


def _data(parameter: str) -> object:
    try:
        value = json.loads(parameter)
    except (ValueError, RecursionError) as exc:
        raise ParameterError(f"parameter is not JSON: {exc}") from None
    if not isinstance(value, dict) or "data" not in value:
        raise ParameterError('parameter must be {"data": ...}')
    return value["data"]


MAX_INTEGER: Final = 2**31 - 1
"""The largest integer parameter taken: the robot's ids and modes are int32."""
MAX_NUMBER: Final = 1e9
"""The largest magnitude a velocity or duration parameter may have. Larger values are refused here,
before any float conversion: a JSON integer of 400 digits is a valid Python int that `float()` cannot
represent (OverflowError), and it once killed the request thread."""


def _integer(value: object) -> int:
    """An integer parameter, refused unless it is a JSON integer (or an integral float) within int32."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ParameterError(f"expected an integer, got {type(value).__name__}")
    if isinstance(value, float):
        if not (math.isfinite(value) and value.is_integer()):
            raise ParameterError(f"expected an integer, got {value!r:.40}")
        value = int(value)
    if not -MAX_INTEGER - 1 <= value <= MAX_INTEGER:
        raise ParameterError(f"an integer out of range ({len(str(abs(value)))} digits)")
    return value


def _number(value: object) -> float:
    """A finite number parameter of magnitude at most MAX_NUMBER (integers of any size are compared
    as integers, never converted first)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ParameterError(f"expected a number, got {type(value).__name__}")
    if isinstance(value, float) and not math.isfinite(value):
        raise ParameterError(f"expected a finite number, got {value!r}")
    if not -MAX_NUMBER <= value <= MAX_NUMBER:
        raise ParameterError(f"a number beyond +-{MAX_NUMBER:g}")
    return float(value)


def _velocity(parameter: str) -> tuple[float, float, float, float]:
    try:
        value = json.loads(parameter)
    except (ValueError, RecursionError) as exc:
        raise ParameterError(f"parameter is not JSON: {exc}") from None
    if not isinstance(value, dict):
        raise ParameterError('parameter must be {"velocity": [vx, vy, wz], "duration": s}')
    velocity, duration = value.get("velocity"), value.get("duration", 1.0)
    if not (isinstance(velocity, list) and len(velocity) == 3):
        raise ParameterError('parameter must be {"velocity": [vx, vy, wz], "duration": s} with numbers')
    vx, vy, wz, seconds = (_number(v) for v in (*velocity, duration))
    return vx, vy, wz, seconds


def answer(api_id: int, parameter: str, walker: Walker) -> tuple[int, str]:
    """The (status code, data) for one request, after handing it to `walker`."""
    if len(parameter) > MAX_PARAMETER_CHARS:
        return RPC_ERR_SERVER_API_PARAMETER, ""
    try:
        if api_id == API_ID_VERSION:
            return RPC_OK, API_VERSION
        if api_id == GET_FSM_ID:
            return RPC_OK, json.dumps({"data": walker.status().fsm_id})
        if api_id == GET_FSM_MODE:
            status = walker.status()
            moving = status.walking and any(status.commanded)
            return RPC_OK, json.dumps({"data": 1 if moving else 0})
        if api_id == GET_BALANCE_MODE:
            return RPC_OK, json.dumps({"data": walker.status().balance_mode})
        if api_id == SET_FSM_ID:
            done = walker.request(fsm_id=_integer(_data(parameter)))
            return (RPC_OK if done.ok else RPC_ERR_SERVER_API_PARAMETER), ""
        if api_id == SET_BALANCE_MODE:
            mode = _integer(_data(parameter))
            if mode not in (0, 1):
                raise ParameterError(f"balance mode is 0 or 1, got {mode}")
            done = walker.request(balance_mode=mode)
            return (RPC_OK if done.ok else RPC_ERR_SERVER_API_PARAMETER), ""
        if api_id == SET_VELOCITY:
            vx, vy, wz, duration_s = _velocity(parameter)
            if duration_s < 0:
                raise ParameterError(f"duration must not be negative, got {duration_s}")
            walker.velocity(vx, vy, wz, duration_s)
            return RPC_OK, ""
    except ValueError:  # ParameterError, or the controller refusing a value
        return RPC_ERR_SERVER_API_PARAMETER, ""
    except NoWalker:
        return RPC_ERR_SERVER_API_NOT_IMPL, ""
    return RPC_ERR_SERVER_API_NOT_IMPL, ""
