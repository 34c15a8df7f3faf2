"""Round trip of ``Servo/Common/getState`` against a bare Zenoh queryable, same run.

    python bench/query_rtt.py [--n 3000]

Both go through the launcher's router: the client connects to it, the servo is
one of its services, and the bare queryable (a separate process, replying a
fixed MessagePack map) connects to it too. Queries alternate between the two so
that machine noise hits both alike. Reported: p50, p99 and the p50 ratio.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from _system import client, launched_system  # noqa: E402

from jara_arm.schema import codec  # noqa: E402
from jara_arm.schema.keys import ArmKeys  # noqa: E402
from jara_arm.schema.operations import COMMON, OP  # noqa: E402

BARE_KEY = "bench/bare/getState"  # not part of the JARA_ARM contract: a plain Zenoh queryable

BARE = textwrap.dedent("""
    import sys, time, msgpack, zenoh
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", '["tcp/127.0.0.1:%s"]' % sys.argv[1])
    conf.insert_json5("scouting/multicast/enabled", "false")
    body = msgpack.packb({"id": 0, "comment": "OK", "state": 0})
    with zenoh.open(conf) as s:
        q = s.declare_queryable(sys.argv[2], zenoh.handlers.FifoChannel(256))
        print("bare up", flush=True)
        while True:
            query = q.recv()
            query.reply(query.key_expr, body)
            query.drop()
""")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=3000)
    args = ap.parse_args()
    keys = ArmKeys("arm0")
    op = COMMON[OP.getState]
    request = codec.encode_request(op)
    with launched_system() as port:
        bare = subprocess.Popen([sys.executable, "-c", BARE, str(port), BARE_KEY],
                                stdout=subprocess.PIPE, text=True)
        try:
            assert bare.stdout is not None and "bare up" in bare.stdout.readline()
            with client(port) as session:
                time.sleep(0.5)
                servo_key = keys.servo_common(OP.getState)
                rtt = {"servo": [], "bare": []}
                for i in range(args.n + 200):
                    for name, key in (("servo", servo_key), ("bare", BARE_KEY)):
                        t = time.perf_counter()
                        replies = list(session.get(key, payload=request, timeout=5))
                        dt = time.perf_counter() - t
                        reply = codec.decode_reply(op, replies[0].ok.payload.to_bytes())
                        assert reply.id == 0
                        if i >= 200:  # warm-up excluded
                            rtt[name].append(dt)
        finally:
            bare.kill()
    s, b = np.array(rtt["servo"]) * 1e6, np.array(rtt["bare"]) * 1e6
    print(f"query round trip over the launcher's router, n={args.n} each")
    print(f"Servo/Common/getState: p50 {np.percentile(s, 50):.0f} us, p99 {np.percentile(s, 99):.0f} us")
    print(f"bare Zenoh queryable:  p50 {np.percentile(b, 50):.0f} us, p99 {np.percentile(b, 99):.0f} us")
    print(f"ratio p50 {np.percentile(s, 50) / np.percentile(b, 50):.2f}x, "
          f"p99 {np.percentile(s, 99) / np.percentile(b, 99):.2f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
