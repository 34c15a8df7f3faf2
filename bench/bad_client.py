"""A client that behaves badly, as users' tools do: slow, frozen or flooding. Plain Zenoh only.

    python bench/bad_client.py slow    --connect EP [--key KEY] [--delay-ms 20]
    python bench/bad_client.py frozen  --connect EP [--key KEY]
    python bench/bad_client.py flood   --connect EP [--key KEY] [--sessions 10]
    (every kind also takes --config FILE: a Zenoh configuration, e.g. a secure cell identity's .json5)

Default keys (from ``schema/keys.py``): every key of every arm (slow), every arm's
``Servo/posFeedback`` (frozen), arm0's ``Common/getState`` (flood).

- ``slow``: subscribes to ``--key`` and spends ``--delay-ms`` in each sample's callback, on Zenoh's own
  thread, as a GUI or logger on a busy PC does (the very thing the Zenoh guide says not to do).
- ``frozen``: subscribes to ``--key`` and then reads nothing: freeze it with ``kill -STOP`` (a process held
  in a debugger, a laptop whose lid closed) and its socket fills; ``kill -CONT`` lets it go on.
- ``flood``: ``--sessions`` clients (a session and a thread each), each sending one query after another
  on ``--key`` as fast as the replies come.

Prints ``bad client ready`` once its subscription or first reply is in place, then, every second,
``bad client: N samples`` (or replies). Runs until killed. Besides the default keys of the schema it
uses nothing of ours: plain Zenoh sessions, as users' tools are.
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time

import zenoh

from jara_arm.schema.keys import ANY_ARM, ArmKeys, any_arm_every_key
from jara_arm.schema.operations import OP, Interface

DEFAULT_KEYS = {"slow": any_arm_every_key(), "frozen": ArmKeys(ANY_ARM).pos_feedback,
                "flood": ArmKeys().interface(Interface.COMMON, OP.getState)}


def session(args: argparse.Namespace) -> zenoh.Session:
    conf = zenoh.Config.from_file(args.config) if args.config else zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([args.connect]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    return zenoh.open(conf)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("kind", choices=("slow", "frozen", "flood"))
    ap.add_argument("--connect", required=True, metavar="ENDPOINT")
    ap.add_argument("--config", metavar="FILE")
    ap.add_argument("--key", help="default: " + ", ".join(f"{k} ({kind})" for kind, k in DEFAULT_KEYS.items()))
    ap.add_argument("--delay-ms", type=float, default=20.0, help="slow: time spent per sample [ms]")
    ap.add_argument("--sessions", type=int, default=10, help="flood: how many clients (sessions) [1..100]")
    args = ap.parse_args()
    key = args.key or DEFAULT_KEYS[args.kind]
    if not 1 <= args.sessions <= 100:
        ap.error(f"--sessions {args.sessions}: between 1 and 100")
    count = [0]
    if args.kind == "flood":
        sessions = [session(args) for _ in range(args.sessions)]

        def flood(s: zenoh.Session) -> None:
            while True:
                for _ in s.get(key, payload=b"{}", timeout=10.0):
                    count[0] += 1  # a race between threads at worst loses a count

        for s in sessions:
            threading.Thread(target=flood, args=(s,), daemon=True).start()
        print("bad client ready", flush=True)
        while True:
            time.sleep(1.0)
            print(f"bad client: {count[0]} replies", flush=True)
    with session(args) as s:

        def slow(_: zenoh.Sample) -> None:
            count[0] += 1
            time.sleep(args.delay_ms / 1e3)

        def frozen(_: zenoh.Sample) -> None:
            count[0] += 1

        sub = s.declare_subscriber(key, slow if args.kind == "slow" else frozen)
        print("bad client ready", flush=True)
        stop = threading.Event()
        while not stop.wait(1.0):
            print(f"bad client: {count[0]} samples", flush=True)
        sub.undeclare()
    return 0


if __name__ == "__main__":
    sys.exit(main())
