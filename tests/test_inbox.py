"""``runtime/inbox.py``: a thread reading several Zenoh inputs sleeps until one brings something."""

from __future__ import annotations

import threading
import time

import zenoh

from jara_arm.services.runtime.inbox import Inbox
from jara_arm.services.runtime.zenoh_args import zenoh_config

from .support import client_session, endpoint, free_port


def test_a_full_box_keeps_the_newest_and_counts_what_it_dropped() -> None:
    inbox = Inbox()
    box = inbox.box(3)
    for k in range(5):
        box(k)
    assert [box.try_recv() for _ in range(4)] == [2, 3, 4, None]
    assert box.dropped == 2


def test_wait_returns_when_a_box_gets_a_sample_and_not_before() -> None:
    inbox = Inbox()
    box = inbox.box(4)
    assert inbox.wait(0.05) is False  # nothing came: the whole timeout
    threading.Timer(0.05, box, args=("sample",)).start()
    t0 = time.monotonic()
    assert inbox.wait(5.0) is True
    assert time.monotonic() - t0 < 2.0 and box.try_recv() == "sample"
    inbox.ring()  # a stop, or a call handed to the thread: it wakes as for a sample
    assert inbox.wait(5.0) is True


def test_spacing_batches_what_comes_sooner() -> None:
    inbox = Inbox()
    box = inbox.box(16)
    inbox.wait(0.0)
    box(1)
    box(2)
    t0 = time.monotonic()
    assert inbox.wait(1.0, spacing=0.2)
    assert time.monotonic() - t0 >= 0.15  # the rest of the 0.2 s since the last return
    assert [box.try_recv(), box.try_recv(), box.try_recv()] == [1, 2, None]


def test_a_zenoh_subscriber_fills_its_box_in_order_and_wakes_the_reader() -> None:
    port = free_port()
    with zenoh.open(zenoh_config("router", listen=[endpoint(port)])) as router, client_session(port) as client:
        inbox = Inbox()
        box = inbox.box(64)
        sub = router.declare_subscriber("inbox/test", box)
        pub = client.declare_publisher("inbox/test")
        deadline = time.monotonic() + 10.0
        while not pub.matching_status.matching and time.monotonic() < deadline:
            inbox.wait(0.01)
        for k in range(10):
            pub.put(str(k))
        got: list[str] = []
        while len(got) < 10 and time.monotonic() < deadline:
            inbox.wait(1.0)
            got.extend(s.payload.to_string() for s in iter(box.try_recv, None))
        assert got == [str(k) for k in range(10)]
        pub.undeclare()
        sub.undeclare()
