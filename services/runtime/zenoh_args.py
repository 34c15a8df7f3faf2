"""Zenoh settings on the command line, shared by every program of the project.

Multicast scouting is off unless ``--multicast`` is given: a controller talks
only to the endpoints it is told about. ``--secure DIR`` joins a secure cell
(``runtime/cell.py``): mutual TLS as identity ``--identity``, every endpoint
``tls/``, and the cell's roles enforced by Zenoh on every link the session
accepts or opens.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Sequence
from pathlib import Path

import zenoh

from .cell import Cell, CellError, check_endpoints

MODES = ("peer", "client", "router")
#: The port of the launcher's router (Zenoh's own default); ``tcp/`` for an open cell, ``tls/`` for a secure one.
DEFAULT_PORT = 7447
DEFAULT_HOST_PORT = f"127.0.0.1:{DEFAULT_PORT}"
#: How often a session retries an endpoint while it may keep trying (``join_within``) [ms]: a router that
#: comes up is joined within half a second.
JOIN_RETRY = {"period_init_ms": 100, "period_max_ms": 500, "period_increase_factor": 2}


def default_endpoint(secure: str | None) -> str:
    """The launcher's default endpoint on this host: TLS in a secure cell."""
    return f"{'tls' if secure else 'tcp'}/{DEFAULT_HOST_PORT}"


def add_zenoh_arguments(parser: argparse.ArgumentParser, *, default_mode: str = "peer",
                        default_identity: str | None = None, fixed_mode: bool = False,
                        default_connect: str | None = None) -> None:
    """The shared Zenoh options. ``fixed_mode``: ``--mode`` accepts ``default_mode`` only and is left out of
    the help (a router); ``default_connect``: what the help says is connected to without ``--connect``."""
    g = parser.add_argument_group("zenoh")
    g.add_argument("--mode", choices=[default_mode] if fixed_mode else MODES, default=default_mode,
                   help=argparse.SUPPRESS if fixed_mode else f"Zenoh session mode (default: {default_mode})")
    g.add_argument("--listen", action="append", default=[], metavar="ENDPOINT",
                   help="endpoint to listen on, e.g. tcp/127.0.0.1:7447 (repeatable)")
    g.add_argument("--connect", action="append", default=[], metavar="ENDPOINT",
                   help="endpoint to connect to, e.g. tcp/127.0.0.1:7447 (repeatable)"
                   + (f" (default: {default_connect})" if default_connect else ""))
    g.add_argument("--config", metavar="ZENOH_CONFIG_FILE",
                   help="Zenoh configuration file (JSON5); the options above override it")
    g.add_argument("--multicast", action="store_true",
                   help="enable multicast scouting (off by default)")
    g.add_argument("--secure", metavar="DIR",
                   help="join the secure cell of DIR (jara-arm certs init): mutual TLS with its certificates, "
                   "its roles enforced; every endpoint tls/HOST:PORT")
    g.add_argument("--identity", metavar="NAME", default=default_identity,
                   help="with --secure: the certificate to present (DIR/NAME.pem)"
                   + (f" (default: {default_identity})" if default_identity else " (required)"))


def zenoh_config(mode: str = "peer", listen: Sequence[str] = (), connect: Sequence[str] = (),
                 config: str | None = None, multicast: bool = False, secure: str | None = None,
                 identity: str | None = None, join_within: float | None = None) -> zenoh.Config:
    """A Zenoh configuration from the shared settings; CellError if ``secure`` cannot be had.

    ``join_within`` [s]: keep trying the ``connect`` endpoints this long before ``zenoh.open`` fails (a
    client command started just before the launcher's router listens); by default one try."""
    if secure:
        if not identity:
            raise CellError("--secure needs --identity NAME: the certificate to present "
                            f"(one of `jara-arm certs list {secure}`)")
        check_endpoints([*listen, *connect])
    conf = zenoh.Config.from_file(config) if config else zenoh.Config()
    conf.insert_json5("mode", json.dumps(mode))
    if listen:
        conf.insert_json5("listen/endpoints", json.dumps(list(listen)))
    elif mode != "router":
        conf.insert_json5("listen/endpoints", "[]")  # peers would otherwise listen on every interface
    if connect:
        conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
    if join_within is not None:
        conf.insert_json5("connect/timeout_ms", json.dumps(max(1, round(join_within * 1e3))))
        conf.insert_json5("connect/retry", json.dumps(JOIN_RETRY))
    conf.insert_json5("scouting/multicast/enabled", json.dumps(bool(multicast)))
    if secure:
        assert identity is not None
        Cell(Path(secure)).apply(conf, identity)
    return conf


def config_from_args(args: argparse.Namespace) -> zenoh.Config:
    return zenoh_config(args.mode, args.listen, args.connect, args.config, args.multicast,
                        args.secure, args.identity)
