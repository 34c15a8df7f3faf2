"""Serve an IDL interface as Zenoh queryables, one handler method per operation.

A handler is any object with methods named exactly as the IDL operations
(``def getState(self) -> Reply``), taking the decoded ``in`` parameters as
keyword arguments. The Zenoh side only hands queries to a channel; one worker
thread decodes, calls the handler and replies, so that replies keep the order
of the queries and nothing runs on Zenoh's own threads.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Mapping
from typing import Any

import zenoh

from jara_arm.schema import codec
from jara_arm.schema.codec import Encoding, Reply
from jara_arm.schema.codes import ReturnCode
from jara_arm.schema.errors import Refusal
from jara_arm.schema.keys import op_of
from jara_arm.schema.operations import Operation

from .entities import Entities
from .timing import DEADLINE_GRACE
from .trace import CallTracer
from .wire import reply

log = logging.getLogger(__name__)

_CHANNEL_CAPACITY = 1024


def expired(query: zenoh.Query) -> float | None:
    """[s] since the requester gave up on ``query`` (its attachment's deadline), or None if it still waits.

    Dropping such a query keeps a service that was held up (SIGSTOP, a stall)
    from acting late on requests already answered by a timeout or a fallback:
    a servoON, a motion or a clearAlarms nobody waits for any more.
    """
    attachment = query.attachment
    deadline = codec.attachment_deadline(attachment.to_bytes() if attachment is not None else None)
    if deadline is None:
        return None
    late = time.time() - deadline
    return late if late > DEADLINE_GRACE else None


def ok(comment: str = "OK", **outs: Any) -> Reply:
    return Reply(ReturnCode.OK, comment, outs)


def answer(op: Operation | None, payload: bytes, encoding: Encoding, handler: object,
           name: str) -> Reply:
    """The reply to one query: decode strictly, call the handler, never raise. A handler returns its
    reply, or raises :class:`Refusal` (a :class:`WireError` for a bad value): its code and comment."""
    if op is None:
        return Reply(ReturnCode.NOT_IMPLEMENTED, f"no operation {name!r} in this interface")
    try:
        args = codec.decode_request(op, payload, encoding)
        reply: Reply = getattr(handler, op.name)(**args)
    except Refusal as exc:
        return Reply(exc.code, exc.comment)
    except Exception as exc:  # a bug of ours must not kill the service or leave a query unanswered
        log.exception("%s failed", op.name)
        return Reply(ReturnCode.NG, f"internal error in {op.name}: {exc}")
    return reply


#: ``(query's key, payload, encoding) -> (reply's key, reply body)``: one endpoint's answer, in
#: the request's encoding (``Encoding.of_request``), which the reply is labelled with.
Answer = Callable[[str, bytes, Encoding], tuple[str, bytes]]


class QueryServer:
    """Queryable ``key`` answered by ``answer`` on one worker thread, in the order of the queries.

    The one query loop of the project: a query whose requester already gave up
    (:func:`expired`) is dropped unanswered, an exception in ``answer`` is logged
    (the caller times out; the service lives on), and every query is finished
    (``drop``) at once, not at garbage collection.
    """

    def __init__(self, session: zenoh.Session, key: str, answer: Answer, name: str,
                 encoding: Encoding | None = None) -> None:
        self._answer = answer
        self._encoding = encoding  # the key's own, if it has one; else the request's (keys.KeyEncoding.AS_REQUEST)
        self._entities = Entities()
        self._queryable = self._entities.enter_context(
            session.declare_queryable(key, zenoh.handlers.FifoChannel(_CHANNEL_CAPACITY)))
        self._busy = threading.Event()  # set while the worker answers a query (not while it waits in recv)
        self._thread = threading.Thread(target=self._serve, name=name, daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        while True:
            try:
                query = self._queryable.recv()
            except Exception:  # the queryable was undeclared: we are shutting down
                return
            self._busy.set()
            try:
                if (late := expired(query)) is not None:
                    log.warning("dropped %s unanswered: its requester gave up %.0f ms ago (this service was "
                                "held up, or the clocks differ)", query.key_expr, late * 1e3)
                    continue
                payload = query.payload.to_bytes() if query.payload is not None else b""
                # JSON text is JSON whatever its label: generic tools send it unlabelled
                encoding = Encoding.of_request(payload, query.encoding) if self._encoding is None else self._encoding
                key, body = self._answer(str(query.key_expr), payload, encoding)
                reply(query, key, body, encoding)
                self._replied(key, payload, encoding, body)
            except Exception:
                log.exception("could not reply to %s", query.key_expr)
            finally:
                query.drop()  # sends the final reply marker now, not at garbage collection
                self._busy.clear()

    def _replied(self, key: str, request: bytes, encoding: Encoding, reply: bytes) -> None:
        """After each reply (on the worker thread): nothing here."""

    def close(self) -> None:
        """Stop serving. The worker may sit in ``recv()``, which holds the queryable; it
        ends when the session closes, so call :meth:`join` after the session's block."""
        self._entities.close()  # the queryable may stay held by recv(): Entities logs it
        if self._busy.is_set():  # let the answer in hand go out while the session is still open
            self._thread.join(timeout=0.2)

    def join(self, timeout: float = 2.0) -> None:
        """Wait for the worker to end (after the session closed): a thread still inside
        Zenoh's ``recv()`` when the interpreter exits aborts the process."""
        self._thread.join(timeout)
        if self._thread.is_alive():
            log.warning("query worker %s did not end", self._thread.name)


class InterfaceServer(QueryServer):
    """Queryable ``key_all`` (``.../<Interface>/*``) answered by ``handler``, one method per operation;
    each call answered is published on its trace key while something subscribes (:class:`CallTracer`)."""

    def __init__(self, session: zenoh.Session, key_all: str, table: Mapping[str, Operation],
                 handler: object, name: str = "rpc") -> None:
        missing = [op for op in table if not callable(getattr(handler, op, None))]
        if missing:
            raise TypeError(f"{type(handler).__name__} lacks operations {missing}")
        self._table, self._handler = table, handler
        self._base = key_all.rsplit("/", 1)[0]  # replies name the concrete key, e.g. for JARA_ARM/*/... queries
        self._tracer = CallTracer(session, key_all)
        super().__init__(session, key_all, self._answer_operation, name)

    def _replied(self, key: str, request: bytes, encoding: Encoding, reply: bytes) -> None:
        self._tracer.publish(key, request, encoding, reply)

    def close(self) -> None:
        super().close()
        self._tracer.close()

    def _answer_operation(self, key: str, payload: bytes, encoding: Encoding) -> tuple[str, bytes]:
        name = op_of(key)
        op = self._table.get(name)
        reply = answer(op, payload, encoding, self._handler, name)
        if op is None:
            return key, codec.dumps({"id": int(reply.id), "comment": reply.comment}, encoding)
        try:
            body = codec.encode_reply(op, reply, encoding)
        except Exception as exc:
            log.exception("%s produced a reply that cannot be encoded", name)
            body = codec.dumps({"id": int(ReturnCode.NG), "comment": f"internal error in {name}: {exc}"}, encoding)
        return f"{self._base}/{name}", body
