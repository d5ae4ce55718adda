"""The topic registry's roles (schemas/topics.py ROLES) are the one home of who writes and reads what.

- Every generated table (protocol, roles, each service's keys) is fresh, and every pattern a role
  lists reaches a topic of its kind.
- Role conformance: each service runs as users run it, with tests/audit/sitecustomize.py on its
  PYTHONPATH recording every declaration its real zenoh session makes (publishers and puts,
  subscribers, queryables, queriers and gets, liveliness tokens, subscribers and queries). Each one
  must be listed by the service's role. Recording the declarations in the process is robust where
  watching the router's denials is not: a declaration is seen whether or not anyone is listening,
  on a plain network, and before any data flows. What the router enforces is checked on a real
  secured router in test_secure.py.
"""

from __future__ import annotations

import asyncio
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import zenoh

from support import REPO, free_port, wait_for
from unitree_sdk import unused_domain_id
from zensim.schemas import generate, topics
from zensim.schemas.keys import Keys
from zensim.schemas.topics import EVERY_ROLE_WATCHES, ROLE_USES, ROLES, Role, includes, intersects, role

AUDIT_DIR = Path(__file__).parent / "audit"
SERVICE_ROLES = {"sim": "sim", "bridge": "bridge", "viz": "viz", "unitree": "unitree", "record": "recorder",
                 "replay": "replay", "loco": "loco"}
"""`zensim <command>` -> the role it runs with (services/*/__main__.py, zensim/record.py, replay.py)."""
FIELD_OF_USE = {"publisher": "publishes", "subscriber": "subscribes", "queryable": "serves", "querier": "queries",
                "token": "tokens"}


# ------------------------------------------------------------------------------------- the registry itself
def test_generated_tables_are_fresh() -> None:
    """Run `python -m zensim.schemas.generate` when this fails (a topic or a role changed)."""
    found: set[str] = set()
    for doc in generate.generated_docs():
        text = doc.read_text()
        assert generate.with_sections(text) == text, f"{doc} is stale"
        found |= set(generate.sections(text))
    service_roles = {f"keys:{r.name}" for r in ROLES if r.kind == "service"}
    # A role whose service is not in this checkout (ros1 until its README lands) has no README yet.
    homeless = {f"keys:{r.name}" for r in ROLES if r.kind == "service" and r.name not in SERVICE_ROLES.values()
                and not (REPO / "services" / r.name / "README.md").is_file()}
    assert {"topics", "roles"} <= found
    assert service_roles - homeless <= found


def test_every_role_pattern_reaches_a_topic_of_its_kind_and_every_topic_has_writers_and_readers() -> None:
    for r in ROLES:
        for _, field, kind in ROLE_USES:
            for pattern in getattr(r, field):
                assert topics.covered_topics(pattern, kind), f"{r.name}.{field} {pattern!r} reaches no {kind}"
    for topic in topics.TOPICS:
        assert topics.writers(topic), f"nobody may write {topic.key}"
        assert topics.readers(topic), f"nobody may read {topic.key}"
    assert len({r.name for r in ROLES}) == len(ROLES)


def test_keys_come_from_the_registry() -> None:
    keys = Keys("r2")
    for topic in topics.TOPICS:
        if topic.name:
            assert getattr(keys, topic.name) == f"zensim/r2/{topic.pattern()}"
    assert keys.mesh_any == "zensim/r2/info/mesh/**" and keys.joint_target_any == "zensim/r2/cmd/joint/*"
    assert keys.ctl("advance") == keys.ctl_advance == "zensim/r2/ctl/advance"


@pytest.mark.parametrize("a, b", [
    ("state/**", "state/joints"), ("state/*", "state/joints"), ("**", "info/mesh/**"), ("info/**", "info/mesh/**"),
    ("info/*", "info/mesh/**"), ("ctl/*", "ctl/**"), ("cmd/joint/*", "cmd/joint/*"), ("state/joints", "state/**"),
    ("alive/*", "alive/sim"), ("a/**/b", "a/x/y/b"), ("a/**/b", "a/b"), ("**/b", "a/c"), ("*", "a/b"),
])
def test_key_matching_agrees_with_zenoh(a: str, b: str) -> None:
    za, zb = zenoh.KeyExpr(a), zenoh.KeyExpr(b)
    assert includes(a, b) == za.includes(zb)
    assert intersects(a, b) == za.intersects(zb) == intersects(b, a)


