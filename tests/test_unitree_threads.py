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
            dds.domain.__del__()  # the domain too: it owns the receive threads and their sockets
        assert dds.under_lock == 0, f"{dds.under_lock} of {dds.writes} LowState_ writes held the adapter's lock"
        assert adapter.lowstate_published() >= 19  # counted, under the lock, after each write


class FaultyDds(UnitreeDds):
    """The real DDS side, whose rt/lowcmd take fails the first `faults` times (a bug past every check)."""

    faults = 3

    def take_lowcmd(self, max_samples: int = 32) -> list[bytes]:
        if self.faults > 0:
            self.faults -= 1
            raise RuntimeError("a fault nobody foresaw")
        return super().take_lowcmd(max_samples)


def test_an_unforeseen_error_is_counted_and_the_dds_thread_serves_on(start_service, router_endpoint: str,
                                                                      robot_id: str) -> None:
    """Issue 27 item 1: one request's OverflowError ended the DDS thread, and with it every command path,
    while the adapter said all was well. Now each reader's handling is guarded: the error is counted
    (internal_errors, last_error), logged, and the same thread goes on forwarding LowCmd_."""
    from cyclonedds.pub import DataWriter
    from cyclonedds.topic import Topic

    from unitree_sdk import KD, KP, low_cmd_crc, new_low_cmd
    from zensim.unitree.idl import LowCmd_

    keys = Keys(robot_id)
    start_service("sim", "--mode", "fixed", "--rtf", "1", "--state-rate-hz", "500")
    with plain_client(router_endpoint) as session:
        wait_alive(session, keys)
        stop = threading.Event()
        robot = fetch_robot(session, keys, 2.0, stop, Robot.from_info, logging.getLogger("test"))
        assert robot is not None
        settings = UnitreeSettings(robot_id=robot_id, domain_id=unused_domain_id(), interface="lo")
        dds = FaultyDds(settings.domain_id, settings.interface)
        adapter = UnitreeAdapter(session, keys, robot, settings, dds)
        thread = threading.Thread(target=adapter.dds_loop, args=(stop,), daemon=True)
        thread.start()
        # A controller on the adapter's own participant (one DDS domain per process): Cyclone delivers
        # its samples to the adapter's reader as from any other.
        writer = DataWriter(dds.participant, Topic(dds.participant, "rt/lowcmd", LowCmd_))
        cmd = new_low_cmd()
        cmd.motor_cmd[18].mode, cmd.motor_cmd[18].q, cmd.motor_cmd[18].kp, cmd.motor_cmd[18].kd = 1, 0.5, KP[18], KD[18]
        cmd.crc = low_cmd_crc(cmd)

        def forwarded() -> bool:
            writer.write(cmd)
            return adapter.counters.lowcmd_forwarded > 0 or not thread.is_alive()

        try:
            wait_for(forwarded, 30, "a LowCmd_ forwarded after the faults", 0.01)
            assert thread.is_alive(), "the DDS thread ended"
            assert adapter.counters.internal_errors == 3, adapter.counters.internal_errors
            assert "RuntimeError" in (adapter.counters.last_error or ""), adapter.counters.last_error
        finally:
            stop.set()
            thread.join(5)
            adapter.close()
            dds.participant.__del__()
            dds.domain.__del__()  # the domain too: it owns the receive threads and their sockets
