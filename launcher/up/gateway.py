"""The cell bus and the client gateway: no client shares a dispatch queue with the control path.

A Zenoh router forwards each message to the sessions that want it one after the other, on the
thread that received it (eclipse-zenoh/zenoh#2585, "subscriber sessions share fate"): a session
whose queue is full holds that thread up (``wait_before_drop`` for a droppable message, up to
``wait_before_close`` for a blocking one), and with it every other session's messages from the same
sender. With services and user tools on one router, one slow GUI stalled the heartbeats and the
motion hand-overs of an arm. So ``jara-arm up`` runs two routers:

- the **cell bus**, in the launcher process (real-time priority): only the cell's own services join
  it, on a private endpoint (a Unix socket in a directory only the cell's user can open).
  Everything that keeps an arm safe and fed travels here.
- the **client gateway**, a process of its own at normal priority, listening on ``--listen``: every
  client joins it, and it joins the bus as one more router. It turns every publication it forwards
  into best effort (``drop``) and drops at once what a client's full queue cannot take; a client
  stuck so long that a blocking message (a declaration) cannot reach it for
  :data:`GATEWAY_WAIT_BEFORE_CLOSE` is disconnected. So the worst a client can do is lose samples of
  its own and slow other clients; the bus sees one reader, the gateway, which never waits on anyone.

The 1 kHz feedback crosses the bus in blocks (``Servo/posFeedbackBlock``, :data:`FEEDBACK_BLOCK_CYCLES
<jara_arm.services.runtime.timing.FEEDBACK_BLOCK_CYCLES>` samples each): the gateway
takes them and publishes the samples one by one on ``Servo/posFeedback`` to its clients, and only while
one subscribes (:class:`FeedbackRelay`; while none does, the gateway takes no block and the servo builds none). So a client's 1 kHz stream costs the real-time side, the servo
and the bus, one message per block, not one per cycle.

On the bus, the only blocking publications (a low-level client's ``Servo/posCmd``, ``Traffic.STREAM``)
are turned into best effort on their way to the gateway (by the gateway's Zenoh id), so a gateway that
falls behind costs the bus nothing but those samples. A reply travels with its query's congestion
control and priority: the services' queriers ask with ``Traffic.REPLY`` (best effort), and the
gateway makes every client's query best effort on its way in.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import queue
import shutil
import tempfile
import threading
from collections.abc import Iterator, Sequence

import zenoh

from jara_arm.schema.encoding import Encoding
from jara_arm.schema.errors import JaraArmError
from jara_arm.schema.keys import ANY_ARM, ArmKeys, arm_of
from jara_arm.schema.messages import feedback_block_samples
from jara_arm.schema.roles import BUS_SUBJECT, Role
from jara_arm.schema.traffic import Traffic
from jara_arm.services.runtime.wire import Publication

log = logging.getLogger("jara_arm.launcher")

#: The gateway's Zenoh id (hex of "jaragate"): the bus knows its link by it. One gateway per cell bus
#: by default; give each further gateway its own (``--gateway-id``) and tell the bus every one.
GATEWAY_ZID = "6a61726167617465"
#: The cell bus's Zenoh id (hex of "jarabus"): its gateways know their link to it by it.
BUS_ZID = "6a617261627573"
#: How long a gateway waits for room in a client's queue before dropping a droppable message [µs]. A
#: client that cannot take a sample loses it after this wait, and the wait is the whole cost to others:
#: 0.1 ms per sample to a frozen client, where Zenoh's default of 1 ms at 1 kHz per arm took the whole of
#: the forwarding thread. Not zero: a healthy client's queue is full for a few microseconds at times.
GATEWAY_WAIT_BEFORE_DROP = 100
#: Batches in each of a client link's queues below real time (Zenoh's default is 2, the most 16): with
#: the samples to clients batched (not express), a queue takes thousands of them before a drop.
GATEWAY_QUEUE_BATCHES = 16
#: The same for a message too big for one batch (its fragments) [µs]: the world model, once a second.
GATEWAY_WAIT_FRAGMENTS = 1_000
#: How long a gateway waits to send a blocking message (a declaration) to a client before it closes that
#: client's session [µs]: a client whose queue stays full this long is stuck (stopped, frozen, gone),
#: and while the gateway waits it forwards nothing. Zenoh's default is 5 s.
GATEWAY_WAIT_BEFORE_CLOSE = 500_000
#: How long the bus waits for room in a link's queue before dropping a droppable message [µs]. The
#: services drain their links at once; a queue that is full is a session that does not read (the
#: gateway starved, a service stopped), and waiting on it would stall the sender's other messages.
BUS_WAIT_BEFORE_DROP = 50


def _deep_queues(conf: zenoh.Config) -> None:
    """:data:`GATEWAY_QUEUE_BATCHES` batches in every queue of ``conf``'s links below real time."""
    for priority in ("interactive_low", "data_high", "data", "data_low", "background"):
        conf.insert_json5(f"transport/link/tx/queue/size/{priority}", str(GATEWAY_QUEUE_BATCHES))