# ------------------------------------------------------------------------------------- role conformance
def audit_env(audit_dir: Path) -> dict[str, str]:
    path = os.pathsep.join(filter(None, [str(AUDIT_DIR), os.environ.get("PYTHONPATH")]))
    return {"PYTHONPATH": path, "ZENOH_AUDIT_DIR": str(audit_dir)}


def audits(audit_dir: Path) -> dict[str, list[dict]]:
    """`zensim <command>` -> the declarations its process(es) made."""
    found: dict[str, list[dict]] = {}
    for path in audit_dir.glob("*.jsonl"):
        lines = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
        argv = lines[0]["argv"]
        command = argv[argv.index("zensim") + 1] if "zensim" in argv else "script"
        found.setdefault(command, []).extend(lines[1:])
    return found


def violations(r: Role, records: list[dict], robot: str) -> list[str]:
    """Every recorded declaration that role `r` does not list, as readable lines."""
    root = f"zensim/{robot}/"
    wrong = []
    for record in records:
        use, key = record["use"], record["key"].split("?", 1)[0]
        if use.startswith("liveliness_") and key == topics.ROUTER_ALIVE.full_key():
            continue  # every role may watch the router's own token (secure.py, ROUTER_WATCH_RULES)
        allowed = EVERY_ROLE_WATCHES if use.startswith("liveliness_") else getattr(r, FIELD_OF_USE[use])
        if not key.startswith(root) or not any(includes(p, key[len(root):]) for p in allowed):
            wrong.append(f"{r.name}: {use} on {record['key']!r} is not in its role")
    return sorted(set(wrong))


def viz_click(port: int, verb: str) -> None:
    """A panel button, as the page sends it: the viz queries ctl/<verb>."""
    import tornado.websocket

    async def click() -> None:
        conn = await tornado.websocket.websocket_connect(f"ws://127.0.0.1:{port}/ws")
        await conn.write_message(json.dumps({"type": "ctl", "verb": verb}))
        await asyncio.sleep(0.5)
        conn.close()
        while await asyncio.wait_for(conn.read_message(), 10) is not None:  # until the close completes
            pass

    asyncio.run(click())


def test_every_service_declares_only_what_its_role_lists(start_service, zsession, robot_id: str,
                                                           tmp_path: Path) -> None:
    audit_dir = tmp_path / "audit"
    audit_dir.mkdir()
    env = audit_env(audit_dir)
    keys = Keys(robot_id)
    recording = tmp_path / "run.mcap"
    viz_port = free_port()
    sim = start_service("sim", "--mode", "fixed", env=env)
    bridge = start_service("bridge", env=env)
    viz = start_service("viz", "--port", str(viz_port), env=env)
    adapter = start_service("unitree", "--domain-id", str(unused_domain_id()), "--interface", "lo", env=env)
    recorder = start_service("record", "-o", str(recording), env=env)
    walking = start_service("loco", env=env)

    def alive() -> set[str]:
        replies = zsession.liveliness().get(keys.alive_any, timeout=1.0)
        return {str(r.ok.key_expr).rsplit("/", 1)[-1] for r in replies if r.ok is not None}

    wait_for(lambda: alive() >= {"sim", "bridge", "viz", "unitree", "loco"}, 120, "every service alive", 0.3)
    wait_for(lambda: "description of" in viz.log(), 60, "the viz to fetch the description")
    wait_for(lambda: "saved the sim's description" in recorder.log(), 60, "the recorder's description")
    for verb in ("pause", "resume"):  # the viz's querier on ctl/*
        viz_click(viz_port, verb)
    wait_for(lambda: "ctl/resume -> ok=True" in viz.log(), 30, "the viz's ctl queries answered")
    zsession.put(keys.joint_target("left_elbow_joint"), "0.3")  # the bridge publishes its targets
    assert recorder.stop(15) == 0, recorder.log()
    replay = start_service("replay", str(recording), "--robot-id", robot_id + "r", "--rate", "20", env=env)
    wait_for(lambda: replay.proc.poll() is not None, 60, "the replay to finish")
    assert replay.proc.returncode == 0, replay.log()
    for service in (sim, bridge, viz, adapter, walking):
        assert service.alive(), service.log()[-2000:]
        service.stop(15)
    # The lockstep clock's own keys (ctl/advance, state/applied), from a second sim.
    lockstep = start_service("sim", "--mode", "fixed", "--clock", "lockstep", "--robot-id", robot_id + "l", env=env)
    wait_for(lambda: "sim up" in lockstep.log() or not lockstep.alive(), 60, "the lockstep sim")
    assert lockstep.alive(), lockstep.log()
    lockstep.stop(15)

    declared = audits(audit_dir)
    assert set(SERVICE_ROLES) <= set(declared), sorted(declared)
    wrong = []
    for command, role_name in SERVICE_ROLES.items():
        assert declared[command], f"zensim {command} declared nothing: the audit did not run"
        robot = robot_id + "r" if command == "replay" else robot_id
        records = [r for r in declared[command] if f"zensim/{robot_id}l/" not in r["key"]]
        wrong += violations(role(role_name), records, robot)
    wrong += violations(role("sim"), [r for r in declared["sim"] if f"zensim/{robot_id}l/" in r["key"]],
                        robot_id + "l")
    assert not wrong, "\n".join(wrong)
    # The audit saw each kind of use, so an unlisted one of any kind would have been caught.
    seen = {record["use"] for records in declared.values() for record in records}
    assert {"publisher", "subscriber", "queryable", "querier", "token", "liveliness_subscriber"} <= seen, seen
    lockstep_keys = {r["key"] for r in declared["sim"]}
    assert {Keys(robot_id + "l").ctl_advance, Keys(robot_id + "l").applied} <= lockstep_keys, lockstep_keys


