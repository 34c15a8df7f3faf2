"""compose.yaml and the Dockerfile, checked without a Docker engine.

The services and commands they name must be the ones the launcher knows, and
each command (variables at their defaults) must be accepted by the parser of
the program that runs it.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import pytest
import yaml

from jara_arm.launcher import cli
from jara_arm.launcher.up.services import NAMES
from jara_arm.robots import ROBOTS
from jara_arm.schema.keys import check_arm

ROOT = Path(__file__).resolve().parent.parent
ROUTER = "router"  #: the cell bus
GATEWAY = "gateway"  #: the client gateway
_VARIABLE = re.compile(r"\$\{(\w+)(:?-)?([^}]*)\}")

pytestmark = pytest.mark.timeout(30)


def substitute_defaults(value: str) -> str:
    """``${VAR:-default}`` → ``default``, as compose does with VAR unset; every variable needs one."""
    def default(m: re.Match[str]) -> str:
        assert m[2], f"compose variable ${{{m[1]}}} has no default"
        return m[3]

    return _VARIABLE.sub(default, value).replace("$$", "$")


@pytest.fixture(scope="module")
def compose() -> dict[str, Any]:
    data = yaml.safe_load((ROOT / "compose.yaml").read_text())
    assert isinstance(data, dict) and isinstance(data.get("services"), dict)
    return data


def command(service: dict[str, Any]) -> list[str]:
    cmd = service["command"]
    assert isinstance(cmd, list), "commands are lists: no shell, no word splitting"
    return [substitute_defaults(str(word)) for word in cmd]


def test_every_service_is_in_the_launcher_table(compose: dict[str, Any]) -> None:
    names = set(compose["services"]) - {ROUTER, GATEWAY, "ros2"}  # ros2: a client (`up --ros2`), not a service
    assert names, "no service besides the routers"
    assert names <= set(NAMES), f"not in the launcher's service table: {names - set(NAMES)}"
    assert ROUTER in compose["services"] and GATEWAY in compose["services"]


def test_every_command_is_accepted_by_its_parser(compose: dict[str, Any]) -> None:
    for name, service in compose["services"].items():
        cmd = command(service)
        assert cmd[0] == "jara-arm", f"{name}: {cmd}"
        parser, argv = cli.command_parser(cmd[1:])
        args = parser.parse_args(argv)  # SystemExit(2) here names the offending option
        if name in (ROUTER, GATEWAY):
            assert cmd[1] == "router" and (args.bus if name == ROUTER else args.gateway), f"{name}: {cmd}"
            if name == GATEWAY:  # joins the bus by its compose name
                assert args.connect and all(f"/{ROUTER}:" in e for e in args.connect), args.connect
            continue
        if name == "ros2":  # a client of the gateway, as any ROS 2 tool
            assert cmd[1] == "ros2" and args.connect and all(f"/{GATEWAY}:" in e for e in args.connect), cmd
            continue
        assert cmd[1:3] == ["service", name], f"compose service {name} runs {cmd[1:3]}"
        check_arm(args.arm)
        assert args.robot in ROBOTS
        # A client of the bus, found by its compose name.
        assert args.mode == "client"
        assert args.connect and all(f"/{ROUTER}:" in e for e in args.connect), args.connect


def test_the_gateway_listens_on_the_published_port_and_the_bus_on_none(compose: dict[str, Any]) -> None:
    gateway = compose["services"][GATEWAY]
    parser, argv = cli.command_parser(command(gateway)[1:])
    assert parser.parse_args(argv).listen == ["tcp/0.0.0.0:7447"]
    published = [substitute_defaults(str(p)) for p in gateway["ports"]]
    assert any(p.endswith(":7447") for p in published), published
    assert "ports" not in compose["services"][ROUTER], "the bus must not be reachable by clients"
    for name in set(compose["services"]) - {ROUTER}:
        assert ROUTER in compose["services"][name]["depends_on"]


def test_servo_may_raise_its_priority(compose: dict[str, Any]) -> None:
    assert "SYS_NICE" in compose["services"]["servo"]["cap_add"]


def test_dockerfile_installs_the_package() -> None:
    text = (ROOT / "Dockerfile").read_text()
    assert re.search(r"^FROM python:3\.11-slim\b", text, re.M)
    assert re.search(r"pip wheel\b.*\s\.$", text, re.M), "builds the repository's package"
    assert re.search(r"pip install\b.*\sjara-arm$", text, re.M), "installs it"
    # The default command is a valid `jara-arm` command line too.
    [cmd] = re.findall(r"^CMD (\[.*\])$", text, re.M)
    words = json.loads(cmd)
    assert words[0] == "jara-arm"
    parser, argv = cli.command_parser(words[1:])
    parser.parse_args(argv)


def test_dockerignore_keeps_the_context_small() -> None:
    ignored = (ROOT / ".dockerignore").read_text().split()
    assert ".venv" in ignored and ".git" in ignored


def test_compose_runs_every_service_of_the_launcher(compose: dict[str, Any]) -> None:
    """The containers are the same deployment as `jara-arm up`: no service left out."""
    assert set(NAMES) <= set(compose["services"]), set(NAMES) - set(compose["services"])


@pytest.fixture(scope="module")
def secure_compose() -> dict[str, Any]:
    data = yaml.safe_load((ROOT / "compose.secure.yaml").read_text())
    assert isinstance(data, dict) and isinstance(data.get("services"), dict)
    return data


def test_the_secure_variant_covers_every_container(compose: dict[str, Any], secure_compose: dict[str, Any]) -> None:
    assert set(secure_compose["services"]) == set(compose["services"])


def test_the_secure_variant_runs_tls_only_with_its_secrets(secure_compose: dict[str, Any]) -> None:
    """Every command joins the cell mounted from secrets: TLS endpoints, and the files its identity needs."""
    from jara_arm.services.runtime.cell import Cell

    declared = secure_compose["secrets"]
    for name, service in secure_compose["services"].items():
        cmd = command(service)
        parser, argv = cli.command_parser(cmd[1:])
        args = parser.parse_args(argv)
        assert args.secure == "/run/secrets/cell", f"{name}: {cmd}"
        endpoints = [*args.listen, *args.connect]
        assert endpoints and all(e.startswith("tls/") for e in endpoints), f"{name}: {endpoints}"
        mounted = {Path("/run/secrets") / s["target"] for s in service["secrets"]}
        cell = Cell(Path(args.secure))
        needed = {cell.ca_certificate, cell.registry_file, cell.certificate(args.identity),
                  cell.private_key(args.identity)}
        assert needed <= mounted, f"{name} lacks {needed - mounted}"
        assert all(s["source"] in declared for s in service["secrets"])