def gateway_config(conf: zenoh.Config, zid: str = GATEWAY_ZID) -> None:
    """Make ``conf`` (a router's) a client gateway's: best effort to every client, never waiting on one.

    Towards the bus (its Zenoh id :data:`BUS_ZID`) a client's publications block instead: a low-level
    client's position commands (``Servo/posCmd``, a SyncFIFO where every command counts) would otherwise
    be lost in bursts at a zero wait. That waits on the bus only, which reads at once; a client that
    floods waits on its own link.
    """
    conf.insert_json5("id", json.dumps(zid))
    queue = "transport/link/tx/queue/congestion_control"
    conf.insert_json5(f"{queue}/drop/wait_before_drop", str(GATEWAY_WAIT_BEFORE_DROP))
    conf.insert_json5(f"{queue}/drop/max_wait_before_drop_fragments", str(GATEWAY_WAIT_FRAGMENTS))
    conf.insert_json5(f"{queue}/block/wait_before_close", str(GATEWAY_WAIT_BEFORE_CLOSE))
    _deep_queues(conf)
    reply = Traffic.REPLY.value
    conf.insert_json5("qos/network", json.dumps([
        # Batched, not express: a queue slot then holds hundreds of samples, not one.
        {"id": "clients-best-effort", "messages": ["put", "delete"], "flows": ["egress"],
         "overwrite": {"congestion_control": "drop", "express": False}},
        # A reply travels with its query's congestion control and priority: a client's blocking query would
        # get a reply that waits on that client. Its queries are made best effort on the way in, and of the
        # reply class's priority, so that the reply does not queue behind the client's own streams.
        {"id": "client-queries-best-effort", "messages": ["query"], "flows": ["ingress"],
         "overwrite": {"congestion_control": reply.congestion, "priority": reply.priority}},
        # After the rule above, which it overrides on this one link (Zenoh applies the rules in order).
        {"id": "to-the-bus-reliably", "zids": [BUS_ZID], "messages": ["put", "delete"], "flows": ["egress"],
         "overwrite": {"congestion_control": "block"}}]))
    _relay_access(conf, BUS_ZID)


def _relay_access(conf: zenoh.Config, bus: str) -> None:
    """The gateway's own ``Servo/posFeedback`` (:class:`FeedbackRelay`) never reaches the bus, nor do its
    clients' subscriptions of that key: with two gateways on one bus, each serves its own clients, once.

    Zenoh allows a message on a link if any of the link's subjects allows it, and a deny wins only within
    one subject. So in a secure cell the deny joins the policies the bus link already has (``cell-bus`` over
    the Unix socket, ``router`` over TLS: ``schema/roles.py``), and each link keeps one subject. A subject of
    its own for the bus (by Zenoh id) left the deny without effect there, and Zenoh traced a denial by it for
    every message of the bus whenever a per-process hash order put it first: the refusal log then reported
    the whole bus refused (7 secure starts of 14), and the gateway took 6.4-7.0 % of a core instead of 5.0-5.3 %."""
    acl = json.loads(conf.get_json("access_control"))
    rule = "gateway relay stays off the bus"
    upstream = [p for p in (acl.get("policies") or []) if {BUS_SUBJECT, Role.ROUTER.value} & set(p["subjects"])]
    if not (acl.get("enabled") and upstream):  # an open cell (or access control of the user's own): by Zenoh id
        if not acl.get("enabled"):
            acl = {"enabled": True, "default_permission": "allow", "rules": [], "subjects": [], "policies": []}
        acl["subjects"] = [*(acl.get("subjects") or []), {"id": "the cell bus", "zids": [bus]}]
        upstream = [{"id": rule, "rules": [], "subjects": ["the cell bus"]}]
        acl["policies"] = [*(acl.get("policies") or []), *upstream]
    acl["rules"] = [*(acl.get("rules") or []), {
        "id": rule, "messages": ["put", "declare_subscriber"], "flows": ["egress"], "permission": "deny",
        "key_exprs": [ArmKeys(ANY_ARM).pos_feedback]}]
    for policy in upstream:
        policy["rules"] = [*policy["rules"], rule]
    conf.insert_json5("access_control", json.dumps(acl))


def bus_config(conf: zenoh.Config, gateways: Sequence[str] = (GATEWAY_ZID,)) -> None:
    """Make ``conf`` (a router's) the cell bus's: its blocking stream reaches ``gateways`` as best effort."""
    conf.insert_json5("id", json.dumps(BUS_ZID))
    queue = "transport/link/tx/queue/congestion_control"
    conf.insert_json5(f"{queue}/drop/wait_before_drop", str(BUS_WAIT_BEFORE_DROP))
    # Replies to clients travel best effort (their queries were made so): room for a burst of them, and
    # of samples, on the link to a gateway that falls behind for a moment (memory taken only when used).
    _deep_queues(conf)
    if gateways:
        conf.insert_json5("qos/network", json.dumps([
            {"id": "to-gateways-best-effort", "zids": list(gateways), "messages": ["put", "delete"],
             "flows": ["egress"], "overwrite": {"congestion_control": "drop", "express": False}}]))


