"""The secure router's refusal log (``launcher/secure/refusals.py``) on lines as Zenoh 1.10 writes them.

The lines below were taken from a router's log (colours removed, ids shortened):
a cache computation on first use of a key (every message kind traced, none of
them a refusal), then the decisions proper.
"""

from __future__ import annotations

import logging

import pytest

from jara_arm.launcher.secure.refusals import RefusalLog

T = "2026-11-23T18:15:08.{:06d}Z TRACE  rx-0 ThreadId(08) zenoh::net::routing::interceptor::access_control: "
SUBJECT = "975bad on Interface(lo)+CertCommonName(olga)+Transport(Tls)+975bad"
KEY = "JARA_ARM/arm0/Common/servoON"
CACHE_BLOCK = [
    T.format(100) + f"ACL (ingress): caching permissions for `{KEY}` ...",
    T.format(110) + f"{SUBJECT} is unauthorized to Query (ingress) on {KEY}",
    T.format(112) + f"{SUBJECT} is unauthorized to Put (ingress) on {KEY}",
    T.format(114) + f"{SUBJECT} is unauthorized to Declare/Undeclare Queryable (ingress) on {KEY}",
]
DECISION = T.format(900) + f"Using cached result: 975bad is unauthorized to Query (ingress) on {KEY}"
ALLOWED = T.format(950) + "Using cached result: 975bad is authorized to Query (ingress) on JARA_ARM/arm0/Common/getState"
TLS = ("2026-11-23T18:18:42.932Z  WARN acc-0 ThreadId(05) zenoh_link_tls::unicast: invalid peer certificate: "
       "certificate expired: verification time 1 (UNIX), but certificate is not valid after 0 (1 seconds ago). "
       "Hint: increase the system open file limit.")


@pytest.fixture
def logged(caplog: pytest.LogCaptureFixture) -> pytest.LogCaptureFixture:
    caplog.set_level(logging.WARNING, "jara_arm.router")
    return caplog


def test_a_cache_computation_is_not_a_refusal_and_the_decision_is(logged: pytest.LogCaptureFixture) -> None:
    log = RefusalLog()
    for line in CACHE_BLOCK:
        log.line(line)
    assert logged.messages == []
    log.line(ALLOWED)
    assert logged.messages == []
    log.line(DECISION)
    assert logged.messages == [f"refused: olga may not Query (ingress) on {KEY}"]


def test_a_refusal_outside_a_cache_computation_is_logged(logged: pytest.LogCaptureFixture) -> None:
    log = RefusalLog()
    log.line(CACHE_BLOCK[0])
    log.line(T.format(100 + 5_000) + f"{SUBJECT} is unauthorized to Query (ingress) on {KEY}")  # 5 ms later
    assert logged.messages == [f"refused: olga may not Query (ingress) on {KEY}"]


def test_repeats_are_counted_not_repeated(logged: pytest.LogCaptureFixture, monkeypatch: pytest.MonkeyPatch) -> None:
    log = RefusalLog()
    now = [100.0]
    monkeypatch.setattr("jara_arm.launcher.secure.refusals.time.monotonic", lambda: now[0])
    log.line(CACHE_BLOCK[1].replace("T18:15:08", "T18:15:00"))  # names olga, outside any block
    for _ in range(3):
        log.line(DECISION)
    now[0] += 6.0
    log.line(DECISION)
    assert logged.messages[-1].endswith("(3 more times since)") and len(logged.messages) == 2


def test_a_refused_handshake_is_logged_without_zenohs_hint(logged: pytest.LogCaptureFixture) -> None:
    RefusalLog().line(TLS)
    assert logged.messages == ["refused connection: invalid peer certificate: certificate expired: verification time 1 "
                       "(UNIX), but certificate is not valid after 0 (1 seconds ago)."]
