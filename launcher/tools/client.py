"""A typed Python client of one arm: every operation by its IDL name, over plain Zenoh queries.

Clients in other languages need nothing of this: it only spares Python users
the encoding (``schema.codec``) and the key expressions (``schema.keys``).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Mapping
from typing import Any

import zenoh

from jara_arm.schema import codec
from jara_arm.schema.codec import Reply
from jara_arm.schema.codes import StateBit
from jara_arm.schema.errors import JaraArmError
from jara_arm.schema.keys import ArmKeys, Service
from jara_arm.schema.operations import OP, Interface, operation
from jara_arm.services.runtime.ask import Asker, Silence


class ClientError(JaraArmError, RuntimeError):
    """No answer, or not exactly one, from the service behind a key."""


class ArmClient:
    """Calls ``Common``, ``Middle``, ``Ext`` and ``Servo/Common`` operations of one arm."""

    def __init__(self, session: zenoh.Session, arm: str = "arm0", timeout: float = 10.0) -> None:
        self.session = session
        self.keys = ArmKeys(arm)
        self.timeout = timeout  # [s] per query
        self._askers: dict[tuple[str, float], Asker] = {}
        self._lock = threading.Lock()

    def _asker(self, key: str) -> Asker:
        with self._lock:  # one querier per key (and timeout), whichever thread asks first
            asker = self._askers.get((key, self.timeout))
            if asker is None:
                asker = self._askers[(key, self.timeout)] = Asker(self.session, key, self.timeout)
            return asker

    def close(self) -> None:
        """Undeclare the queriers (the session's closing does it too)."""
        with self._lock:
            for asker in self._askers.values():
                asker.close()
            self._askers.clear()

    def call(self, interface: Interface, name: str, args: Mapping[str, Any] | None = None,
             *, servo: bool = False) -> Reply:
        """One query; ``servo=True`` asks the low level (``Servo/Common``) instead of the command service."""
        op = operation(interface, name)
        key = self.keys.servo_common(name) if servo else self.keys.interface(interface, name)
        got = self._asker(key).ask(codec.encode_request(op, args))
        if isinstance(got, Silence):
            raise ClientError(got.why)
        return codec.decode_reply(op, got.payload, got.encoding)

    def common(self, name: str, args: Mapping[str, Any] | None = None) -> Reply:
        return self.call(Interface.COMMON, name, args)

    def middle(self, name: str, args: Mapping[str, Any] | None = None) -> Reply:
        return self.call(Interface.MIDDLE, name, args)

    def ext(self, name: str, args: Mapping[str, Any] | None = None) -> Reply:
        return self.call(Interface.EXT, name, args)

    def servo(self, name: str, args: Mapping[str, Any] | None = None) -> Reply:
        return self.call(Interface.COMMON, name, args, servo=True)

    def state(self) -> int:
        return int(self.common(OP.getState)["state"])

    def wait_alive(self, services: tuple[Service, ...], timeout: float = 30.0) -> None:
        """Until every service's liveliness token is up (connectivity, not health)."""
        deadline = time.monotonic() + timeout
        for service in services:
            while not list(self.session.liveliness().get(self.keys.alive(service), timeout=1.0)):
                if time.monotonic() > deadline:
                    raise ClientError(f"{service.value} of {self.keys.arm} is not running")
                time.sleep(0.1)

    def wait_idle(self, timeout: float = 60.0, poll: float = 0.02) -> float:
        """Until the arm neither moves nor has queued motions (or is paused); returns [s] waited."""
        t0 = time.monotonic()
        time.sleep(poll)
        while True:
            state = self.state()
            if not state & StateBit.MOVING or state & StateBit.PAUSED or state & StateBit.ALARM:
                return time.monotonic() - t0
            if time.monotonic() - t0 > timeout:
                raise ClientError(f"the arm still moves after {timeout} s (state 0x{state:02x})")
            time.sleep(poll)
