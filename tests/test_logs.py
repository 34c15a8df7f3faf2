"""A log call that interrupts another in the same thread (a ``gc`` callback, a signal handler) cannot deadlock.

Each test runs a child process of its own under a timeout: the defect they guard against is a hang.
"""

from __future__ import annotations

import subprocess
import sys

from jara_arm.schema.keys import Service

GC_CHILD = """
import gc, logging, sys, zenoh
from jara_arm.schema.keys import ArmKeys, Service
from jara_arm.services.runtime.logs import ZenohLogHandler
from jara_arm.services.runtime.zenoh_args import zenoh_config

log = logging.getLogger("child")
session = zenoh.open(zenoh_config())
handler = ZenohLogHandler(session, ArmKeys("arm0"), Service(sys.argv[1]))
logging.getLogger().addHandler(handler)
logging.getLogger().setLevel(logging.INFO)
said = [0]
def _collected(phase, info):
    if phase == "stop":
        said[0] += 1
        log.info("collected %d", said[0])
gc.callbacks.append(_collected)
gc.set_threshold(1)  # a collection at almost every allocation: also inside emit, with its locks held
for i in range(3000):
    log.info("record %d %s", i, [[i]])
gc.callbacks.remove(_collected)
gc.set_threshold(700)
handler.close()
session.close()
print("done", said[0] > 0)
"""

def test_a_log_call_from_a_gc_callback_inside_the_zenoh_handler_does_not_hang() -> None:
    """The servo's start once hung so: a collection began inside the handler's ``emit``, holding a lock, and a
    ``gc`` callback logged again. ``emit`` now only puts on a ``SimpleQueue``, which is reentrant."""
    out = subprocess.run([sys.executable, "-c", GC_CHILD, Service.SERVO.value], capture_output=True, text=True,
                         timeout=30, check=True).stdout
    assert "done True" in out, out
