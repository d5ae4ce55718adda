"""The sim's lockstep clock: each motor command advances the physics by `lockstep_steps`, then time stands still.

Reads:   cmd/motors (MotorCommand): every accepted command advances, in arrival order (not latest-wins)
Writes:  state/applied (AppliedCommand), then state/joints, state/odom, state/imu of the new instant
Serves:  ctl/advance (MotorCommand -> AdvanceReply): the one-round-trip form of the same step
Status:  state/sim says `clock: lockstep` and `waiting: true` while no command is pending

Why the ctl/ plane for the request/reply form: every queryable that acts on the sim lives under
ctl/, so an access-control rule on `ctl/**` covers it with the others, and cmd/ stays the plane of
fire-and-forget publications with latest-wins semantics.

A command is stepped right on the thread that received it (the sim's command thread, or the
zenoh callback of ctl/advance), under the service's physics lock, which the loop thread also
holds while it runs ctl requests (reset, pause, step) and while it reads the sim for state/sim:
a step never interleaves with a reset or a status, and no thread hand-off sits in the
controller's round trip. A ctl/advance
query is answered before the states go out to everyone else (the asking client waits; the others
only listen). Commands on cmd/motors come through the sim's command ring, drained by one thread,
so they are stepped in arrival order; a client that floods faster than the physics runs loses the
oldest ones in the ring (a ctl/advance round trip never loses a step). The loop never steps on its own: no pacing, no watchdog (the watchdog measures
wall time, and between two commands of a lockstep client no sim time passes). From the same reset
and the same commands the states are bit-identical (MuJoCo is deterministic on one machine and
build; the commands are the only input).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass

import zenoh

from zensim.common.wire import TypedPublisher, decode_input, payload_of, reply
from zensim.schemas import AdvanceReply, AppliedCommand, Codec, DecodeError, MotorCommand, bounded, is_json

from .physics import CommandError
from .requests import run_guarded
from .service import SimService

logger = logging.getLogger("zensim.sim.lockstep")

IDLE_POLL_S = 0.005
"""How long the loop waits for a ctl request before it checks the status timer and the stop event."""


@dataclass(frozen=True)
class Advanced:
    """The outcome of one advance: the reply, and what to publish (None when nothing moved)."""

    reply: AdvanceReply
    applied: AppliedCommand | None = None


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
        self.lock = service.physics
        """The service's physics lock: held while the physics moves, a ctl request runs or the status is read."""
        self._codec = Codec(MotorCommand)
        self._reply_codec = Codec(AdvanceReply)
        service.sim.watchdog_enabled = False
        keys = service.keys
        self.advance_key = keys.ctl("advance")
        self.pub_applied = TypedPublisher(service.session, keys.applied, AppliedCommand)
        self.queryable = service.session.declare_queryable(self.advance_key, self._on_advance)

    # --- the two ways in: a command on cmd/motors, a ctl/advance query ----------------------------

    def submit(self, command: MotorCommand) -> None:
        """A command from cmd/motors (the sim's command thread): step and publish."""
        with self.lock:
            self._publish(self.advance(command, hold_when_paused=True, key=self.service.keys.motors))

    def _on_advance(self, query: zenoh.Query) -> None:
        service, sim = self.service, self.service.sim
        # Answer in the request's own format (an oversize one too: its first bytes say, and the
        # router has already capped its size at 64 kB).
        fmt = "json" if query.payload is None or is_json(*payload_of(query)) else "msgpack"
        if str(query.key_expr) != self.advance_key:
            # `z_get zensim/g1/**` reaches every queryable: the sim steps only when named.
            error = service.request_refusals.refuse(query.key_expr, f"ctl/advance acts only on a query for exactly "
                                                    f"{self.advance_key}; nothing was done")
            self._refuse(query, error, fmt)
            return
        try:
            command = decode_input(query, self._codec, service.input_cap_bytes)
        except DecodeError as exc:
            # A bad command is a bad command, whichever way it came: counted with those on cmd/motors.
            error = service.command_refusals.refuse(query.key_expr, str(exc))
            sim.reject(error)
            self._refuse(query, error, fmt)
            return
        with self.lock:
            advanced = run_guarded(lambda: self.advance(command, hold_when_paused=False, key=self.advance_key),
                                   "ctl/advance", lambda error: Advanced(AdvanceReply(ok=False, error=error)))
            self._answer(query, advanced.reply, fmt)  # the asking client first, then everyone else
            query.drop()  # ends the query now: a client waiting for the get to complete need not wait for the publishing
            self._publish(advanced)

    def _refuse(self, query: zenoh.Query, error: str, fmt: str) -> None:
        """Answer a refused query without the physics lock: time and steps from the service's snapshot."""
        now = self.service._snapshot
        self._answer(query, AdvanceReply(ok=False, error=error, sim_time_s=now.sim_time_s, steps=now.steps), fmt)

    def _answer(self, query: zenoh.Query, message: AdvanceReply, fmt: str) -> None:
        reply(query, self.advance_key, message, fmt, self._reply_codec)  # type: ignore[arg-type]

    # --- stepping (the caller holds `lock`) ------------------------------------------------------

    def advance(self, command: MotorCommand, hold_when_paused: bool, key: str) -> Advanced:
        """Apply `command` and run `lockstep_steps` physics steps (the caller holds `lock`).

        While paused, a command from cmd/motors is held (ctl/step then runs it) and one from
        ctl/advance is refused: neither moves time.
        """
        service, sim = self.service, self.service.sim
        if service.paused and not hold_when_paused:
            return Advanced(AdvanceReply(ok=False, error="paused: send ctl/resume (or ctl/step to step by hand)",
                                         sim_time_s=sim.sim_time_s, steps=sim.steps))
        try:
            sim.accept_command(command)
        except CommandError as exc:
            error = service.command_refusals.refuse(key, str(exc))
            sim.reject(error)
            return Advanced(AdvanceReply(ok=False, error=error, sim_time_s=sim.sim_time_s, steps=sim.steps))
        if service.paused:
            return Advanced(AdvanceReply(ok=True, sim_time_s=sim.sim_time_s, steps=sim.steps))
        self.applied_seq += 1
        applied = AppliedCommand(sim_time_s=sim.sim_time_s, seq=self.applied_seq, steps=self.steps, command=command)
        sim.step(self.steps)
        service.pacer.stepped(self.steps)
        reason = sim.broken()
        if reason:
            service._physics_reset(reason)
            return Advanced(AdvanceReply(ok=False, error=bounded(f"the physics broke ({reason}): reset"),
                                         sim_time_s=sim.sim_time_s, steps=sim.steps))
        service.seq += 1
        service._snapshot = service._take_snapshot()
        joints, odom, imu = sim.joint_state(service.seq), sim.odometry(service.seq), sim.imu(service.seq)
        reply = AdvanceReply(ok=True, sim_time_s=sim.sim_time_s, steps=sim.steps, joints=joints, odom=odom, imu=imu)
        return Advanced(reply, applied)

    def _publish(self, advanced: Advanced) -> None:
        """The new instant for everyone: joints, odom, imu (what pub/sub clients wait on), then what was applied."""
        reply = advanced.reply
        if advanced.applied is None or reply.joints is None or reply.odom is None or reply.imu is None:
            return
        service = self.service
        service.pub_joints.put(reply.joints)
        service.pub_odom.put(reply.odom)
        service.pub_imu.put(reply.imu)
        self.pub_applied.put(advanced.applied)
        service._check_fall()

    # --- the loop thread: ctl requests and the status ---------------------------------------------

    def run(self) -> None:
        """Run ctl requests until the stop event; publish SimStatus at its wall-clock rate."""
        service, sim = self.service, self.service.sim
        status_period_s = 1.0 / service.settings.status_rate_hz
        now = time.monotonic()
        next_status = now
        with self.lock:
            last_status_wall, last_status_sim = now, sim.sim_time_s
            service._publish_states()  # the initial instant, before the first command
        while not service.stop.is_set():
            service.requests.run_next(min(IDLE_POLL_S, max(0.0, next_status - time.monotonic())), service.run_request)
            now = time.monotonic()
            if now >= next_status:
                stepping = self.lock.locked()  # a command is being stepped right now
                with self.lock:  # the status reads MjData: never while another thread steps
                    wall = now - last_status_wall
                    rtf = (sim.sim_time_s - last_status_sim) / wall if wall > 0 else 0.0
                    self.waiting = not service.paused and not stepping
                    service._publish_status(max(rtf, 0.0))
                    last_status_wall, last_status_sim = now, sim.sim_time_s
                next_status = now + status_period_s

    def close(self) -> None:
        self.queryable.undeclare()
        self.pub_applied.undeclare()
