"""Read the robot's states: joint positions (state/joints) and the sim's status (state/sim).

States are msgpack maps with field names (JSON when a sample's encoding says so); the joint order is
info/robot's `joint_names`, asked once at start.

    python examples/read_states.py --count 5
"""

from __future__ import annotations

import json
import queue

import msgspec
import zenoh


def decode(sample: zenoh.Sample) -> dict:
    """A state as a dict, whichever encoding the sample carries."""
    payload = sample.payload.to_bytes()
    return json.loads(payload) if "json" in str(sample.encoding) else msgspec.msgpack.decode(payload)


def main(conf: zenoh.Config, robot: str, count: int) -> None:
    with zenoh.open(conf) as session:
        info = json.loads(next(iter(session.get(f"zensim/{robot}/info/robot?format=json", timeout=10))).ok.payload.to_bytes())
        names = info["joint_names"]
        print(f"{robot}: {len(names)} joints, mode {info['mode']}")
        states: queue.Queue[dict] = queue.Queue()
        with session.declare_subscriber(f"zensim/{robot}/state/joints", lambda sample: states.put(decode(sample))):
            for _ in range(count):
                state = states.get(timeout=10)
                print(f"t={state['sim_time_s']:.3f} s seq={state['seq']} {names[0]}={state['q'][0]:+.3f} rad")
        # A subscriber with a channel instead of a callback: receive where you want to.
        with session.declare_subscriber(f"zensim/{robot}/state/sim", zenoh.handlers.FifoChannel(4)) as status_sub:
            status = decode(status_sub.recv())  # the sim's status comes ~10 times a second
        print(f"status: rtf={status['rtf']:.2f} paused={status['paused']} fallen={status['fallen']}")


if __name__ == "__main__":
    import argparse

    import common

    parser = argparse.ArgumentParser(prog="read_states", description=__doc__.split("\n")[0])
    common.add_config_arguments(parser)
    parser.add_argument("--count", "-n", type=int, default=10, help="how many joint states to print")
    args = parser.parse_args()
    main(common.get_config_from_args(args), args.robot, args.count)
