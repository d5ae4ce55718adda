"""The sim service: build the World the settings name, serve it on zenoh, run the engine until stopped.

A robot alone (`zensim sim`) is a world of one; `zensim sim --world lab.toml` a world of several. Both
are the same engine (engine.py: the one loop, the verbs, the advance), the same per-robot keys
(robot_endpoint.py), one command thread for every robot (commands.py); a world file adds the world's own
verbs (world_endpoint.py). Every key is documented in services/sim/README.md and docs/protocol.md.
"""

from __future__ import annotations

import logging
import threading
from pathlib import Path

import zenoh

from zensim.common.claim import current_owner, taken_message
from zensim.common.logs import RateLimitedLog
from zensim.common.session import StartupError
from zensim.robots import robot_files
from zensim.robots.terrain import TerrainError, load_terrain
from zensim.schemas import Keys, bounded

from .commands import CommandIntake
from .engine import Engine
from .physics import Limits
from .robot_endpoint import RobotEndpoint
from .settings import SimSettings
from .world import World
from .world_endpoint import WorldEndpoint
from .world_file import WorldFile, read_world_file

logger = logging.getLogger("zensim.sim")


def load_world(settings: SimSettings) -> tuple[World, WorldFile | None]:
    """Build what the settings name (before the session: a bad robot or world file fails fast): the world of
    a world file (and the file), or a world of the one robot.

    Raises:
        StartupError: a missing or broken URDF, mesh, control or world file; the text names the file.
    """
    limits = Limits(max_kp=settings.max_kp, max_kd=settings.max_kd)
    try:
        terrain = load_terrain(settings.terrain) if settings.terrain else None
    except TerrainError as exc:
        raise StartupError(f"terrain (--terrain / ZENSIM_SIM_TERRAIN): {bounded(str(exc), 400)}") from None
    if settings.world:
        world_file = read_world_file(settings.world)
        if world_file.terrain is not None:
            if terrain is not None:
                raise StartupError(f"the world file {settings.world} has a [terrain] table and --terrain names "
                                   "another: give one")
            terrain = world_file.terrain
        try:
            world = World.of_file(world_file, Path(settings.world).resolve().parent, settings.mode, limits,
                                  settings.watchdog_timeout_s, settings.timestep_s, terrain)
        except (OSError, ValueError) as exc:
            raise StartupError(f"cannot build the world ({settings.world}): {bounded(str(exc), 400)}") from None
        logger.info("world %s: %d robots (%s), %d bodies, mode %s, step %.4f s", world.id, len(world),
                    ", ".join(world.sims), world.model.nbody, world.mode, world.timestep_s)
        return world, world_file
    # An explicit URDF stands alone: it must not pick up the bundled G1's control file.
    try:
        files = robot_files(None if settings.urdf else settings.robot, urdf=settings.urdf, control=settings.control)
        world = World.alone(settings.robot_id, files, settings.mode, limits, settings.watchdog_timeout_s,
                            settings.timestep_s, terrain)
    except (OSError, ValueError) as exc:
        which = "--urdf / ZENSIM_SIM_URDF" if settings.urdf else "--robot / ZENSIM_SIM_ROBOT"
        raise StartupError(f"cannot load the robot ({which}, --control / ZENSIM_SIM_CONTROL): "
                           f"{bounded(str(exc), 400)}") from None
    (sim,) = world.robots
    logger.info("robot %s: %d joints, mode %s, step %.4f s", sim.robot.name, sim.robot.nu, sim.mode, world.timestep_s)
    return world, None


class SimService:
    """A World served on zenoh: its engine, each robot's endpoint, the world's verbs (a world file), the
    command thread. `run` until the stop event, then `close`."""

    def __init__(self, session: zenoh.Session, settings: SimSettings, stop: threading.Event, world: World,
                 world_file: WorldFile | None = None) -> None:
        self.world = world
        if settings.band:  # every floating robot starts on the band (a fixed one is held by its stand)
            for sim in world.robots:
                sim.disturbances.band_on = True
        self.engine = engine = Engine(world, settings, stop)
        # A robot alone under lockstep advances on each command; a world's lockstep advances by world/advance.
        advances = settings.clock == "lockstep" and world_file is None
        refusal_logs = (RateLimitedLog(logger), RateLimitedLog(logger))  # a flood to every robot: one line a second
        self.robots = robots = [
            RobotEndpoint(session, engine, index, robot_id, advances, refusal_logs if world_file else None)
            for index, robot_id in enumerate(world.sims)]
        self.world_endpoint = WorldEndpoint(session, engine, world_file.robots,
                                            [robot.request_refusals for robot in robots]) if world_file else None
        engine.serve(robots, [self.world_endpoint] if self.world_endpoint else [])
        self.intake = CommandIntake(robots, every_sample=advances)
        for robot in robots:  # alive/sim last: a client that saw it finds everything served, the world's verbs too
            robot.announce()
        if self.world_endpoint:
            self.world_endpoint.announce()
            logger.info("world up on %s/world: %s", self.world_endpoint.keys.root,
                        ", ".join(f"zensim/{r}" for r in world.sims))
        else:
            logger.info("sim up on %s", robots[0].keys.root)

    def run(self) -> None:
        self.engine.run()

    def close(self) -> None:
        # The command thread first, and wait for it: under lockstep a command advances the robot and
        # publishes its states from that thread, and a publisher undeclared while it puts raised "Already
        # borrowed" (the sim exited 1 at a SIGINT, the put itself "session closed").
        self.intake.close()
        for robot in self.robots:
            robot.stop_commands()
        self.intake.join()
        if self.world_endpoint:
            self.world_endpoint.close()
        for robot in self.robots:
            robot.close()
        self.engine.close()


def run(session: zenoh.Session, settings: SimSettings, stop: threading.Event, world: World,
        world_file: WorldFile | None = None) -> int:
    """Serve `world` on the session until `stop` is set. Returns the exit code."""
    for robot_id in (world.id, *world.sims) if world_file else world.sims:
        owner = current_owner(session, Keys(robot_id))
        if owner is not None:
            raise StartupError(taken_message(robot_id, owner))
    service = SimService(session, settings, stop, world, world_file)
    try:
        service.run()
    finally:
        service.close()
    logger.info("%s stopped after %.1f sim s", "world" if world_file else "sim", world.sim_time_s)
    return 0
