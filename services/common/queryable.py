"""One way to serve a queryable: exact key, size cap before any copy, reply format, decode, refusal, one reply.

Every ctl/, world/ and info/ handler of the sim, the world and `zensim replay` is a `TypedQueryable`: the
handler states only what it does with a request that passed every check, and answers through the
`TypedQuery` it is given, on whatever thread (the loop thread, later, for a ctl request). What a handler
must never forget lives here once:

- a queryable that acts answers only a query for exactly its key (`zensim/g1/**` reaches every queryable);
  one that only describes (`exact=False`) answers any query that reaches it, always on its own key;
- the payload's size is checked before a byte of it is copied (an oversize payload's format is judged by
  its encoding label alone);
- the reply comes in the query's format: JSON for `?format=json`, a query with no payload (a bare `z_get`)
  or a JSON payload; msgpack for a msgpack payload;
- every refusal is counted and logged at a bounded rate (`Refusals`), its text cut, and answered with the
  verb's own refusal message (or an error reply where the verb has none);
- every query gets exactly one reply: a second answer is dropped, and the query ends with the first.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import Generic, TypeVar

import zenoh

from zensim.schemas import MSGPACK, Codec, DecodeError, Message, is_json
from zensim.schemas.codec import Format

from .wire import Refusals, decode_input, payload_of, reply

Req = TypeVar("Req", bound=Message)
Rep = TypeVar("Rep", bound=Message)

logger = logging.getLogger("zensim.common.queryable")


def wants_json(query: zenoh.Query, cap_bytes: int | None, bare: bool) -> bool:
    """Whether to answer in JSON: asked by `?format=json`, a JSON payload, or no payload when `bare` (a verb
    answers a bare `z_get` in JSON; a description answers it in msgpack, what its clients decode).

    A payload over `cap_bytes` is never read: it is JSON unless its label says msgpack (the command line
    sets no label). `cap_bytes` None: the payload's own size is its cap (a describing queryable reads at
    most the label and the first bytes the JSON check needs).
    """
    if "format=json" in str(query.parameters):
        return True
    payload = query.payload
    if payload is None:
        return bare
    if cap_bytes is not None and len(payload) > cap_bytes:
        encoding = query.encoding
        return not (encoding is not None and str(encoding).startswith(MSGPACK))
    return is_json(*payload_of(query))


class TypedQuery(Generic[Req, Rep]):
    """One checked query: its decoded request, the format to answer in, and its one answer.

    `reply` (or `refuse`) may be called from any thread; only the first call answers, and it ends the query.
    """

    def __init__(self, query: zenoh.Query, request: Req | None, fmt: Format, served: TypedQueryable[Req, Rep]) -> None:
        self.query = query
        self._request = request
        self.fmt: Format = fmt
        self._served = served
        self._answered = False
        self._lock = threading.Lock()

    @property
    def request(self) -> Req:
        """The decoded request (a queryable without a request type has none to give)."""
        assert self._request is not None, "this queryable decodes no request"
        return self._request

    def reply(self, message: Rep) -> None:
        """Answer with `message` on the queryable's own key, in the query's format; the query ends.

        A refusal (a message whose `ok` is False) is counted with the others."""
        with self._lock:
            if self._answered:
                return
            self._answered = True
        served = self._served
        try:
            if served.count_refused_replies and getattr(message, "ok", True) is False:
                served.refusals.refuse(self.query.key_expr, getattr(message, "error", None) or "refused")
            reply(self.query, served.key, message, self.fmt, served.reply_codec)
        finally:
            self.query.drop()  # the final reply: the client's get() ends now

    def refuse(self, error: str) -> str:
        """Answer a refusal (counted, text cut); returns the bounded text."""
        with self._lock:
            if self._answered:
                return error
            self._answered = True
        served = self._served
        text = served.refusals.refuse(self.query.key_expr, error)
        try:
            served.send_refusal(self.query, text, self.fmt)
        finally:
            self.query.drop()
        return text


class TypedQueryable(Generic[Req, Rep]):
    """A queryable on one key that takes one request type and answers one reply type.

    Args:
        session: the zenoh session.
        key: the queryable's own key (replies always go out on it).
        handle: what the verb does with a checked query; it answers through the TypedQuery (now or later).
        reply_type: the type of its replies.
        refusals: counts and logs every refusal (a wildcard, a bad payload, a refused request).
        request_type: the request it decodes; None: the payload is never decoded (a describing queryable).
        cap_bytes: the largest payload read; None: no cap (only with no request type: the payload is not read).
        refused: the verb's refusal reply made from the error text; None: an error reply (`reply_err`).
        exact: act only on a query for exactly `key` (every verb that acts); False: answer any query that
            reaches it (info/*, which only describes).
        bad_input: counts a payload that does not decode (default: `refusals`); ctl/advance counts it with the
            robot's refused commands.
        count_refused_replies: count a reply whose `ok` is False with the refusals (a ctl verb's refused
            request); False where the handler counts its own (ctl/advance: a refused command).
    """

    def __init__(self, session: zenoh.Session, key: str, handle: Callable[[TypedQuery[Req, Rep]], None],
                 reply_type: type[Rep], refusals: Refusals, request_type: type[Req] | None = None,
                 cap_bytes: int | None = None, refused: Callable[[str], Rep] | None = None, exact: bool = True,
                 bad_input: Callable[[object, str], str] | None = None, count_refused_replies: bool = True) -> None:
        if request_type is not None and cap_bytes is None:
            raise ValueError("a queryable that decodes its payload needs a size cap")
        self.key = key
        self.refusals = refusals
        self.reply_codec = Codec(reply_type)
        self._handle = handle
        self._request_codec = None if request_type is None else Codec(request_type)
        self._cap_bytes = cap_bytes
        self._refused = refused
        self._exact = exact
        self._bad_input = bad_input or refusals.refuse
        self.count_refused_replies = count_refused_replies
        self._queryable = session.declare_queryable(key, self._on_query)

    def send_refusal(self, query: zenoh.Query, text: str, fmt: Format) -> None:
        """Send a refusal, already counted, in the verb's own shape."""
        if self._refused is None:
            query.reply_err(text.encode())
        else:
            reply(query, self.key, self._refused(text), fmt, self.reply_codec)

    def _on_query(self, query: zenoh.Query) -> None:
        fmt: Format = "json" if wants_json(query, self._cap_bytes, bare=self._request_codec is not None) else "msgpack"
        refusal: TypedQuery[Req, Rep] = TypedQuery(query, None, fmt, self)
        if self._exact and str(query.key_expr) != self.key:
            acts = "; nothing was done" if self._request_codec is not None else ""
            refusal.refuse(f"answers only a query for exactly {self.key}{acts}")
            return
        request: Req | None = None
        if self._request_codec is None:  # a description: its payload is never read, only its size checked
            payload = query.payload
            if self._cap_bytes is not None and payload is not None and len(payload) > self._cap_bytes:
                refusal.refuse(f"payload of {len(payload)} bytes is over this key's cap of {self._cap_bytes} bytes")
                return
        else:
            assert self._cap_bytes is not None
            try:  # the size is checked before a byte is copied; an oversize payload is a bad input too
                request = decode_input(query, self._request_codec, self._cap_bytes)
            except DecodeError as exc:
                text = self._bad_input(query.key_expr, str(exc))
                try:
                    self.send_refusal(query, text, fmt)
                finally:
                    query.drop()
                return
        incoming = TypedQuery(query, request, fmt, self)
        try:
            self._handle(incoming)
        except Exception:  # a handler that raised must not leave its client without an answer
            logger.exception("the handler of %s failed", self.key)
            incoming.refuse("the handler failed; see the service's log")

    def undeclare(self) -> None:
        self._queryable.undeclare()
