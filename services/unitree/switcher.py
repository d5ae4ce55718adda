"""Answers to Unitree's motion-switcher service (`rt/api/motion_switcher/*`), without DDS.

On the robot the motion switcher owns the high-level controllers (sport/ai modes); the SDK's
low-level examples ask it which mode is active (CheckMode) and release that mode (ReleaseMode)
before they send LowCmd_. zensim's one high-level controller is the adapter's locomotion controller
(loco.py, the "sport" service), so:

    1      API version     0, "1.0.0.1"
    1001   CheckMode       0, {"form": "0", "name": ""}   (no mode active), or "name": "sport" while the
                           locomotion controller drives the robot (a name of zensim's choosing: any
                           non-empty name makes the SDK's examples call ReleaseMode)
    1002   SelectMode      3203 (not implemented: the locomotion controller starts with a sport request)
    1003   ReleaseMode     0, ""                          (stops the locomotion controller, if it runs)
    1005   GetSilent       0, {"silent": false}
    other                  3203 (not implemented)

Codes are the SDK's RPC codes (0 ok, 3203 RPC_ERR_SERVER_API_NOT_IMPL).
"""

from __future__ import annotations

import json
from typing import Final

API_VERSION: Final = "1.0.0.1"
RPC_OK: Final = 0
RPC_ERR_SERVER_API_NOT_IMPL: Final = 3203

API_ID_VERSION: Final = 1
API_ID_CHECK_MODE: Final = 1001
API_ID_SELECT_MODE: Final = 1002
API_ID_RELEASE_MODE: Final = 1003
API_ID_GET_SILENT: Final = 1005


ACTIVE_MODE_NAME: Final = "sport"


def answer(api_id: int, active: bool = False) -> tuple[int, str]:
    """The (status code, data) the motion switcher answers to a request for `api_id`.

    Args:
        api_id: the request's API id.
        active: whether the locomotion controller drives the robot (CheckMode names it then).
    """
    if api_id == API_ID_VERSION:
        return RPC_OK, API_VERSION
    if api_id == API_ID_CHECK_MODE:
        return RPC_OK, json.dumps({"form": "0", "name": ACTIVE_MODE_NAME if active else ""})
    if api_id == API_ID_RELEASE_MODE:
        return RPC_OK, ""
    if api_id == API_ID_GET_SILENT:
        return RPC_OK, json.dumps({"silent": False})
    return RPC_ERR_SERVER_API_NOT_IMPL, ""
