"""A secure cell's directory: its certificate authority, its identities and their roles.

``jara-arm certs init DIR`` makes it and ``jara-arm certs issue DIR NAME --role
ROLE`` adds to it (``launcher/secure/certs.py``); every program given ``--secure DIR``
reads it here and joins the network over mutual TLS as identity ``NAME``
(:meth:`Cell.apply`). Every router and peer also enforces the roles of the
registry with Zenoh's access control (:func:`jara_arm.schema.roles.access_control`).

Layout (docs/secure_cell.md)::

    DIR/ca.pem          the cell's CA certificate (public: every host has it)
    DIR/ca.key          the CA's private key (only where certificates are issued)
    DIR/cell.json       the registry: name -> role, serial, expiry (public: every router has it)
    DIR/NAME.pem        NAME's certificate (common name NAME), signed by the CA
    DIR/NAME.key        NAME's private key (only on NAME's host)
    DIR/NAME.json5      a Zenoh configuration for NAME with the TLS settings filled in
"""

from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path
from typing import Any

import zenoh

from jara_arm.schema.errors import JaraArmError
from jara_arm.schema.roles import Role, RoleError, access_control

#: An identity's name: its certificate's common name and its files' stem.
NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")
REGISTRY_FORMAT = 1
#: The identities ``jara-arm certs init`` issues and ``jara-arm up --secure`` runs as: its router, and
#: every process it starts.
ROUTER_IDENTITY = "router"
SERVICE_IDENTITY = "service"


class CellError(JaraArmError, ValueError):
    """A cell directory, identity or endpoint that cannot be used, and why."""


def check_name(name: str) -> str:
    """``name`` if it can name an identity, else CellError saying what is allowed."""
    if not isinstance(name, str) or not NAME.fullmatch(name):
        raise CellError(f"identity name {name!r} must be 1-64 characters of [A-Za-z0-9_.-], "
                        "starting with a letter or digit")
    return name


@dataclasses.dataclass(frozen=True)
class Identity:
    """One registry entry: who holds certificate ``name`` and what it may do."""

    name: str
    role: Role
    serial: str  #: the certificate's serial number, hex
    not_after: str  #: the certificate's expiry, ISO 8601 UTC
    hosts: tuple[str, ...] = ()  #: the DNS names and addresses it may serve TLS on


@dataclasses.dataclass(frozen=True)
class Cell:
    """The files of one cell directory."""

    root: Path

    @property
    def ca_certificate(self) -> Path:
        return self.root / "ca.pem"

    @property
    def ca_key(self) -> Path:
        return self.root / "ca.key"

    @property
    def registry_file(self) -> Path:
        return self.root / "cell.json"

    def certificate(self, name: str) -> Path:
        return self.root / f"{check_name(name)}.pem"

    def private_key(self, name: str) -> Path:
        return self.root / f"{check_name(name)}.key"

    def zenoh_file(self, name: str) -> Path:
        return self.root / f"{check_name(name)}.json5"

    # -- the registry -------------------------------------------------------------------
    def identities(self) -> dict[str, Identity]:
        """The registry: every identity issued in this cell, by name."""
        try:
            data = json.loads(self.registry_file.read_text())
            entries = data["identities"]
            return {name: Identity(name, Role.parse(e["role"]), str(e["serial"]), str(e["not_after"]),
                                   tuple(e.get("hosts", ())))
                    for name, e in entries.items()}
        except FileNotFoundError:
            raise CellError(f"{self.root} is not a cell directory (no {self.registry_file.name}; "
                            "make one with `jara-arm certs init DIR`)") from None
        except (OSError, ValueError, KeyError, TypeError, AttributeError, RoleError) as exc:
            raise CellError(f"{self.registry_file}: unreadable registry ({exc})") from None

    def write_identities(self, identities: dict[str, Identity]) -> None:
        """Replace the registry (written whole, then renamed: a reader never sees half of it)."""
        data = {"format": REGISTRY_FORMAT, "identities": {
            i.name: {"role": i.role.value, "serial": i.serial, "not_after": i.not_after, "hosts": list(i.hosts)}
            for i in sorted(identities.values(), key=lambda i: i.name)}}
        tmp = self.registry_file.with_suffix(".json.tmp")
        tmp.write_text(json.dumps(data, indent=2) + "\n")
        tmp.replace(self.registry_file)

    def roles(self) -> dict[str, Role]:
        return {name: i.role for name, i in self.identities().items()}

    # -- joining the network -------------------------------------------------------------
    def tls(self, name: str) -> dict[str, Any]:
        """Zenoh's ``transport/link/tls`` settings for identity ``name``: its key and certificate on
        both sides of every link, the cell's CA as the only root, the peer's certificate required."""
        files = (self.ca_certificate, self.private_key(name), self.certificate(name))
        missing = [str(f) for f in files if not f.is_file()]
        if missing:
            raise CellError(f"identity {name!r} of cell {self.root}: missing {', '.join(missing)} "
                            f"(issue it with `jara-arm certs issue {self.root} {name} --role ROLE`)")
        key, cert = str(self.private_key(name).resolve()), str(self.certificate(name).resolve())
        return {"root_ca_certificate": str(self.ca_certificate.resolve()),
                "listen_private_key": key, "listen_certificate": cert,
                "connect_private_key": key, "connect_certificate": cert,
                "enable_mtls": True, "verify_name_on_connect": True}

    def apply(self, conf: zenoh.Config, name: str) -> None:
        """Make ``conf`` join the cell as ``name``: mutual TLS, and the cell's roles enforced on
        every link this session accepts or opens (a router's clients, a peer's peers)."""
        roles = self.roles()
        if name not in roles:
            raise CellError(f"identity {name!r} is not in the registry of cell {self.root} "
                            f"(identities: {', '.join(sorted(roles)) or 'none'})")
        conf.insert_json5("transport/link/tls", json.dumps(self.tls(name)))
        conf.insert_json5("access_control", json.dumps(access_control(roles)))


def check_endpoints(endpoints: list[str] | tuple[str, ...]) -> None:
    """With ``--secure`` every endpoint must be TLS: a plain one would be a door left open. A Unix socket
    (the cell bus's, ``unixsock-stream/PATH``) is a door of this host only, which its directory's
    permissions keep to the cell's own OS user; it has the router role (schema/roles.py)."""
    plain = [e for e in endpoints if not e.startswith(("tls/", "unixsock-stream/"))]
    if plain:
        raise CellError(f"--secure: every endpoint must be tls/HOST:PORT (or the cell bus's "
                        f"unixsock-stream/PATH), not {', '.join(plain)}")
