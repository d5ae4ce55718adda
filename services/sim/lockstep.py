"""The sim's lockstep clock: each motor command advances the physics by `lockstep_steps`, then time stands still.

Reads:   cmd/motors (MotorCommand): every accepted command advances, in arrival order (not latest-wins)
Writes:  state/applied (AppliedCommand), then state/joints, state/odom, state/imu of the new instant
Serves:  ctl/advance (MotorCommand -> AdvanceReply): the one-round-trip form of the same step
Status:  state/sim says `clock: lockstep` and `waiting: true` while no command is pending

Why the ctl/ plane for the request/reply form: every queryable that acts on the sim lives under
ctl/, so an access-control rule on `ctl/**` covers it with the others, and cmd/ stays the plane of
fire-and-forget publications with latest-wins semantics.

Commands from both paths run on the service's loop thread through the same job queue as the ctl
requests, so a step never interleaves with a reset or a pause, and everything happens in the order
it arrived. The loop never steps on its own: no pacing, no watchdog (the watchdog measures wall time,
and between two commands of a lockstep client no sim time passes). From the same reset and the same
commands the states are bit-identical (MuJoCo is deterministic on one machine and build; the
commands are the only input).
"""

from __future__ import annotations

import logging
import queue
import threading
import time

import zenoh

from zensim.common.logs import RateLimitedLog
from zensim.common.wire import TypedPublisher, payload_of
from zensim.schemas import (
    AdvanceReply,
    AppliedCommand,
    Codec,
    CtlReply,
    DecodeError,
    MotorCommand,
    ResetRequest,
    encoding_of,
    is_json,
)

from .physics import CommandError
from .service import REQUEST_TIMEOUT_S, Job, SimService

logger = logging.getLogger("zensim.sim.lockstep")

MAX_PENDING = 256
"""Commands from cmd/motors waiting for the loop; more are rejected (a flood must not grow memory)."""
IDLE_POLL_S = 0.005
"""How long the loop waits for a command before it checks the status timer and the stop event."""
MAX_ERROR_CHARS = 300
"""Error texts echoed to a client are cut here."""


