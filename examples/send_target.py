"""Send a joint target through the bridge (cmd/joints): it slews there and holds it.

The bridge turns targets into motor commands with the robot's gains, limited in speed and clamped to
the joint's range; what it did is on state/targets, and anything it refused on report/bridge.

    python examples/send_target.py left_elbow_joint 0.9
"""

from __future__ import annotations

import json

import zenoh


def main(conf: zenoh.Config, robot: str, joint: str, q: float) -> None:
    with zenoh.open(conf) as session:
        # JSON text needs no encoding flag; the field names are JointTargets' (docs/protocol.md).
        session.put(f"zensim/{robot}/cmd/joints", json.dumps({"names": [joint], "q": [q]}))
        # The same, for one joint, as a bare number: session.put(f"zensim/{robot}/cmd/joint/{joint}", str(q))
        print(f"target {joint} = {q} rad sent")


if __name__ == "__main__":
    import argparse

    import common

    parser = argparse.ArgumentParser(prog="send_target", description=__doc__.split("\n")[0])
    common.add_config_arguments(parser)
    parser.add_argument("joint", help="a joint name (info/robot's joint_names)")
    parser.add_argument("q", type=float, help="its target position, rad")
    args = parser.parse_args()
    main(common.get_config_from_args(args), args.robot, args.joint, args.q)
