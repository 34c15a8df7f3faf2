"""Zenoh settings on the command line, shared by every program of the project.

Multicast scouting is off unless ``--multicast`` is given: a controller talks
only to the endpoints it is told about.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Sequence

import zenoh

MODES = ("peer", "client", "router")


def add_zenoh_arguments(parser: argparse.ArgumentParser, *, default_mode: str = "peer") -> None:
    g = parser.add_argument_group("zenoh")
    g.add_argument("--mode", choices=MODES, default=default_mode,
                   help=f"Zenoh session mode (default: {default_mode})")
    g.add_argument("--listen", action="append", default=[], metavar="ENDPOINT",
                   help="endpoint to listen on, e.g. tcp/127.0.0.1:7447 (repeatable)")
    g.add_argument("--connect", action="append", default=[], metavar="ENDPOINT",
                   help="endpoint to connect to, e.g. tcp/127.0.0.1:7447 (repeatable)")
    g.add_argument("--config", metavar="ZENOH_CONFIG_FILE",
                   help="Zenoh configuration file (JSON5); the options above override it")
    g.add_argument("--multicast", action="store_true",
                   help="enable multicast scouting (off by default)")


def zenoh_config(mode: str = "peer", listen: Sequence[str] = (), connect: Sequence[str] = (),
                 config: str | None = None, multicast: bool = False) -> zenoh.Config:
    """A Zenoh configuration from the shared settings."""
    conf = zenoh.Config.from_file(config) if config else zenoh.Config()
    conf.insert_json5("mode", json.dumps(mode))
    if listen:
        conf.insert_json5("listen/endpoints", json.dumps(list(listen)))
    elif mode != "router":
        conf.insert_json5("listen/endpoints", "[]")  # peers would otherwise listen on every interface
    if connect:
        conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
    conf.insert_json5("scouting/multicast/enabled", json.dumps(bool(multicast)))
    return conf


def config_from_args(args: argparse.Namespace) -> zenoh.Config:
    return zenoh_config(args.mode, args.listen, args.connect, args.config, args.multicast)


def zenoh_argv(mode: str, listen: Sequence[str] = (), connect: Sequence[str] = (),
               config: str | None = None, multicast: bool = False) -> list[str]:
    """The command-line form of the settings, to pass them on to a child process."""
    argv = ["--mode", mode]
    for e in listen:
        argv += ["--listen", e]
    for e in connect:
        argv += ["--connect", e]
    if config:
        argv += ["--config", config]
    if multicast:
        argv.append("--multicast")
    return argv
