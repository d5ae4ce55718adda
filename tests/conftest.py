"""Shared fixtures: the official G1, a Zenoh router on a free loopback port, real service processes,
and a plain zenoh session in the test process."""

from __future__ import annotations

import os
import sys
import time
import uuid
from collections.abc import Callable, Generator, Iterator
from pathlib import Path

import pytest
import zenoh

from browser import Browser, chromium_binary
from support import Service, free_port, plain_client, wait_for


@pytest.fixture(autouse=True, scope="module")
def _close_dds_clients_after_each_module() -> Iterator[None]:
    """Close the DDS clients a test module opened, when it ends: a Cyclone domain left open in this process
    keeps its receive threads on their sockets through every later test, and in one CI run such a thread
    spun on `recvmsg ... retcode -52` (EAGAIN) from the viewer's tests on (29 616 lines, a core burnt)."""
    yield
    sdk = sys.modules.get("unitree_sdk")
    if sdk is not None:
        for client in list(sdk.OPEN_CLIENTS):
            client.close()


def pytest_sessionfinish(session: pytest.Session) -> None:
    """Close the DDS clients tests opened in this process (tests/unitree_sdk.py says why), while the
    interpreter is still whole: left to its exit, Cyclone's receive thread spun on their closed sockets."""
    sdk = sys.modules.get("unitree_sdk")
    if sdk is not None:
        for client in list(sdk.OPEN_CLIENTS):
            client.close()


CONFIG: pytest.Config | None = None


def pytest_configure(config: pytest.Config) -> None:
    global CONFIG
    CONFIG = config


SESSION_START = time.monotonic()
STARTED_FILES: set[str] = set()


@pytest.hookimpl(trylast=True)
def pytest_runtest_logstart(nodeid: str, location: tuple) -> None:
    """Each file's progress line starts with the minutes since the session began (after pytest's file name):
    a CI log cut off by its time limit then shows where the time went."""
    file = nodeid.split("::", 1)[0]
    if file in STARTED_FILES or CONFIG is None:
        return
    STARTED_FILES.add(file)
    reporter = CONFIG.pluginmanager.get_plugin("terminalreporter")
    if reporter is not None and CONFIG.option.verbose == 0:  # the file-name lines (-q has none, -v its own)
        reporter.write(f"[{(time.monotonic() - SESSION_START) / 60:4.1f} min] ")


FILE_SECONDS: dict[str, float] = {}
"""Seconds spent per test file (setup, call and teardown of its tests), for the summary below."""


def pytest_runtest_logreport(report: pytest.TestReport) -> None:
    file = report.nodeid.split("::", 1)[0]
    FILE_SECONDS[file] = FILE_SECONDS.get(file, 0.0) + report.duration


def pytest_terminal_summary(terminalreporter) -> None:  # noqa: ANN001 - pytest's TerminalReporter
    """Where the suite's time goes by file (issue 25's CI time): the 15 costliest files and their share."""
    total = sum(FILE_SECONDS.values())
    if total < 60:  # a run of a few tests: nothing to learn
        return
    terminalreporter.section("slowest 15 test files")
    for file, seconds in sorted(FILE_SECONDS.items(), key=lambda item: item[1], reverse=True)[:15]:
        terminalreporter.write_line(f"{seconds:8.1f}s {100 * seconds / total:5.1f}%  {file}")


@pytest.fixture(scope="session")
def official_g1_dir() -> Path:
    """Unitree's own g1_description folder (URDF + meshes), from env ZENSIM_OFFICIAL_G1.

    Unset: the test is skipped. Set but incomplete: the test fails, because a CI that sets it
    means to run these checks.
    """
    value = os.environ.get("ZENSIM_OFFICIAL_G1")
    if not value:
        pytest.skip("ZENSIM_OFFICIAL_G1 is not set")
    folder = Path(value).resolve()
    missing = [p for p in (folder / "g1_29dof.urdf", folder / "meshes") if not p.exists()]
    if missing:
        pytest.fail(f"ZENSIM_OFFICIAL_G1={value} lacks {', '.join(map(str, missing))}")
    return folder


@pytest.fixture
def browser() -> Iterator[Browser]:
    """A headless chromium page, 1280x800 (the viz's screenshots and clicks); chromium missing fails the test."""
    if chromium_binary() is None:
        pytest.fail("chromium is needed: apt-get install -y --no-install-recommends chromium")
    with Browser(width=1280, height=800) as b:
        yield b


@pytest.fixture
def robot_id() -> str:
    """A robot id unique to this test, so tests never see each other's traffic."""
    return "t" + uuid.uuid4().hex[:10]


@pytest.fixture
def router_endpoint(tmp_path: Path) -> Iterator[str]:
    """A zensim router on its own loopback port, as `zensim router` runs it."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    env = dict(os.environ, ZENSIM_ZENOH_LISTEN=endpoint, ZENSIM_ZENOH_MULTICAST_SCOUTING="false")
    router = Service("router", [], env, tmp_path)
    try:
        wait_for(lambda: "router up" in router.log() or not router.alive(), 15, "the router to start")
        assert router.alive(), router.log()
        yield endpoint
    finally:
        router.stop()


@pytest.fixture
def service_env(router_endpoint: str, robot_id: str) -> dict[str, str]:
    """Environment for a service that joins the test's router as a client."""
    return dict(
        os.environ,
        ZENSIM_ROBOT_ID=robot_id,
        ZENSIM_ZENOH_MODE="client",
        ZENSIM_ZENOH_CONNECT=router_endpoint,
        ZENSIM_ZENOH_MULTICAST_SCOUTING="false",
        PYTHONUNBUFFERED="1",
    )


@pytest.fixture
def start_service(
    service_env: dict[str, str], tmp_path: Path, request: pytest.FixtureRequest
) -> Iterator[Callable[..., Service]]:
    """Factory: `start_service("sim", "--mode", "fixed", env={...})` runs a real service process.

    Every service started is stopped at teardown; its log is printed when the test failed.
    """
    started: list[Service] = []

    def start(command: str, *args: str, env: dict[str, str] | None = None) -> Service:
        service = Service(command, list(args), {**service_env, **(env or {})}, tmp_path)
        started.append(service)
        return service

    yield start
    for service in started:
        service.stop()
    report = getattr(request.node, "rep_call", None)
    if report is not None and report.failed:
        for service in started:
            print(f"\n----- {service.command} log -----\n{service.log()}")


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo) -> Generator[None, pytest.TestReport, pytest.TestReport]:
    """Remember each phase's report on the item so fixtures can tell a failed test."""
    report = yield
    setattr(item, f"rep_{report.when}", report)
    return report


@pytest.fixture
def zsession(router_endpoint: str) -> Iterator[zenoh.Session]:
    """A plain zenoh session in the test process, connected to the test's router."""
    with plain_client(router_endpoint) as session:
        yield session
