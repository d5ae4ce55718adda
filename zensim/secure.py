"""`zensim secure init DIR`: make the credentials and Zenoh configs of a secured zensim network.

    zensim secure init secrets --host sim-host.lan --host 192.168.1.20
    zensim up --secure-dir secrets           # router + services over TLS with roles
    zensim secure init secrets --robots operator=a --robots viewer=a,b   # credentials scoped to robots
    zensim secure init secrets --client alice=operator:a --client bob=operator:b   # one more credential each
    # any Zenoh client: load secrets/operator.json5 (or viewer.json5) and add connect/endpoints

The folder's layout and the roles are described in services/common/secure.py and docs/security.md.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from zensim.common.secure import DEFAULT_HOSTS, DEFAULT_ROS_DOMAINS, Client, SecureConfigError, init
from zensim.common.settings import ROUTER_PORT, SECURE_LOCAL_ROUTER_ENDPOINT
from zensim.schemas.topics import ROLE_NAMES


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="zensim secure", description=__doc__.split("\n\n")[0])
    commands = parser.add_subparsers(dest="command", required=True)
    make = commands.add_parser("init", help="make a CA, certificates, passwords and the role configs in DIR")
    make.add_argument("dir", type=Path, help="a new (or empty) folder; keep it private")
    make.add_argument("--host", action="append", default=[],
                      help=f"a DNS name or IP the router is reached at (repeatable; always: {', '.join(DEFAULT_HOSTS)})")
    make.add_argument("--listen", action="append", default=[],
                      help=f"the router's default tls/ listen endpoint (repeatable; default {SECURE_LOCAL_ROUTER_ENDPOINT})")
    make.add_argument("--days", type=int, default=825, help="certificate lifetime in days (default 825)")
    make.add_argument("--robots", action="append", default=[], metavar="ROLE=ID[,ID...]",
                      help="the robot ids a role's credential may act on (repeatable, e.g. operator=a; "
                           "default: every robot)")
    make.add_argument("--client", action="append", default=[], metavar="NAME=ROLE[:ID,...]",
                      help="one more credential, NAME.json5, with a client role's rules on its own robots (repeatable, "
                           "e.g. alice=operator:a; no ids: every robot): several people on one router, each "
                           "with robots of their own")
    make.add_argument("--ros-domain", action="append", type=int, default=[], metavar="N",
                      help="a ROS domain whose rmw_zenoh keys `zensim ros2` and ROS 2 nodes may use (repeatable; "
                           "default 0; docs/ros.md)")
    args = parser.parse_args(list(argv) if argv is not None else None)
    listen = tuple(args.listen) or (SECURE_LOCAL_ROUTER_ENDPOINT,)
    bad = [e for e in listen if not e.startswith("tls/")]
    if bad:
        print(f"zensim secure: --listen takes tls/ endpoints, not {', '.join(bad)}", file=sys.stderr)
        return 2
    robots: dict[str, tuple[str, ...]] = {}
    for scope in args.robots:
        name, _, ids = scope.partition("=")
        robots[name.strip()] = tuple(i.strip() for i in ids.split(",") if i.strip())
        if not robots[name.strip()]:
            print(f"zensim secure: --robots takes ROLE=ID[,ID...], not {scope!r}", file=sys.stderr)
            return 2
    clients = []
    for given in args.client:
        name, _, rest = given.partition("=")
        its_role, _, ids = rest.partition(":")
        if not name.strip() or not its_role.strip():
            print(f"zensim secure: --client takes NAME=ROLE[:ID,...], not {given!r}", file=sys.stderr)
            return 2
        clients.append(Client(name.strip(), its_role.strip(), tuple(i.strip() for i in ids.split(",") if i.strip())))
    try:
        bad_domains = [d for d in args.ros_domain if not 0 <= d <= 232]
        if bad_domains:
            raise SecureConfigError(f"a ROS domain is 0 to 232, not {bad_domains[0]}")
        init(args.dir, tuple(args.host), listen, args.days, robots, tuple(args.ros_domain) or DEFAULT_ROS_DOMAINS,
             clients)
    except SecureConfigError as exc:
        print(f"zensim secure: {exc}", file=sys.stderr)
        return 2
    named = f"; named clients: {', '.join(c.name for c in clients)}" if clients else ""
    print(f"wrote {args.dir}: router.json5, users.txt, ca.pem and one config per role ({', '.join(ROLE_NAMES)}){named}")
    print(f"run:      zensim up --secure-dir {args.dir}")
    print(f"clients:  zenoh.Config.from_file('{args.dir}/operator.json5') + connect/endpoints "
          f"[\"tls/<router host>:{ROUTER_PORT}\"]")
    return 0


if __name__ == "__main__":
    sys.exit(main())