def test_a_world_viewer_declares_only_what_the_viz_role_lists(start_service, zsession, robot_id: str,
                                                               tmp_path: Path) -> None:
    """`zensim viz --world`: world/info and the clock's verbs on the world's id, and each robot's keys as for a
    robot alone."""
    from support import TWO_JOINT_ARM

    audit_dir = tmp_path / "audit"
    audit_dir.mkdir()
    ids = {"world": robot_id + "w", "g1": robot_id + "a", "arm": robot_id + "b"}
    (tmp_path / "arm.urdf").write_text(TWO_JOINT_ARM)
    (tmp_path / "world.toml").write_text(f'id = "{ids["world"]}"\n[[robots]]\nid = "{ids["g1"]}"\n'
                                         f'[[robots]]\nid = "{ids["arm"]}"\nurdf = "arm.urdf"\nmode = "fixed"\nxy = [0, 2]\n')
    start_service("sim", "--world", str(tmp_path / "world.toml"))
    viz_port = free_port()
    viz = start_service("viz", "--port", str(viz_port), "--world", ids["world"], env=audit_env(audit_dir))
    wait_for(lambda: "description of world" in viz.log(), 60, "the viz to fetch the world")
    viz_click(viz_port, "pause")  # the world's pause (its robots share one clock), then the robot's reset
    wait_for(lambda: "world/pause -> ok=True" in viz.log(), 30, "the viz's world/pause answered")
    viz_click(viz_port, "reset")
    wait_for(lambda: "ctl/reset -> ok=True" in viz.log(), 30, "the viz's ctl/reset answered")
    viz.stop(15)
    records = audits(audit_dir)["viz"]
    by_root: dict[str, list[dict]] = {}
    for record in records:
        by_root.setdefault(record["key"].split("/")[1], []).append(record)
    assert set(by_root) == set(ids.values()) | {"@router"}, sorted(by_root)
    wrong = [line for robot in ids.values() for line in violations(role("viz"), by_root[robot], robot)]
    assert not wrong, "\n".join(wrong)
    assert {r["key"].split("?")[0] for r in by_root[ids["world"]]} == {Keys(ids["world"]).world_info,
                                                                     Keys(ids["world"]).world_pause}
    assert Keys(ids["g1"]).ctl_reset in {r["key"] for r in by_root[ids["g1"]]}


ROGUE = """
import sys, threading
from zensim.common.session import open_session
from zensim.common.settings import ZenohSettings
from zensim.common.wire import TypedPublisher
from zensim.schemas import topics
from zensim.schemas.keys import Keys

keys = Keys(sys.argv[1])
session = open_session(ZenohSettings(mode="peer", listen=("tcp/127.0.0.1:0",)), role="bridge")
TypedPublisher.of(session, keys, topics.MOTORS)        # listed for the bridge
TypedPublisher.of(session, keys, topics.SIM_STATUS)    # not listed: only the sim (and a replay) write state/sim
session.close()
"""


