"""Answers to Unitree's motion-switcher service (`rt/api/motion_switcher/*`), without DDS.

On the robot the motion switcher owns the high-level controllers (sport/ai modes); the SDK's
low-level examples ask it which mode is active (CheckMode) and release that mode (ReleaseMode)
before they send LowCmd_. zensim runs no high-level controller, so:

    1      API version     0, "1.0.0.1"
    1001   CheckMode       0, {"form": "0", "name": ""}   (no mode active)
    1002   SelectMode      3203 (not implemented: there is no high-level mode to select)
    1003   ReleaseMode     0, ""                          (nothing to release: succeeds)
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


def answer(api_id: int) -> tuple[int, str]:
    """The (status code, data) the motion switcher answers to a request for `api_id`."""
    if api_id == API_ID_VERSION:
        return RPC_OK, API_VERSION
    if api_id == API_ID_CHECK_MODE:
        return RPC_OK, json.dumps({"form": "0", "name": ""})
    if api_id == API_ID_RELEASE_MODE:
        return RPC_OK, ""
    if api_id == API_ID_GET_SILENT:
        return RPC_OK, json.dumps({"silent": False})
    return RPC_ERR_SERVER_API_NOT_IMPL, ""
