"""The Unitree adapter's threading rule: its lock guards its counters and its LowState_ builder, and is
never held across a DDS write (a write that blocks would stall the thread that reads rt/lowcmd).

A real sim process publishes 500 Hz states; the adapter runs in this process on real Cyclone DDS
(loopback, a domain of its own). Its DDS writer is the real one, wrapped to check, at each write,
whether the writing thread holds the adapter's lock: the lock is not reentrant, so a thread that
holds it cannot take it again (the acquire times out), while one held briefly by another thread is
taken after a short wait.
"""

from __future__ import annotations

import logging
import threading

from support import ctl, plain_client, wait_for
from test_sim_process import wait_alive
from unitree_sdk import unused_domain_id
from zensim.common.robot_info import fetch_robot
from zensim.schemas import Keys
from zensim.unitree.dds import UnitreeDds
from zensim.unitree.service import Robot, UnitreeAdapter
from zensim.unitree.settings import UnitreeSettings


class CheckedDds(UnitreeDds):
    """The real DDS side; counts LowState_ writes made while the writing thread held the adapter's lock."""

    adapter: UnitreeAdapter | None = None
    writes = 0
    under_lock = 0

    def write_lowstate(self, data: bytes) -> None:
        adapter = self.adapter
        if adapter is not None:
            lock = adapter._lock
            if lock.acquire(timeout=0.5):
                lock.release()
            else:
                self.under_lock += 1
            self.writes += 1
        super().write_lowstate(data)


def test_lowstate_is_written_without_the_adapters_lock(start_service, router_endpoint: str, robot_id: str) -> None:
    keys = Keys(robot_id)
    start_service("sim", "--mode", "fixed", "--rtf", "1", "--state-rate-hz", "500")
    with plain_client(router_endpoint) as session:
        wait_alive(session, keys)
        assert ctl(session, keys.ctl("reset"))["ok"]
        stop = threading.Event()
        robot = fetch_robot(session, keys, 2.0, stop, Robot.from_info, logging.getLogger("test"))
        assert robot is not None
        settings = UnitreeSettings(robot_id=robot_id, domain_id=unused_domain_id(), interface="lo")
        dds = CheckedDds(settings.domain_id, settings.interface)
        adapter = UnitreeAdapter(session, keys, robot, settings, dds)
        dds.adapter = adapter
        try:
            wait_for(lambda: dds.writes >= 20, 30, "20 LowState_ written")
        finally:
            adapter.close()
            # Cyclone keeps every entity in a class-level table, so the participant (and its sockets, tied to
            # `lo`) would outlive the test inside the pytest process: delete it and its readers and writers.
            dds.participant.__del__()
        assert dds.under_lock == 0, f"{dds.under_lock} of {dds.writes} LowState_ writes held the adapter's lock"
        assert adapter.lowstate_published() >= 19  # counted, under the lock, after each write
