"""Following a robot's sim through its state/sim: a restarted sim, a new episode.

Every service that drives or mirrors a sim's robot (the bridge, the Unitree adapter, the ROS 1 gateway)
must notice two things on `state/sim` (SimStatus): a new `run_id` is a restarted sim, perhaps of another
robot, whose description must be learned again (`info/robot`); a new `episode` is a reset or a mode switch,
after which the robot stands in its default pose. `SimFollower` decodes the statuses (size cap first,
bad ones logged at a bounded rate and dropped), sets `restarted` on a new run and hands every other
status to the service, which decides what an episode means to it. `SimRun` is that decision alone, for a
service that reads state/sim on a subscriber of its own (the Unitree adapter: one subscriber for all state/*).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable

import zenoh

from zensim.schemas import Keys, SimStatus, topics

from .logs import RateLimitedLog
from .wire import TypedSubscriber

logger = logging.getLogger("zensim.common.follow")

BAD_STATUS_LOG_PERIOD_S = 5.0


class SimRun:
    """Which sim run a service follows: a status from another run is a restart (no I/O; see SimFollower).

    Args:
        run_id: the sim run the service learned the robot from (RobotInfo.run_id); empty: restarts are not
            followed (a robot from local files).
    """

    def __init__(self, run_id: str = "") -> None:
        self.restarted = threading.Event()
        """Set when a status comes from a new sim run: the service learns the robot again, then `adopt`s it."""
        self._run_id = run_id

    def adopt(self, run_id: str) -> None:
        """The robot was learned from sim run `run_id` (again, after a restart): follow that run."""
        self._run_id = run_id
        self.restarted.clear()

    def follows(self, status: SimStatus) -> bool:
        """Whether `status` is of the followed run; a first status of a new run sets `restarted`."""
        if self.restarted.is_set():
            return False  # the service is learning the new sim's robot; its statuses count after that
        if self._run_id and status.run_id and status.run_id != self._run_id:
            logger.info("the sim restarted (run %s): learning the robot again", status.run_id)
            self.restarted.set()
            return False
        return True


class SimFollower(SimRun):
    """Subscribes to one robot's state/sim until closed.

    Args:
        session: the zenoh session.
        keys: the robot's keys.
        cap_bytes: the largest status read (sized from the robot, like every input).
        on_status: called (on zenoh's thread) with each status of the known sim run.
        run_id: as for SimRun.
    """

    def __init__(self, session: zenoh.Session, keys: Keys, cap_bytes: int, on_status: Callable[[SimStatus], None],
                 run_id: str = "") -> None:
        super().__init__(run_id)
        self._on_status = on_status
        self._bad_log = RateLimitedLog(logger, BAD_STATUS_LOG_PERIOD_S)
        self._subscriber = TypedSubscriber(session, keys.sim_status, topics.SIM_STATUS.message_type(), cap_bytes,
                                           self._on_message, self._on_bad)

    def _on_bad(self, _sample: zenoh.Sample, reason: str) -> None:
        self._bad_log.warning("ignoring bad SimStatus: %s", reason)

    def _on_message(self, status: SimStatus) -> None:
        if self.follows(status):
            self._on_status(status)

    def close(self) -> None:
        self._subscriber.undeclare()
