"""A robot's description on the wire: info/robot, info/urdf and info/mesh/{path}, served under one set of rules.

The sim serves its robot's; `zensim replay` serves a recording's. Both answer the same way: info/*
only describes, so it may answer a wildcard query, always on its own key (a reply on `zensim/g1/**`
would not name what it is); its payload is never decoded (JSON is asked for by `?format=json` or a
JSON payload, as on every queryable, common/queryable.py); a mesh is served one per query, named by its
path (RobotInfo.mesh_paths), and what is missing gets an error reply that says so.
"""

from __future__ import annotations

from collections.abc import Callable

import zenoh

from zensim.schemas import Keys, RobotInfo, bounded

from .queryable import TypedQuery, TypedQueryable
from .wire import Refusals, is_wildcard


class MeshError(LookupError):
    """A mesh that cannot be served (unknown, unreadable); the text says why."""


class DescriptionServer:
    """Serves one robot's info/robot, info/urdf and info/mesh/{path} until closed.

    Args:
        session: the zenoh session.
        keys: the robot's keys.
        refusals: counts the refused queries.
        info: the RobotInfo now (a value replaced whole by its owner), or None when there is none.
        urdf: the URDF text, or None.
        mesh: the bytes of the mesh on a key (`Keys.mesh(path)`); raises MeshError.
        missing: how an error reply names what holds no info/robot or info/urdf (`the recording`).
    """

    def __init__(self, session: zenoh.Session, keys: Keys, refusals: Refusals, info: Callable[[], RobotInfo | None],
                 urdf: Callable[[], str | None], mesh: Callable[[str], bytes], missing: str = "this service") -> None:
        self.keys = keys
        self._info = info
        self._urdf = urdf
        self._mesh = mesh
        self._missing = missing
        self._robot_info = TypedQueryable(session, keys.robot_info, self._on_info, RobotInfo, refusals, exact=False)
        self._declared = [session.declare_queryable(keys.urdf, self._on_urdf),
                          session.declare_queryable(keys.mesh_any, self._on_mesh)]

    def _on_info(self, query: TypedQuery[RobotInfo, RobotInfo]) -> None:
        info = self._info()
        if info is None:
            query.refuse(f"{self._missing} holds no info/robot")
            return
        query.reply(info)

    def _on_urdf(self, query: zenoh.Query) -> None:
        urdf = self._urdf()
        if urdf is None:
            query.reply_err(f"{self._missing} holds no info/urdf".encode())
            return
        query.reply(self.keys.urdf, urdf.encode(), encoding=zenoh.Encoding.APPLICATION_XML)

    def _on_mesh(self, query: zenoh.Query) -> None:
        key = str(query.key_expr)
        if is_wildcard(key):
            query.reply_err(b"info/mesh/{path} serves one mesh per query: name its path (RobotInfo.mesh_paths)")
            return
        try:
            data = self._mesh(key)
        except MeshError as exc:
            query.reply_err(bounded(str(exc)).encode())
            return
        query.reply(key, data, encoding=zenoh.Encoding.APPLICATION_OCTET_STREAM)

    def undeclare(self) -> None:
        self._robot_info.undeclare()
        for entity in self._declared:
            entity.undeclare()
