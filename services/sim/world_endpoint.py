"""A world's own verbs, under the world's id: zensim/{world}/world/pause|resume|step|reset|advance|info, and
world/advance under each robot's id: zensim/{robot}/world/advance.

Serves:  world/pause, world/resume, world/step, world/reset (-> CtlReply), world/advance (lockstep:
         WorldAdvanceRequest -> WorldAdvanceReply), world/info (WorldInfo), all under the world's id;
         world/advance under each robot's id (that robot's entry only, that robot's states back)
Token:   alive/world (the world's own id is taken while it runs, services/common/claim.py)

Who may do what is the router's to say (docs/security.md): its access rules are on key expressions, and
a query's payload is out of their sight. So the key a request comes on is its authority, and the sim only
acts on a query for exactly that key (a wildcard reaches every queryable and is refused): the world's id
is the whole world (its verbs move every robot; scope a credential to it only if it may move them all),
a robot's id is that robot. world/advance on a robot's key carries that robot's command alone: an entry
for any other robot refuses the whole request (nothing applied, counted in that robot's
`rejected_requests`), so a credential scoped to robot `a` drives `a` in a lockstep world and cannot
command `b`, whatever its payload says. Its advance moves the world's one clock (the other robots hold
their commands), as a robot alone's ctl/advance does.

What the verbs do is the engine's (engine.py); each robot's own keys are its RobotEndpoint's.
"""

from __future__ import annotations

import logging
import uuid
from collections.abc import Callable, Sequence

import msgspec
import zenoh

from zensim.common.queryable import TypedQuery, TypedQueryable
from zensim.common.wire import Refusals
from zensim.schemas import (
    CtlReply,
    Keys,
    MotorCommand,
    PauseRequest,
    ResetRequest,
    ResumeRequest,
    RobotStates,
    StepRequest,
    WorldAdvanceReply,
    WorldAdvanceRequest,
    WorldInfo,
    WorldRobot,
    bounded,
)
from zensim.schemas.bounds import vector_cap_bytes
from zensim.schemas.messages import Message

from .engine import Engine
from .physics import Checked, CommandError
from .requests import Request, Requests, run_guarded
from .world_file import RobotEntry
from .world_states import States

logger = logging.getLogger("zensim.sim")

WORLD_INPUT_CAP_BYTES = 4096
"""Largest world/* request but world/advance: they carry at most a step count."""


