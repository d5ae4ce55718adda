"""Settings: defaults < ZENSIM_* environment < flags, with errors that name the setting."""

from __future__ import annotations

import pytest

from zensim.common.settings import SettingsError, load_settings
from zensim.router import RouterSettings
from zensim.sim.settings import SimSettings


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
