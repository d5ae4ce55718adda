"""Records every Zenoh declaration a process makes, for tests/test_roles.py.

Put this folder on PYTHONPATH and set ZENOH_AUDIT_DIR: Python imports `sitecustomize` at start, and
this one wraps `zenoh.open` so that the real session it opens is handed out behind a thin recorder.
Each publisher, subscriber, queryable, querier, query, put and liveliness use is appended as one JSON
line to `ZENOH_AUDIT_DIR/<pid>.jsonl` (the first line is the process's argv) before the real call runs.
Nothing else changes: the session, its sockets and its traffic are zenoh's own.

The variable has no `ZENSIM_` prefix so that `zensim up` passes it on to the services it starts.
"""

from __future__ import annotations

import json
import os
import sys
import threading

_DIR = os.environ.get("ZENOH_AUDIT_DIR")

if _DIR:
    import zenoh

    _lock = threading.Lock()
    _path = os.path.join(_DIR, f"{os.getpid()}.jsonl")

    def _record(use: str, key: object) -> None:
        with _lock, open(_path, "a") as out:
            out.write(json.dumps({"use": use, "key": str(key)}) + "\n")

    with open(_path, "w") as first:
        first.write(json.dumps({"argv": sys.orig_argv}) + "\n")

    class _Liveliness:
        def __init__(self, liveliness: object) -> None:
            self._l = liveliness

        def declare_token(self, key, *args, **kwargs):  # noqa: ANN001, ANN002, ANN003, ANN201
            _record("token", key)
            return self._l.declare_token(key, *args, **kwargs)

        def declare_subscriber(self, key, *args, **kwargs):  # noqa: ANN001, ANN002, ANN003, ANN201
            _record("liveliness_subscriber", key)
            return self._l.declare_subscriber(key, *args, **kwargs)

        def get(self, key, *args, **kwargs):  # noqa: ANN001, ANN002, ANN003, ANN201
            _record("liveliness_query", key)
            return self._l.get(key, *args, **kwargs)

        def __getattr__(self, name: str) -> object:
            return getattr(self._l, name)

    class _Session:
        _USES = {"declare_publisher": "publisher", "put": "publisher", "delete": "publisher",
                 "declare_subscriber": "subscriber", "declare_queryable": "queryable",
                 "declare_querier": "querier", "get": "querier"}

        def __init__(self, session: zenoh.Session) -> None:
            self._s = session

        def __getattr__(self, name: str) -> object:
            real = getattr(self._s, name)
            use = self._USES.get(name)
            if use is None:
                return real

            def audited(key, *args, **kwargs):  # noqa: ANN001, ANN002, ANN003, ANN202
                _record(use, key)
                return real(key, *args, **kwargs)

            return audited

        def liveliness(self) -> _Liveliness:
            return _Liveliness(self._s.liveliness())

        def __enter__(self) -> _Session:
            self._s.__enter__()
            return self

        def __exit__(self, *exc: object) -> object:
            return self._s.__exit__(*exc)

    _open = zenoh.open

    def _audited_open(*args, **kwargs):  # noqa: ANN002, ANN003, ANN202
        return _Session(_open(*args, **kwargs))

    zenoh.open = _audited_open