@contextlib.contextmanager
def private_bus() -> Iterator[str]:
    """A private endpoint for the cell bus, for as long as the context lasts: a Unix socket in a fresh
    directory of mode 0700. Only this OS user's processes can join it, no TCP client can reach it,
    and in a secure cell it spares the bus TLS (which cost the real-time router enough CPU to starve
    the planner's stream beside a TLS observer); the cell's roles give it the router role."""
    directory = tempfile.mkdtemp(prefix="jara-arm-bus-")
    os.chmod(directory, 0o700)
    try:
        yield f"unixsock-stream/{directory}/bus.sock"
    finally:
        shutil.rmtree(directory, ignore_errors=True)


#: Blocks the relay holds for its thread before it drops the newest (100 a second per arm arrive).
RELAY_QUEUE = 1024


class FeedbackRelay:
    """The gateway's ``Servo/posFeedback``: each ``Servo/posFeedbackBlock`` from the bus, sample by sample,
    to the gateway's clients, while one of them subscribes (the arm's publisher here matches).

    The relay subscribes to the blocks only while some client of the gateway subscribes to any arm's
    ``posFeedback`` (a publisher on ``*/Servo/posFeedback`` here, for its matching status): otherwise the
    servo builds no block and the bus carries none. An idle cell then costs 100 messages a second per arm
    less on the servo, the bus and the gateway (``docs/architecture.md``, "Feedback in blocks").

    The Zenoh callbacks only queue; a thread of its own declares, unpacks and publishes, so a slow relay
    loses blocks of its own (:attr:`dropped`) and holds up no routing. A block that is not one, or that
    cannot be published, is dropped and logged once per key.
    """

    def __init__(self, session: zenoh.Session) -> None:
        self._session = session
        self._blocks: queue.Queue[zenoh.Sample | bool | None] = queue.Queue(RELAY_QUEUE)
        self._publications: dict[str, Publication] = {}
        self._lock = threading.Lock()
        self._said: set[str] = set()
        self.relayed = self.dropped = 0  # samples published; blocks lost to a full queue
        self._sub: zenoh.Subscriber | None = None  # the blocks' subscription, while wanted (the thread's)
        self._demand = session.declare_publisher(ArmKeys(ANY_ARM).pos_feedback)  # never put: its matching
        self._wanted = False
        self._demand_listener = self._demand.declare_matching_listener(self._on_demand)
        self._thread = threading.Thread(target=self._run, name="feedback-relay", daemon=True)
        self._thread.start()
        self._on_demand(self._demand.matching_status)

    def _on_demand(self, status: zenoh.MatchingStatus) -> None:
        self._wanted = status.matching
        # A full queue: the thread is busy and looks at the demand after every block anyway.
        with contextlib.suppress(queue.Full):
            self._blocks.put_nowait(status.matching)

    def _take(self, sample: zenoh.Sample) -> None:
        try:
            self._blocks.put_nowait(sample)
        except queue.Full:
            self.dropped += 1

    @property
    def relaying(self) -> bool:
        """Whether the relay subscribes to the arms' blocks (a client of the gateway wants feedback)."""
        return self._sub is not None

    def _publication(self, arm: str) -> Publication:
        with self._lock:  # the relay's thread and :meth:`wanted`'s caller
            pub = self._publications.get(arm)
            if pub is None:
                # Not express: a block's samples leave in one batch. Sent one by one (express), a burst
                # of ten outran the client's transmission queue beside busy cores and lost samples.
                pub = self._publications[arm] = Publication(self._session, ArmKeys(arm).pos_feedback,
                                                            Encoding.MSGPACK, express=False)
            return pub

    def wanted(self, arm: str) -> bool:
        """Whether a subscriber of ``arm``'s ``Servo/posFeedback`` is there to relay to."""
        return self._publication(arm).publisher.matching_status.matching

    def _follow_demand(self) -> None:
        if self._wanted and self._sub is None:
            self._sub = self._session.declare_subscriber(ArmKeys(ANY_ARM).pos_feedback_block, self._take)
        elif not self._wanted and self._sub is not None:
            self._sub.undeclare()
            self._sub = None

    def _run(self) -> None:
        while (item := self._blocks.get()) is not None:
            self._follow_demand()
            if isinstance(item, bool):
                continue
            key = str(item.key_expr)
            try:
                pub = self._publication(arm_of(key))
                if not pub.publisher.matching_status.matching:
                    continue
                for payload in feedback_block_samples(item.payload.to_bytes()):
                    pub.put(payload)
                    self.relayed += 1
            except (JaraArmError, zenoh.ZError) as exc:  # a block that is not one (WireError), a put refused
                if key not in self._said:
                    self._said.add(key)
                    log.warning("feedback relay: dropped a block on %s: %s", key, exc)
        if self._sub is not None:
            self._sub.undeclare()
            self._sub = None

    def close(self) -> None:
        """Stop relaying: the demand's listener, then the thread (it undeclares the blocks), then the publishers."""
        self._demand_listener.undeclare()
        self._demand.undeclare()
        with contextlib.suppress(queue.Full):
            self._blocks.put(None, timeout=1.0)
        self._thread.join(timeout=2.0)
        for pub in self._publications.values():
            pub.close()
