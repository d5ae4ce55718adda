"""Each fact has one home; the places that cannot import it (compose files, the README) are checked against it.

The homes: the services in `zensim.schemas.keys.SERVICES` (and which are optional), the modes in
`zensim.schemas.MODES` (from the `Mode` type), the router's port in `zensim.common.settings.ROUTER_PORT`.
A new service that is missing from one of the places a user meets it fails here, naming the place.
"""

from __future__ import annotations

import re
import subprocess
import sys
from typing import get_args

import yaml

from support import REPO
from zensim.cli import COMMANDS, LONG_RUNNING
from zensim.common.settings import LOCAL_ROUTER_ENDPOINT, ROUTER_PORT
from zensim.schemas import MODES, Mode
from zensim.schemas.keys import OPTIONAL_SERVICES, SERVICES
from zensim.schemas.topics import ROLES
from zensim.up import SETTINGS_OF, settings_of


def test_every_service_is_a_command_with_a_role_of_its_own() -> None:
    service_roles = {role.name for role in ROLES if role.kind == "service"}
    for service in SERVICES:
        assert service in COMMANDS, f"`zensim {service}` is not a command (zensim/cli.py COMMANDS)"
        if service != "router":  # the router is the one that enforces the roles
            assert service in service_roles, f"{service} has no Role in schemas/topics.py ROLES"
            assert any(f"alive/{service}" in role.tokens for role in ROLES if role.name == service)
    assert LONG_RUNNING == set(SERVICES)
    assert set(SETTINGS_OF) == set(SERVICES) and all(settings_of(service) for service in SERVICES)
    assert set(OPTIONAL_SERVICES) < set(SERVICES)


def test_compose_runs_the_services_zensim_up_runs() -> None:
    compose = yaml.safe_load((REPO / "compose.yaml").read_text())["services"]
    zensim_services = {name for name, service in compose.items() if service.get("entrypoint") is None}
    default = [name for name in compose if "profiles" not in compose[name]]
    assert zensim_services == set(SERVICES), "compose.yaml's zensim services are keys.SERVICES"
    assert default == [s for s in SERVICES if s not in OPTIONAL_SERVICES], "compose's default services, in order"
    for name in OPTIONAL_SERVICES:
        assert compose[name]["profiles"][0] == name  # the walking controller also comes with `unitree`
    secure = yaml.safe_load((REPO / "compose.secure.yaml").read_text())["services"]
    assert set(secure) <= set(SERVICES)


def test_the_readme_lists_every_service() -> None:
    readme = (REPO / "README.md").read_text()
    table = re.findall(r"^\| (\w+) \| `zensim (\w+)` \|", readme, re.MULTILINE)
    assert [name for name, _ in table] == list(SERVICES)
    assert all(name == command for name, command in table)


def test_modes_and_the_router_port_have_one_home() -> None:
    assert MODES == get_args(Mode) == ("floating", "fixed")
    page = (REPO / "services" / "viz" / "static" / "index.html").read_text()
    selector = re.search(r'<select id="mode">(.*?)</select>', page, re.DOTALL)
    assert selector and tuple(re.findall(r'<option value="(\w+)">', selector.group(1))) == MODES, "the page's mode selector"
    assert LOCAL_ROUTER_ENDPOINT.endswith(f":{ROUTER_PORT}")
    # What a user reads in --help comes from the same place.
    result = subprocess.run([sys.executable, "-m", "zensim", "secure", "init", "--help"], capture_output=True,
                            text=True, timeout=60, cwd=REPO)
    assert f"tls/127.0.0.1:{ROUTER_PORT}" in result.stdout, result.stdout + result.stderr
    result = subprocess.run([sys.executable, "-m", "zensim", "robot", "build", "--help"], capture_output=True,
                            text=True, timeout=60, cwd=REPO)
    assert "{floating,fixed}" in result.stdout, result.stdout + result.stderr


def test_the_walking_controller_takes_the_squat_and_leg_gains_from_the_robots_control_file(tmp_path) -> None:
    """walking.toml does not copy control.toml: a robot folder whose spawn squat or floating leg gains change
    walks with the new ones (the controller's stand-up ramps to the pose the sim spawns in)."""
    import numpy as np

    from zensim.robots import BUNDLED_DIR
    from zensim.robots.walking import load_walking

    bundled = BUNDLED_DIR / "unitree_g1"
    walking = load_walking(bundled / "walking.toml")
    knee = walking.joints.index("left_knee_joint")
    assert walking.squat_q[knee] == 0.9 and walking.ramp_kp[knee] == 1000.0  # control.toml's [pose], [floating]
    (tmp_path / "walking.toml").write_text((bundled / "walking.toml").read_text())
    control = (bundled / "control.toml").read_text()
    assert '"*_knee_joint" = 0.9' in control and "kp = 1000.0" in control
    (tmp_path / "control.toml").write_text(control.replace('"*_knee_joint" = 0.9', '"*_knee_joint" = 0.7')
                                           .replace("kp = 1000.0", "kp = 800.0", 1))
    changed = load_walking(tmp_path / "walking.toml")
    assert changed.squat_q[knee] == 0.7 and changed.ramp_kp[knee] == 800.0
    assert np.array_equal(changed.walk_kp, walking.walk_kp)  # the policy's own gains stay the policy's