def test_the_conformance_check_catches_an_undeclared_publisher(tmp_path: Path, robot_id: str) -> None:
    """A bridge-role process that also publishes the sim's status is caught; so is a real viz checked as a viewer."""
    audit_dir = tmp_path / "audit"
    audit_dir.mkdir()
    done = subprocess.run([sys.executable, "-c", ROGUE, robot_id], env={**os.environ, **audit_env(audit_dir)},
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    records = audits(audit_dir)["script"]
    assert {r["key"] for r in records} == {Keys(robot_id).motors, Keys(robot_id).sim_status}
    assert violations(role("bridge"), records, robot_id) == [
        f"bridge: publisher on {Keys(robot_id).sim_status!r} is not in its role"]
    assert violations(role("sim"), records, robot_id) == [
        f"sim: publisher on {Keys(robot_id).motors!r} is not in its role"]


def test_a_world_sim_declares_only_what_the_sim_role_lists(start_service, zsession, robot_id: str,
                                                            tmp_path: Path) -> None:
    """`zensim sim --world`: the world's verbs and token on the world's id, each robot's keys as for a robot alone."""
    audit_dir = tmp_path / "audit"
    audit_dir.mkdir()
    ids = {"world": robot_id + "w", "a": robot_id + "a", "b": robot_id + "b"}
    (tmp_path / "world.toml").write_text(f'id = "{ids["world"]}"\n[[robots]]\nid = "{ids["a"]}"\n'
                                         f'[[robots]]\nid = "{ids["b"]}"\nxy = [1.5, 0]\n')
    world = start_service("sim", "--world", str(tmp_path / "world.toml"), "--mode", "fixed", "--clock", "lockstep",
                          env=audit_env(audit_dir))
    wait_for(lambda: list(zsession.liveliness().get(Keys(ids["world"]).alive("world"), timeout=1.0)), 120,
             "the world up")
    world.stop(15)
    by_root: dict[str, list[dict]] = {}
    for record in audits(audit_dir)["sim"]:
        by_root.setdefault(record["key"].split("/")[1], []).append(record)
    assert set(by_root) - {"@router"} == set(ids.values()), sorted(by_root)
    wrong = [line for robot in ids.values() for line in violations(role("sim"), by_root[robot], robot)]
    assert not wrong, "\n".join(wrong)
    world_keys = {r["key"] for r in by_root[ids["world"]]}
    assert {Keys(ids["world"]).world_advance, Keys(ids["world"]).alive("world")} <= world_keys, world_keys
    assert {Keys(robot).ctl("reset") for robot in (ids["a"], ids["b"])} <= {r["key"] for r in by_root[ids["a"]] + by_root[ids["b"]]}


def test_the_ros1_gateway_declares_only_what_its_role_lists(start_service, zsession, robot_id: str,
                                                             tmp_path: Path) -> None:
    """`zensim ros1` with a real master: its startup declarations, and the puts a ROS controller topic makes."""
    from ros_graph import Roscore

    roscore = Roscore(tmp_path / "ros")
    try:
        audit_dir = tmp_path / "audit"
        audit_dir.mkdir()
        start_service("sim", "--mode", "fixed")
        start_service("bridge")
        gateway = start_service("ros1", "--mesh-http-port", "0", env={**roscore.env, **audit_env(audit_dir)})
        wait_for(lambda: "ros1 gateway up" in gateway.log() or not gateway.alive(), 90, "the gateway to start")
        assert gateway.alive(), gateway.log()
        # A ROS controller command: the gateway puts it on the robot's cmd/joint/{joint}.
        topic = f"/{robot_id}_description/left_elbow_joint_controller/command"
        subprocess.run(["rostopic", "pub", "-1", topic, "std_msgs/Float64", "data: 0.3"], env={**os.environ, **roscore.env},
                       capture_output=True, timeout=60, check=True)
        assert gateway.stop(15) == 0, gateway.log()
    finally:
        roscore.stop()
    records = audits(audit_dir)["ros1"]
    assert not violations(role("ros1"), records, robot_id), "\n".join(violations(role("ros1"), records, robot_id))
    uses = {r["use"] for r in records}
    assert {"publisher", "subscriber", "querier", "token"} <= uses, uses
    assert any(r["key"].startswith(f"zensim/{robot_id}/cmd/joint") for r in records if r["use"] == "publisher")
