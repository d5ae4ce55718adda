"""Record every sample of a robot into an MCAP file (Foxglove, the mcap CLI), as `zensim record` does.

A subscriber on zensim/{robot}/** sees every publication of that robot; each key becomes an MCAP
channel whose message encoding is the sample's (msgpack or JSON). `zensim record` does more (the
robot's description attached, lockstep commands for `zensim resim`): use it for real work.

    python examples/record.py -o run.mcap --seconds 5
"""

from __future__ import annotations

import queue
import time

import zenoh
from mcap.writer import Writer


def main(conf: zenoh.Config, robot: str, path: str, seconds: float) -> None:
    samples: queue.Queue[tuple[str, str, bytes, int]] = queue.Queue()
    with zenoh.open(conf) as session, open(path, "wb") as stream:
        writer = Writer(stream)
        writer.start(profile="", library="zensim examples/record.py")
        channels: dict[str, int] = {}

        def write(key: str, encoding: str, payload: bytes, now_ns: int) -> None:
            if key not in channels:
                schema = writer.register_schema(name="", encoding="", data=b"")
                channels[key] = writer.register_channel(topic=key, message_encoding=encoding.split(";")[0], schema_id=schema)
            writer.add_message(channels[key], log_time=now_ns, publish_time=now_ns, data=payload)

        # The callback only queues (zenoh's thread must not wait on the file); this thread writes.
        subscriber = session.declare_subscriber(f"zensim/{robot}/**", lambda s: samples.put(
            (str(s.key_expr), str(s.encoding), s.payload.to_bytes(), time.time_ns())))
        end = time.monotonic() + seconds
        count = 0
        while time.monotonic() < end:
            try:
                write(*samples.get(timeout=0.1))
                count += 1
            except queue.Empty:
                pass
        subscriber.undeclare()
        while not samples.empty():  # what came before the subscriber was closed
            write(*samples.get_nowait())
            count += 1
        writer.finish()
    print(f"wrote {count} samples on {len(channels)} keys to {path}")


if __name__ == "__main__":
    import argparse

    import common

    parser = argparse.ArgumentParser(prog="record", description=__doc__.split("\n")[0])
    common.add_config_arguments(parser)
    parser.add_argument("-o", "--output", default="zensim.mcap", help="the MCAP file to write")
    parser.add_argument("--seconds", type=float, default=10.0, help="how long to record")
    args = parser.parse_args()
    main(common.get_config_from_args(args), args.robot, args.output, args.seconds)
