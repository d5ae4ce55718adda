"""Settings: defaults < ZENSIM_* environment < flags, with errors that name the setting."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from zensim.bridge.settings import BridgeSettings
from zensim.check import CheckSettings
from zensim.common.settings import AMBIGUOUS_LEGACY, CommonSettings, SettingsError, env_names, load_settings
from zensim.router import RouterSettings
from zensim.sim.settings import SimSettings
from zensim.unitree.settings import UnitreeSettings
from zensim.up import UpSettings
from zensim.viz.settings import VizSettings

SERVICE_SETTINGS = (SimSettings, BridgeSettings, VizSettings, RouterSettings, CheckSettings, UpSettings, UnitreeSettings)
"""Every command's settings: a new command adds its struct here."""
COMMON_NAMES = set(env_names(CommonSettings)) | {"ZENSIM_LOG_LEVEL"}


def test_defaults() -> None:
    settings = load_settings(SimSettings, [], env={})
    assert settings.robot_id == "g1"
    assert settings.mode == "floating"
    assert settings.zenoh.mode == "peer"


def test_environment_then_flags() -> None:
    env = {"ZENSIM_MODE": "fixed", "ZENSIM_RTF": "2.5", "ZENSIM_ZENOH_CONNECT": "tcp/a:1, tcp/b:2",
           "ZENSIM_ZENOH_MULTICAST_SCOUTING": "false"}
    settings = load_settings(SimSettings, ["--rtf", "0"], env=env)
    assert settings.mode == "fixed"
    assert settings.rtf == 0.0
    assert settings.zenoh.connect == ("tcp/a:1", "tcp/b:2")
    assert settings.zenoh.multicast_scouting is False


def test_nested_defaults_survive_a_sibling_setting() -> None:
    # The router's nested default (mode router, where ZenohSettings says peer) outlives a sibling flag.
    settings = load_settings(RouterSettings, ["--zenoh-multicast-scouting", "true"], env={})
    assert settings.zenoh.mode == "router" and settings.zenoh.multicast_scouting is True


def test_secure_dir_is_one_setting_for_every_service() -> None:
    """`--secure-dir` / `ZENSIM_SECURE_DIR` (no zenoh prefix) reaches the nested zenoh settings."""
    assert load_settings(RouterSettings, ["--secure-dir", "/a"], env={}).zenoh.secure_dir == "/a"
    assert load_settings(RouterSettings, [], env={"ZENSIM_SECURE_DIR": "/b"}).zenoh.secure_dir == "/b"
    assert load_settings(RouterSettings, [], env={}).zenoh.multicast_scouting is False


@pytest.mark.parametrize(
    "argv, env, needle",
    [
        (["--mode", "flying"], {}, "--mode"),
        ([], {"ZENSIM_ZENOH_MODE": "bogus"}, "ZENSIM_ZENOH_MODE"),
        (["--rtf", "fast"], {}, "--rtf"),
        (["--rtf", "-1"], {}, "rtf"),
    ],
)
def test_bad_values_name_the_setting(argv: list[str], env: dict[str, str], needle: str) -> None:
    with pytest.raises(SettingsError) as info:
        load_settings(SimSettings, argv, env=env)
    assert needle in str(info.value)


def test_unknown_flag_exits() -> None:
    with pytest.raises(SystemExit):
        load_settings(SimSettings, ["--no-such-flag", "1"], env={})