class WorldEndpoint:
    """Serves the world's verbs and world/info until closed.

    Args:
        session: the zenoh session.
        engine: the engine running the world.
        entries: the world file's robots, in the world's order (world/info lists them).
    """

    def __init__(self, session: zenoh.Session, engine: Engine, entries: Sequence[RobotEntry],
                 robot_refusals: Sequence[Refusals] = ()) -> None:
        self._session = session
        self.engine = engine
        world = engine.world
        self.keys = keys = Keys(world.id)
        self.run_id = uuid.uuid4().hex[:16]
        self.refusals = Refusals(logger, "world request")
        self.requests = Requests(lambda reason: self._reply(ok=False, error=reason), engine.work)
        self.snapshot = self._take_reply_state()
        self._index = {robot_id: index for index, robot_id in enumerate(world.sims)}
        self.info = WorldInfo(world=world.id, robots=tuple(
            WorldRobot(robot=entry.id, model=sim.robot.name, mode=sim.mode, xy=entry.xy, yaw_deg=entry.yaw_deg)
            for entry, sim in zip(entries, world.robots)), terrain=world.terrain)
        """world/info's answer, made once: a world's robots never change while it runs."""
        advance_cap_bytes = WORLD_INPUT_CAP_BYTES + sum(vector_cap_bytes(sim.robot.joint_names) for sim in world.robots)
        self._queryables: list[TypedQueryable] = [
            self._verb(keys.world_pause, PauseRequest, self._pause),
            self._verb(keys.world_resume, ResumeRequest, self._resume),
            self._verb(keys.world_step, StepRequest, self._step),
            self._verb(keys.world_reset, ResetRequest, self._reset),
            TypedQueryable(session, keys.world_advance, self._on_advance, WorldAdvanceReply, self.refusals,
                           WorldAdvanceRequest, advance_cap_bytes, refused=self._advance_refusal),
            # Exact key only, as the verbs: a reply to a wildcard would not say which world it lists.
            TypedQueryable(session, keys.world_info, lambda query: query.reply(self.info), WorldInfo, self.refusals,
                           cap_bytes=WORLD_INPUT_CAP_BYTES),
        ]
        # Each robot's own world/advance: authorised by its key (the router's rules), refusals counted in the
        # robot's status, where a client scoped to it reads them.
        for robot_id, refusals in zip(world.sims, robot_refusals):
            self._queryables.append(TypedQueryable(
                session, Keys(robot_id).world_advance, self._robot_advance(robot_id), WorldAdvanceReply, refusals,
                WorldAdvanceRequest, advance_cap_bytes, refused=self._advance_refusal))
        self.token: zenoh.LivelinessToken | None = None

    def announce(self) -> None:
        """Declare alive/world: the world's own id is taken from now on."""
        self.token = self._session.liveliness().declare_token(self.keys.alive("world"))

    def take_snapshot(self) -> None:
        self.snapshot = self._take_reply_state()

    # --- the verbs (run by the engine's loop, physics lock held) -----------------------------------

    def _verb(self, key: str, request_type: type[Message], handler: Callable) -> TypedQueryable:
        def on_query(query: TypedQuery) -> None:
            self.requests.submit(Request(query, lambda: handler(query.request)))

        return TypedQueryable(self._session, key, on_query, CtlReply, self.refusals, request_type,
                              WORLD_INPUT_CAP_BYTES, refused=lambda error: self._reply(ok=False, error=error))

    def _take_reply_state(self) -> CtlReply:
        """(physics lock held) The world's figures, taken whole, for replies made off the loop."""
        engine, world = self.engine, self.engine.world
        return CtlReply(ok=True, sim_time_s=world.sim_time_s, paused=engine.paused, mode=world.mode,
                        steps=world.steps, episode=f"{self.run_id}.{world.resets}")

    def _reply(self, ok: bool = True, error: str | None = None) -> CtlReply:
        return msgspec.structs.replace(self.snapshot, ok=ok, error=error)

    def _pause(self, _request: PauseRequest) -> CtlReply:
        self.engine.pause()
        return self._take_reply_state()

    def _resume(self, _request: ResumeRequest) -> CtlReply:
        self.engine.resume()
        return self._take_reply_state()

    def _step(self, request: StepRequest) -> CtlReply:
        if not self.engine.paused:
            return self._reply(ok=False, error="world/step works while paused; send world/pause first")
        broken = self.engine.step(request.n)
        if broken:  # already followed by a reset: the reply says why the world moved back
            return msgspec.structs.replace(self._take_reply_state(), ok=False,
                                           error=bounded(f"the physics broke ({broken[0][1]}): reset"))
        return self._take_reply_state()

    def _reset(self, request: ResetRequest) -> CtlReply:
        if request != ResetRequest():
            return self._reply(ok=False, error="world/reset takes an empty request (every robot to its default "
                                               "pose); send ctl/reset to one robot for a pose, a height or a mode")
        self.engine.reset_world()
        self.engine.request_log.info("world reset")
        return self._take_reply_state()

    # --- world/advance: on the query's thread ------------------------------------------------------

    def _robot_advance(self, robot_id: str) -> Callable[[TypedQuery[WorldAdvanceRequest, WorldAdvanceReply]], None]:
        """world/advance on robot `robot_id`'s own key: its entry alone."""
        return lambda query: self._on_advance(query, only=robot_id)

    def _on_advance(self, query: TypedQuery[WorldAdvanceRequest, WorldAdvanceReply], only: str | None = None) -> None:
        """As ctl/advance of a robot alone: stepped on this thread, under the physics lock, answered first and
        then published; no hand-over to the loop thread on the way. `only`: the robot whose key it came on."""
        engine = self.engine
        with engine.physics:
            reply, states = run_guarded(lambda: self._advance(query.request, only), "world/advance",
                                        lambda error: (self._advance_refusal(error), None))
            query.reply(reply)
            if states is not None:  # put by the publisher thread, while the client reads
                engine.submit_states(states)
            self.take_snapshot()

    def _advance(self, request: WorldAdvanceRequest,
                 only: str | None = None) -> tuple[WorldAdvanceReply, list[States] | None]:
        """(physics lock held) Every command checked first, then all applied, then one advance.

        `only`: the request came on that robot's key, which authorises its entry alone; an entry for any other
        robot refuses it whole, before anything else is looked at, and the reply carries that robot's states.
        """
        engine = self.engine
        if only is not None:
            others = [robot for robot in request.commands if robot != only]
            if others:
                return self._advance_refusal(bounded(
                    f"{Keys(only).world_advance} carries robot {only}'s command alone, not robot {others[0]!r}'s: "
                    f"send the whole world's on {self.keys.world_advance} (a credential for the whole world); "
                    "nothing was applied")), None
        if not engine.lockstep:
            return self._advance_refusal("world/advance works under --clock lockstep; this world runs in real time"), None
        if engine.paused:
            return self._advance_refusal("paused: send world/resume (or world/step to step by hand)"), None
        unknown = [robot for robot in request.commands if robot not in self._index]
        if unknown:
            return self._advance_refusal(bounded(f"no robot {unknown[0]!r} in this world; robots: "
                                                 f"{', '.join(self._index)}")), None
        checked: dict[int, tuple[MotorCommand, Checked]] = {}
        sims = engine.world.robots
        for robot, command in request.commands.items():
            index = self._index[robot]
            try:
                checked[index] = (command, sims[index].check_command(command))
            except CommandError as exc:
                return self._advance_refusal(bounded(f"robot {robot}: {exc}; nothing was applied")), None
        engine.advance(checked)
        states = engine.read_states()  # published once the client has its reply
        world = engine.world
        mine = [(robot, robot_states) for robot, robot_states in zip(world.sims, states) if only is None or robot == only]
        return WorldAdvanceReply(ok=True, sim_time_s=world.sim_time_s, steps=world.steps,
                                 states={robot: RobotStates(joints=j, odom=o, imu=i, contacts=c)
                                         for robot, (j, o, i, c) in mine if j is not None and i is not None},
                                 withheld=tuple(robot for robot, (j, _, i, _) in mine if j is None or i is None)), states

    def _advance_refusal(self, error: str) -> WorldAdvanceReply:
        now = self.snapshot
        return WorldAdvanceReply(ok=False, error=error, sim_time_s=now.sim_time_s, steps=now.steps)

    def close(self) -> None:
        if self.token is not None:
            self.token.undeclare()
        for queryable in self._queryables:
            queryable.undeclare()
        self.requests.close("the world is shutting down")

