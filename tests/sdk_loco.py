"""A G1 program written with Unitree's own SDK (unitree_sdk2_python's LocoClient), driven line by line.

    python tests/sdk_loco.py DOMAIN
stdin, one call per line: a LocoClient method and its arguments as JSON, e.g. `["Move", 0.3, 0, 0, true]`,
`["SetFsmId", 706]`, `["GetFsmId"]`, or `["odommodestate"]` (the newest rt/odommodestate); stdout: one JSON line per call, `{"result": ...}` (what the SDK
method returned: a code, or [code, data]). Tests run it as a separate process because the SDK's channel
factory is one per process, on one DDS domain.
"""

import json
import sys

from unitree_sdk2py.core.channel import ChannelFactoryInitialize, ChannelSubscriber
from unitree_sdk2py.g1.loco.g1_loco_client import LocoClient
from unitree_sdk2py.idl.unitree_go.msg.dds_ import SportModeState_

latest: list = []


def on_odom(message: SportModeState_) -> None:
    latest[:] = [message]


def main() -> None:
    ChannelFactoryInitialize(int(sys.argv[1]), "lo")
    client = LocoClient()
    client.SetTimeout(10.0)
    client.Init()
    odom = ChannelSubscriber("rt/odommodestate", SportModeState_)
    odom.Init(on_odom, 1)
    print(json.dumps({"ready": True}), flush=True)
    for line in sys.stdin:
        name, *args = json.loads(line)
        if name == "odommodestate":  # the newest SportModeState_, as the SDK's own type reads it
            m = latest[0] if latest else None
            result = None if m is None else {"position": list(m.position), "velocity": list(m.velocity),
                                            "mode": m.mode, "sec": m.stamp.sec, "nanosec": m.stamp.nanosec,
                                            "yaw": m.imu_state.rpy[2], "foot_force": list(m.foot_force)}
        else:
            result = getattr(client, name)(*args)
        print(json.dumps({"result": result}), flush=True)


if __name__ == "__main__":
    main()
