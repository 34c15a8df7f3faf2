"""Real-time scheduling of a whole process (``realtime_process``), in a child process of its own."""

from __future__ import annotations

import gc
import logging
import subprocess
import sys

import pytest

CHILD = """
import logging, sys, threading
from jara_arm.services.runtime.realtime import realtime_process
logging.basicConfig(level=logging.INFO, format="%(levelname)s %(message)s", stream=sys.stdout)
threading.Thread(target=threading.Event().wait, daemon=True).start()
print("first", realtime_process(int(sys.argv[1]), "the first call"))
print("second", realtime_process(int(sys.argv[1]) - 1, "the second call"))
"""


def test_a_second_call_on_threads_already_real_time_says_nothing() -> None:
    """The alarm monitor sets its threads in its start and the service skeleton once more after: the second
    call finds no thread left under the normal scheduler, sets none and warns of no missing permission."""
    out = subprocess.run([sys.executable, "-c", CHILD, "5"], capture_output=True, text=True, timeout=30,
                         check=True).stdout
    if "first 0" in out:
        pytest.skip("no permission for SCHED_FIFO here")
    assert "INFO the first call: 2 threads run with SCHED_FIFO priority 5" in out, out
    assert "second 0" in out and "the second call" not in out, out


def test_without_permission_the_call_says_so() -> None:
    """A priority the kernel refuses (above 99) is said: the threads stay under the normal scheduler."""
    out = subprocess.run([sys.executable, "-c", CHILD, "100"], capture_output=True, text=True, timeout=30,
                         check=True).stdout
    assert "first 0" in out and "WARNING the first call without real-time priority (no permission?)" in out, out


def test_a_long_collection_is_kept_in_the_callback_and_said_after(monkeypatch: pytest.MonkeyPatch,
                                                                 caplog: pytest.LogCaptureFixture) -> None:
    """The servo's GC watch logs nothing from inside the collection (a collection can start within a log
    handler holding its lock: logging again from there deadlocked a servo's start) and says it on ``say()``."""
    from jara_arm.services.servo import clock

    monkeypatch.setattr(clock, "GC_PAUSE_LOGGED", 0.0)
    watch = clock.GcWatch()
    gc.callbacks.append(watch)
    try:
        with caplog.at_level(logging.WARNING, logger=clock.__name__):
            gc.collect()
            assert watch.long and not caplog.records, caplog.records
            watch.say()
    finally:
        gc.callbacks.remove(watch)
    assert not watch.long
    assert any("garbage collection (generation 2" in r.getMessage() for r in caplog.records), caplog.records
