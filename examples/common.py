"""Zenoh session flags shared by the examples, as zenoh-python's examples/common.py does.

Every example opens a plain zenoh session (no zensim import): what a client in any language does.
By default it joins a router on this machine (`zensim up` or `zensim router`, tcp/127.0.0.1:7447) as a
client, with multicast scouting off; `--connect` names another, `--config` a zenoh config file (a
secured network's operator.json5, made by `zensim secure init`).
"""

from __future__ import annotations

import argparse
import json

import zenoh


def add_config_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--connect", "-e", action="append", default=[], metavar="ENDPOINT",
                        help="a router to connect to (repeatable; default tcp/127.0.0.1:7447)")
    parser.add_argument("--config", "-c", metavar="FILE", help="a zenoh config file (e.g. a secured network's operator.json5)")
    parser.add_argument("--robot", "-r", default="g1", help="the robot id: keys are zensim/{robot}/... (default g1)")


def get_config_from_args(args: argparse.Namespace) -> zenoh.Config:
    conf = zenoh.Config.from_file(args.config) if args.config else zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    if args.connect or not args.config:
        conf.insert_json5("connect/endpoints", json.dumps(args.connect or ["tcp/127.0.0.1:7447"]))
    return conf
