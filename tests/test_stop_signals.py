"""SIGINT/SIGTERM stop a service or a ``jara-arm`` command even when they come while its main thread holds
the stop event's own lock.

Each test runs a child process under a timeout: the defect they guard against is a hang (``jara-arm logs``
ignored a SIGINT in CI so, until it was killed).
"""

from __future__ import annotations

import subprocess
import sys

import pytest

SERVICE_CHILD = """
import logging, os, signal, sys, threading
from jara_arm.services.runtime.service import stop_event

logging.basicConfig(level=logging.INFO, stream=sys.stdout, format="%(message)s")
stop = stop_event()
threading.Timer(0.2, os.kill, (os.getpid(), signal.SIGTERM)).start()
while not stop.wait(0):  # the signal comes while this thread is inside the event's lock, most of the time
    pass
print("stopped")
"""

# The signal is raised while this thread holds the event's lock: a handler that set the event would wait for
# that lock in the same thread, forever. Private, but the one way to make the race certain.
COMMAND_CHILD = """
import os, signal, sys
from jara_arm.services.runtime.stop_signals import StopSignals

signals = StopSignals()
with signals.stop._cond:
    os.kill(os.getpid(), getattr(signal, sys.argv[1]))
    os.kill(os.getpid(), getattr(signal, sys.argv[1]))
print("stopped" if signals.stop.wait(10) else "not stopped", signals.name)
print("hurried" if signals.hurry.wait(10) else "not hurried")
"""


def test_a_signal_while_a_service_waits_on_its_stop_event_stops_it() -> None:
    out = subprocess.run([sys.executable, "-c", SERVICE_CHILD], capture_output=True, text=True, timeout=30,
                         check=True).stdout
    assert "received SIGTERM, shutting down" in out and out.rstrip().endswith("stopped"), out


@pytest.mark.parametrize("name", ["SIGINT", "SIGTERM"])
def test_a_signal_while_a_command_holds_its_stop_events_lock_stops_it_and_a_second_hurries_it(name: str) -> None:
    out = subprocess.run([sys.executable, "-c", COMMAND_CHILD, name], capture_output=True, text=True, timeout=30,
                         check=True).stdout
    assert out.split("\n")[:2] == [f"stopped {name}", "hurried"], out