class TestPerServiceNames:
    """Shared settings keep one name; a service's own fields carry its prefix; old names fade out."""

    def test_own_fields_carry_the_service_prefix(self) -> None:
        env = {"ZENSIM_SIM_MODE": "fixed", "ZENSIM_SIM_RTF": "2.5", "ZENSIM_ROBOT_ID": "r2", "ZENSIM_LOG_LEVEL": "DEBUG"}
        settings = load_settings(SimSettings, [], env=env)
        assert (settings.mode, settings.rtf, settings.robot_id, settings.log_level) == ("fixed", 2.5, "r2", "DEBUG")

    def test_a_service_ignores_another_services_variables(self) -> None:
        assert load_settings(BridgeSettings, [], env={"ZENSIM_VIZ_RATE_HZ": "30"}).rate_hz == 100.0
        assert load_settings(VizSettings, [], env={"ZENSIM_BRIDGE_RATE_HZ": "500"}).rate_hz == 60.0

    def test_first_release_names_still_work_with_a_warning(self, caplog: pytest.LogCaptureFixture) -> None:
        settings = load_settings(SimSettings, [], env={"ZENSIM_MODE": "fixed"})
        assert settings.mode == "fixed"
        assert "ZENSIM_MODE is deprecated" in caplog.text and "ZENSIM_SIM_MODE" in caplog.text
        # The new name wins over the old one.
        assert load_settings(SimSettings, [], env={"ZENSIM_MODE": "fixed", "ZENSIM_SIM_MODE": "floating"}).mode == "floating"

    def test_names_that_were_never_released_have_no_unprefixed_alias(self) -> None:
        # compose's build switch ZENSIM_UNITREE=1 turned on `zensim up --unitree` through an invented alias.
        assert load_settings(UpSettings, [], env={"ZENSIM_UNITREE": "1", "ZENSIM_ROS1": "1"}) == UpSettings()
        assert load_settings(VizSettings, [], env={"ZENSIM_TOKEN": "guess", "ZENSIM_WORLD": "lab"}) == VizSettings()
        assert load_settings(SimSettings, [], env={"ZENSIM_CLOCK": "lockstep"}).clock == "realtime"
        assert "ZENSIM_UNITREE" not in env_names(UpSettings).values()

    @pytest.mark.parametrize("cls", [BridgeSettings, VizSettings])
    def test_a_name_two_services_read_differently_is_refused(self, cls: type) -> None:
        with pytest.raises(SettingsError) as info:
            load_settings(cls, [], env={"ZENSIM_RATE_HZ": "500"})
        assert "ZENSIM_BRIDGE_RATE_HZ" in str(info.value) and "ZENSIM_VIZ_RATE_HZ" in str(info.value)

    def test_the_ambiguous_table_is_exactly_the_shared_old_names(self) -> None:
        readers: dict[str, set[str]] = {}
        for cls in SERVICE_SETTINGS:
            for new, legacy in env_names(cls).items():
                if legacy:
                    readers.setdefault(legacy, set()).add(new)
        shared = {legacy: news for legacy, news in readers.items() if len(news) > 1}
        assert {k: set(v) for k, v in AMBIGUOUS_LEGACY.items()} == shared

    def test_no_two_services_share_a_variable_but_the_common_ones(self) -> None:
        seen: dict[str, type] = {}
        for cls in SERVICE_SETTINGS:
            for name in env_names(cls):
                if name in seen:
                    assert name in COMMON_NAMES, f"{name} read by {seen[name].__name__} and {cls.__name__}"
                seen[name] = cls


@pytest.mark.parametrize("cls, argv", [
    (SimSettings, ["--state-rate-hz", "1e-300"]),
    (SimSettings, ["--status-rate-hz", "1e-300"]),
    (SimSettings, ["--rtf", "1e-300"]),
    (SimSettings, ["--timestep-s", "1e-300"]),
    (SimSettings, ["--watchdog-timeout-s", "1e-300"]),
    (BridgeSettings, ["--targets-rate-hz", "1e-300"]),
    (BridgeSettings, ["--info-timeout-s", "1e-300"]),
    (VizSettings, ["--rate-hz", "1e-300"]),
    (UnitreeSettings, ["--status-rate-hz", "1e-300"]),
    (RouterSettings, ["--cmd-rate-limit-hz", "1e-300"]),
    (CheckSettings, ["--timeout-s", "1e-300"]),
])
def test_rates_and_timeouts_below_a_sane_floor_are_refused(cls: type, argv: list[str]) -> None:
    """A tiny positive rate passed a `> 0` check and a service never published again (issue 18)."""
    with pytest.raises(SettingsError) as info:
        load_settings(cls, argv, env={})
    assert argv[0] in str(info.value), str(info.value)


@pytest.mark.parametrize("cls, argv", [
    (SimSettings, ["--rtf", "0"]), (BridgeSettings, ["--targets-rate-hz", "0"]),
    (RouterSettings, ["--cmd-rate-limit-hz", "0"]),
])
def test_zero_still_means_off_or_unbounded(cls: type, argv: list[str]) -> None:
    load_settings(cls, argv, env={})


@pytest.mark.parametrize("command", ["sim", "record"])
def test_an_absurdly_long_robot_id_is_one_clear_line_at_startup(command: str, router_endpoint: str) -> None:
    """Issue 27 item 7: a 100 000-character robot id made zenoh panic (a Rust panic and a Python traceback)."""
    env = dict(os.environ, ZENSIM_ZENOH_MODE="client", ZENSIM_ZENOH_CONNECT=router_endpoint)
    result = subprocess.run([sys.executable, "-m", "zensim", command, "--robot-id", "a" * 100_000],
                            capture_output=True, text=True, timeout=60, env=env)
    lines = (result.stdout + result.stderr).strip().splitlines()
    assert result.returncode == 2, (result.returncode, [line[:200] for line in lines[-5:]])
    assert len(lines) == 1 and len(lines[0]) < 200 and "at most 64" in lines[0], [line[:200] for line in lines[-5:]]