class Lockstep:
    """The lockstep clock of one SimService: its extra keys and its loop.

    Args:
        service: the sim service whose physics, publishers and job queue this drives.
    """

    def __init__(self, service: SimService) -> None:
        self.service = service
        self.steps = service.settings.lockstep_steps
        self.applied_seq = 0
        self.waiting = True
        self._pending = 0
        self._pending_lock = threading.Lock()
        self._codec = Codec(MotorCommand)
        self._reply_codec = Codec(AdvanceReply)
        self._reject_log = RateLimitedLog(logger)
        service.sim.watchdog_enabled = False
        keys = service.keys
        self.advance_key = keys.ctl("advance")
        self.pub_applied = TypedPublisher(service.session, keys.applied, AppliedCommand)
        self.queryable = service.session.declare_queryable(self.advance_key, self._on_advance)

    # --- zenoh callbacks: decode, hand over --------------------------------------------------

    def submit(self, command: MotorCommand) -> None:
        """A command from cmd/motors (callback thread): queue it for the loop, bounded."""
        with self._pending_lock:
            if self._pending >= MAX_PENDING:
                self._reject(f"lockstep: more than {MAX_PENDING} commands wait for the physics; command dropped")
                return
            self._pending += 1
        self.service.jobs.put(Job(lambda: self._from_topic(command)))

    def _from_topic(self, command: MotorCommand) -> CtlReply:
        with self._pending_lock:
            self._pending -= 1
        reply = self.advance(command, hold_when_paused=True)
        return self.service._status_reply(ok=reply.ok, error=reply.error)

    def _on_advance(self, query: zenoh.Query) -> None:
        data, encoding = payload_of(query)
        fmt = "msgpack" if data and not is_json(data, encoding) else "json"
        if str(query.key_expr) != self.advance_key:
            # A wildcard query (`zensim/g1/**`) reaches this queryable too; it must not step the sim.
            query.reply_err(b"ctl/advance acts only when queried on its exact key")
            return
        try:
            command = self._codec.decode(data, encoding)
        except DecodeError as exc:
            self._reject(str(exc))
            self._answer(query, AdvanceReply(ok=False, error=str(exc)[:MAX_ERROR_CHARS]), fmt)
            return
        job = Job(lambda: self.advance(command, hold_when_paused=False))  # type: ignore[arg-type,return-value]
        self.service.jobs.put(job)
        if not job.done.wait(REQUEST_TIMEOUT_S):
            self._answer(query, AdvanceReply(ok=False, error="the sim loop did not answer in time"), fmt)
            return
        reply = job.reply
        if not isinstance(reply, AdvanceReply):  # the job failed and the loop answered with a CtlReply
            reply = AdvanceReply(ok=False, error=getattr(reply, "error", "failed"))
        self._answer(query, reply, fmt)

    def _answer(self, query: zenoh.Query, reply: AdvanceReply, fmt: str) -> None:
        query.reply(query.key_expr, self._reply_codec.encode(reply, fmt),  # type: ignore[arg-type]
                    encoding=zenoh.Encoding(encoding_of(fmt)))  # type: ignore[arg-type]

    def _reject(self, reason: str) -> None:
        self.service.sim.reject(reason[:MAX_ERROR_CHARS])
        self._reject_log.warning("rejected lockstep command: %s", reason[:MAX_ERROR_CHARS])

    # --- the loop thread -----------------------------------------------------------------------

    def advance(self, command: MotorCommand, hold_when_paused: bool) -> AdvanceReply:
        """Apply `command`, run `lockstep_steps` physics steps, publish and return the new states.

        While paused, a command from cmd/motors is held (ctl/step then runs it) and one from
        ctl/advance is refused: neither moves time.
        """
        service, sim = self.service, self.service.sim
        if service.paused and not hold_when_paused:
            return AdvanceReply(ok=False, error="paused: send ctl/resume (or ctl/step to step by hand)",
                                sim_time_s=sim.sim_time_s, steps=sim.steps)
        try:
            sim.accept_command(command)
        except CommandError as exc:
            self._reject(str(exc))
            return AdvanceReply(ok=False, error=str(exc)[:MAX_ERROR_CHARS], sim_time_s=sim.sim_time_s, steps=sim.steps)
        if service.paused:
            return AdvanceReply(ok=True, error=None, sim_time_s=sim.sim_time_s, steps=sim.steps)
        self.applied_seq += 1
        self.pub_applied.put(AppliedCommand(sim_time_s=sim.sim_time_s, seq=self.applied_seq, steps=self.steps,
                                            command=command))
        sim.step(self.steps)
        service.pacer.stepped(self.steps)
        if sim.diverged():
            logger.error("the physics diverged (NaN or huge accelerations): resetting")
            service._reset(ResetRequest())
            return AdvanceReply(ok=False, error="the physics diverged; the sim was reset",
                                sim_time_s=sim.sim_time_s, steps=sim.steps)
        service.seq += 1
        joints, odom, imu = sim.joint_state(service.seq), sim.odometry(service.seq), sim.imu(service.seq)
        service.pub_joints.put(joints)
        service.pub_odom.put(odom)
        service.pub_imu.put(imu)
        service._check_fall()
        return AdvanceReply(ok=True, sim_time_s=sim.sim_time_s, steps=sim.steps, joints=joints, odom=odom, imu=imu)

    def run(self) -> None:
        """Serve commands and ctl requests until the stop event; publish SimStatus on its wall-clock rate."""
        service, sim = self.service, self.service.sim
        status_period_s = 1.0 / service.settings.status_rate_hz
        now = time.monotonic()
        next_status = now
        last_status_wall, last_status_sim = now, sim.sim_time_s
        service._publish_states()  # the initial instant, before the first command
        while not service.stop.is_set():
            self._serve_one(min(IDLE_POLL_S, max(0.0, next_status - time.monotonic())))
            now = time.monotonic()
            if now >= next_status:
                wall = now - last_status_wall
                rtf = (sim.sim_time_s - last_status_sim) / wall if wall > 0 else 0.0
                self.waiting = not service.paused and service.jobs.empty()
                service._publish_status(max(rtf, 0.0))
                last_status_wall, last_status_sim = now, sim.sim_time_s
                next_status = now + status_period_s

    def _serve_one(self, timeout_s: float) -> None:
        """Run the next job (command or ctl request), waiting up to `timeout_s` for one."""
        try:
            job = self.service.jobs.get(timeout=timeout_s) if timeout_s > 0 else self.service.jobs.get_nowait()
        except queue.Empty:
            return
        try:
            job.reply = job.run()
        except Exception as exc:  # a failed request must not take the loop down
            logger.exception("lockstep job failed")
            job.reply = self.service._status_reply(ok=False, error=f"{type(exc).__name__}: {exc}"[:MAX_ERROR_CHARS])
        job.done.set()

    def close(self) -> None:
        self.queryable.undeclare()
        self.pub_applied.undeclare()
