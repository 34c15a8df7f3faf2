"""``jara-arm certs``: a secure cell's certificate authority and the certificates it issues.

``jara-arm certs init DIR`` makes the cell directory (:class:`Cell`): a CA of its
own, an empty registry, and the two identities that ``jara-arm up --secure DIR``
needs (``router`` and ``service``); ``jara-arm certs issue DIR NAME --role ROLE``
adds a person or program to it, ``jara-arm certs list DIR`` shows who is in it.

Every identity gets an EC P-256 key, a certificate whose common name is its name
(the name Zenoh's access control knows it by), and ``NAME.json5``: a Zenoh
configuration with its TLS settings filled in, to which its user adds a connect
endpoint. The roles are not in the certificates: the registry (``cell.json``)
gives them, and the routers of the cell enforce them.

Everything is done with the ``cryptography`` package, in this process: no
``openssl`` command, no key on a command line.
"""

from __future__ import annotations

import argparse
import datetime as dt
import ipaddress
import json
import os
import re
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TextIO

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from jara_arm.schema.errors import JaraArmError
from jara_arm.schema.keys import DEFAULT_ARM, ArmKeys
from jara_arm.schema.operations import OP, Interface
from jara_arm.schema.roles import Role, RoleError
from jara_arm.services.runtime.arguments import positive_int
from jara_arm.services.runtime.cell import ROUTER_IDENTITY, SERVICE_IDENTITY, Cell, CellError, Identity, check_name
from jara_arm.services.runtime.zenoh_args import DEFAULT_PORT, default_endpoint

from ..command import USAGE_ERROR, Command

#: What a certificate is valid for unless told otherwise: this host, by name and by address.
DEFAULT_HOSTS = ("localhost", "127.0.0.1", "::1")
CA_DAYS = 3650  #: the CA's validity unless told otherwise [days]
ISSUE_DAYS = 365  #: an identity's validity unless told otherwise [days]
MAX_DAYS = 36500  #: a hundred years: beyond that a date is more likely a typing mistake
#: How far back a new certificate's validity starts: a host whose clock is a little behind still accepts it.
CLOCK_SKEW = dt.timedelta(minutes=5)
#: The identities that ``jara-arm up --secure DIR`` runs as: its router, and its services.
CELL_IDENTITIES = ((ROUTER_IDENTITY, Role.ROUTER), (SERVICE_IDENTITY, Role.SERVICE))
#: Names whose files would be the CA's (ca.pem, ca.key), on a file system that ignores case too.
_RESERVED = frozenset({"ca"})
_DNS_LABEL = re.compile(r"(?!-)[A-Za-z0-9-]{1,63}(?<!-)")


class CertsError(JaraArmError, ValueError):
    """A certificate that cannot be made or issued, and what to do about it."""


# -- checks ------------------------------------------------------------------------------------------

def check_days(days: int) -> int:
    """``days`` if it can be a validity [days], else CertsError saying what is allowed."""
    if isinstance(days, bool) or not isinstance(days, int) or not 1 <= days <= MAX_DAYS:
        raise CertsError(f"days {days!r} must be a whole number from 1 to {MAX_DAYS}")
    return days


def check_hosts(hosts: Sequence[str]) -> tuple[str, ...]:
    """``hosts`` as they go into a certificate (addresses in their canonical form, no repeats), else
    CertsError naming the one that is neither an IP address nor a DNS name."""
    if isinstance(hosts, str):  # a lone name would otherwise be taken letter by letter
        hosts = (hosts,)
    out: list[str] = []
    for host in hosts:
        text = host.strip() if isinstance(host, str) else ""
        try:
            out.append(str(ipaddress.ip_address(text)))
            continue
        except ValueError:
            pass
        name = text.lower()
        if not (0 < len(name) <= 253 and all(_DNS_LABEL.fullmatch(label) for label in name.split("."))):
            raise CertsError(f"host {host!r} is neither an IP address (e.g. 127.0.0.1, ::1) nor a DNS name "
                             "(letters, digits and '-' in dot-separated labels, e.g. arm-pc.local)")
        out.append(name)
    return tuple(dict.fromkeys(out))


def _check_identity_name(name: str) -> str:
    try:
        check_name(name)
    except CellError as exc:
        raise CertsError(str(exc)) from None
    if name.lower() in _RESERVED:
        raise CertsError(f"identity name {name!r} is taken by the cell's CA (ca.pem, ca.key); choose another")
    return name


def _role(role: Role | str) -> Role:
    try:
        return role if isinstance(role, Role) else Role.parse(role)
    except RoleError as exc:
        raise CertsError(str(exc)) from None


# -- files -------------------------------------------------------------------------------------------

def _write_private(path: Path, data: bytes) -> None:
    """Write a private key readable by its owner only: created with mode 0600 (never a moment wider,
    as a chmod after writing would leave), then renamed over ``path`` so an existing key of wider mode
    is replaced, not reused."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        tmp.replace(path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def _write_public(path: Path, text: str) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(text)
    tmp.replace(path)


def _key_pem(key: ec.EllipticCurvePrivateKey) -> bytes:
    # PKCS#8 without a passphrase: Zenoh (rustls) reads it, and the file's mode is its protection.
    return key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                             serialization.NoEncryption())


def _cert_pem(cert: x509.Certificate) -> str:
    return cert.public_bytes(serialization.Encoding.PEM).decode()


def _utc_text(when: dt.datetime) -> str:
    return when.astimezone(dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


def load_ca(cell: Cell) -> tuple[x509.Certificate, ec.EllipticCurvePrivateKey | None]:
    """The cell's CA certificate, and its key if this copy of the cell has it."""
    try:
        cert = x509.load_pem_x509_certificate(cell.ca_certificate.read_bytes())
    except FileNotFoundError:
        raise CertsError(f"{cell.root} is not a cell directory (no {cell.ca_certificate.name}; "
                         "make one with `jara-arm certs init DIR`)") from None
    except (OSError, ValueError) as exc:
        raise CertsError(f"{cell.ca_certificate}: unreadable CA certificate ({exc})") from None
    try:
        key = serialization.load_pem_private_key(cell.ca_key.read_bytes(), password=None)
    except FileNotFoundError:
        return cert, None
    except (OSError, ValueError, TypeError) as exc:
        raise CertsError(f"{cell.ca_key}: unreadable CA key ({exc})") from None
    if not isinstance(key, ec.EllipticCurvePrivateKey) or key.public_key() != cert.public_key():
        raise CertsError(f"{cell.ca_key} is not the key of {cell.ca_certificate}; "
                         "copy the CA's own ca.key next to its ca.pem")
    return cert, key


# -- the cell ----------------------------------------------------------------------------------------

def init_cell(root: Path, *, days: int = CA_DAYS, hosts: Sequence[str] = DEFAULT_HOSTS) -> Cell:
    """Make the cell directory ``root``: its CA (valid ``days``), an empty registry, and the identities
    ``router`` and ``service`` (valid on ``hosts``, for ``days`` or a year, whichever is shorter).

    CertsError if ``root`` already holds a CA: a second one would orphan every certificate of the first.
    """
    check_days(days)
    hosts = check_hosts(hosts)
    root = Path(root)
    cell = Cell(root)
    if cell.ca_certificate.exists():
        raise CertsError(f"{root} already holds a cell ({cell.ca_certificate.name}); add to it with "
                         f"`jara-arm certs issue {root} NAME --role ROLE`, or choose another directory")
    try:
        root.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise CertsError(f"cannot make the cell directory {root}: {exc.strerror or exc}") from None
    key = ec.generate_private_key(ec.SECP256R1())
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, f"jara-arm cell CA ({root.resolve().name})")])
    now = dt.datetime.now(dt.UTC)
    cert = (x509.CertificateBuilder()
            .subject_name(name).issuer_name(name)
            .public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - CLOCK_SKEW)
            .not_valid_after(now + dt.timedelta(days=days))
            # path_length 0: it signs the cell's identities only, never another CA.
            .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
            .add_extension(x509.KeyUsage(digital_signature=False, content_commitment=False, key_encipherment=False,
                                         data_encipherment=False, key_agreement=False, key_cert_sign=True,
                                         crl_sign=True, encipher_only=False, decipher_only=False), critical=True)
            .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), critical=False)
            .sign(key, hashes.SHA256()))
    _write_private(cell.ca_key, _key_pem(key))  # the key first: a ca.pem without it could issue nothing
    _write_public(cell.ca_certificate, _cert_pem(cert))
    cell.write_identities({})
    for identity, role in CELL_IDENTITIES:
        issue(cell, identity, role, hosts=hosts, days=min(days, ISSUE_DAYS))
    return cell


def issue(cell: Cell, name: str, role: Role | str, *, hosts: Sequence[str] = DEFAULT_HOSTS,
          days: int = ISSUE_DAYS, not_before: dt.datetime | None = None, force: bool = False) -> Identity:
    """Issue identity ``name`` with ``role`` in ``cell``: its key, its certificate (common name
    ``name``, valid on ``hosts`` from ``not_before``, by default a few minutes ago, for ``days``), its
    Zenoh configuration, and its registry entry, which it returns.

    CertsError for a bad name, role, host or number of days, a name already issued (unless ``force``,
    which replaces it: new key, new serial), or a copy of the cell without the CA's key.
    """
    name = _check_identity_name(name)
    role = _role(role)
    check_days(days)
    hosts = check_hosts(hosts)
    ca_cert, ca_key = load_ca(cell)
    if ca_key is None:
        raise CertsError(f"this copy of the cell has no CA key ({cell.ca_key}); issue certificates where "
                         "ca.key is, then copy the new NAME.pem, NAME.key and NAME.json5 to NAME's host")
    identities = cell.identities()
    if not force:
        if name in identities:
            old = identities[name]
            raise CertsError(f"identity {name!r} is already issued (role {old.role.value}, expires "
                             f"{old.not_after}); give --force to replace it with a new key and certificate")
        present = [str(p) for p in (cell.certificate(name), cell.private_key(name)) if p.exists()]
        if present:
            raise CertsError(f"identity {name!r} is not in the registry but {', '.join(present)} exist; "
                             "give --force to replace them")
    start = (not_before if not_before is not None else dt.datetime.now(dt.UTC) - CLOCK_SKEW)
    if start.tzinfo is None:
        raise CertsError(f"not_before {start.isoformat()} must say its time zone (e.g. datetime.UTC)")
    end = start + dt.timedelta(days=days)
    if end > ca_cert.not_valid_after_utc:
        most = max((ca_cert.not_valid_after_utc - start).days, 0)
        raise CertsError(f"a certificate for {days} days would outlive the cell's CA, which expires "
                         f"{_utc_text(ca_cert.not_valid_after_utc)}; ask for at most {most} days")
    key = ec.generate_private_key(ec.SECP256R1())
    ca_public = ca_key.public_key()
    builder = (x509.CertificateBuilder()
               .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name)]))
               .issuer_name(ca_cert.subject)
               .public_key(key.public_key())
               .serial_number(x509.random_serial_number())
               .not_valid_before(start)
               .not_valid_after(end)
               .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
               # key_agreement: TLS's ECDH with an EC key; digital_signature: the handshake's signature.
               .add_extension(x509.KeyUsage(digital_signature=True, content_commitment=False, key_encipherment=False,
                                            data_encipherment=False, key_agreement=True, key_cert_sign=False,
                                            crl_sign=False, encipher_only=False, decipher_only=False),
                              critical=True)
               # Both: every identity is a client of a router, and a router or a peer also serves.
               .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH,
                                                     ExtendedKeyUsageOID.CLIENT_AUTH]), critical=False)
               .add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_public), critical=False)
               .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), critical=False))
    if hosts:  # an empty SubjectAlternativeName is not allowed; without hosts, the name cannot serve TLS
        builder = builder.add_extension(x509.SubjectAlternativeName(
            [x509.IPAddress(ipaddress.ip_address(h)) if _is_ip(h) else x509.DNSName(h) for h in hosts]),
            critical=False)
    cert = builder.sign(ca_key, hashes.SHA256())
    _write_private(cell.private_key(name), _key_pem(key))
    _write_public(cell.certificate(name), _cert_pem(cert))
    _write_public(cell.zenoh_file(name), zenoh_file_text(cell, name, role))
    identity = Identity(name, role, f"{cert.serial_number:x}", _utc_text(cert.not_valid_after_utc), hosts)
    cell.write_identities({**identities, name: identity})
    return identity


def _is_ip(host: str) -> bool:
    try:
        ipaddress.ip_address(host)
        return True
    except ValueError:
        return False


def list_identities(cell: Cell) -> list[Identity]:
    """Every identity of the cell's registry, by name."""
    return sorted(cell.identities().values(), key=lambda i: i.name)


def expired(identity: Identity, now: dt.datetime | None = None) -> bool:
    """Whether ``identity``'s certificate is past its expiry (by the registry)."""
    return dt.datetime.fromisoformat(identity.not_after) <= (now or dt.datetime.now(dt.UTC))


# -- NAME.json5 --------------------------------------------------------------------------------------

def zenoh_settings(cell: Cell, name: str, role: Role) -> dict[str, object]:
    """The Zenoh configuration of identity ``name``: mutual TLS with the cell's files (absolute paths),
    no multicast scouting, no endpoint to connect to yet (its user adds the router's)."""
    settings: dict[str, object] = {
        "mode": "router" if role is Role.ROUTER else "client",
        "connect": {"endpoints": []},
        "scouting": {"multicast": {"enabled": False}},
        "transport": {"link": {"tls": cell.tls(name)}},
    }
    if role is Role.ROUTER:  # a router without listen endpoints would listen on plain TCP, every interface
        settings["listen"] = {"endpoints": [default_endpoint(secure=str(cell.root))]}
    return settings


def zenoh_file_text(cell: Cell, name: str, role: Role) -> str:
    """``NAME.json5``: :func:`zenoh_settings` under a comment saying whose it is and how to use it."""
    root = cell.root.resolve()
    key = ArmKeys(DEFAULT_ARM).interface(Interface.COMMON, OP.getState)
    local = default_endpoint(secure=str(root))
    if role is Role.ROUTER:
        use = [
            f"A Zenoh router: it listens on {local}; change listen/endpoints to serve",
            "other hosts (an address or name of the certificate's hosts).",
            f"The cell's own router is `jara-arm router --secure {root}` (or `jara-arm up --secure {root}`),",
            "which enforces the roles of cell.json; this file alone does not.",
        ]
    else:
        use = [
            f"A Zenoh client: add the endpoint of a router of the cell, e.g. tls/HOST:{DEFAULT_PORT}, where HOST",
            "is one of the router certificate's hosts (jara-arm certs list), then:",
            f"    z_get --config {name}.json5 -e {local} -s {key}",
            "or, in Python:",
            f"    conf = zenoh.Config.from_file({str(cell.zenoh_file(name).resolve())!r})",
            f"    conf.insert_json5(\"connect/endpoints\", '[\"{local}\"]')",
            "    session = zenoh.open(conf)",
        ]
    header = [
        f"Zenoh configuration of identity {name!r}, role {role.value}, of the jara-arm cell {root}",
        f"(written by `jara-arm certs issue`; issuing {name} again rewrites it).",
        "",
        *use,
        "",
        "It holds no access_control: the routers of the cell (jara-arm router/up --secure) enforce",
        f"what role {role.value} may do. {name}.key is the private key: it stays on {name}'s host.",
    ]
    comment = "\n".join(f"// {line}".rstrip() for line in header)
    return f"{comment}\n{json.dumps(zenoh_settings(cell, name, role), indent=2)}\n"


# -- for the command line ----------------------------------------------------------------------------

def files_of(cell: Cell, name: str) -> tuple[Path, ...]:
    """The files of identity ``name``: certificate, private key, Zenoh configuration."""
    return cell.certificate(name), cell.private_key(name), cell.zenoh_file(name)


def table(identities: Sequence[Identity], now: dt.datetime | None = None) -> list[str]:
    """The lines of ``jara-arm certs list``: a header, then one line per identity: name, role, expiry
    (with EXPIRED once past), hosts."""
    rows = [("NAME", "ROLE", "EXPIRES", "HOSTS")] + [
        (i.name, i.role.value, i.not_after + ("  EXPIRED" if expired(i, now) else ""), ", ".join(i.hosts) or "-")
        for i in identities]
    widths = [max(len(row[c]) for row in rows) for c in range(3)]
    return [f"{r[0]:<{widths[0]}}  {r[1]:<{widths[1]}}  {r[2]:<{widths[2]}}  {r[3]}" for r in rows]


# -- what ``jara-arm certs`` prints ----------------------------------------------------------------------


def report_init(root: Path, out: TextIO, *, days: int = CA_DAYS, hosts: Sequence[str] = DEFAULT_HOSTS) -> Cell:
    """``certs init``: :func:`init_cell`, then what was made and what to do next, on ``out``."""
    cell = init_cell(root, days=days, hosts=hosts)
    ca_cert, _ = load_ca(cell)
    print(f"made the cell {cell.root.resolve()}:", file=out)
    print(f"  {cell.ca_certificate.resolve()}  the CA's certificate, expires "
          f"{ca_cert.not_valid_after_utc:%Y-%m-%dT%H:%M:%SZ}: every host of the cell needs it", file=out)
    print(f"  {cell.ca_key.resolve()}  the CA's private key: issue certificates here, copy it nowhere", file=out)
    print(f"  {cell.registry_file.resolve()}  the registry (name -> role): every router of the cell needs it",
          file=out)
    print("identities:", file=out)
    for line in table(list_identities(cell)):
        print(f"  {line}", file=out)
    print("  with, for each NAME: NAME.pem (certificate), NAME.key (private key, mode 0600), NAME.json5 "
          "(Zenoh configuration)", file=out)
    print(f"next: `jara-arm certs issue {root} NAME --role operator` for each person or program, "
          f"then `jara-arm up --secure {root}`", file=out)
    return cell


def report_issue(root: Path, name: str, role: Role, out: TextIO, *, hosts: Sequence[str] = DEFAULT_HOSTS,
                 days: int = ISSUE_DAYS, force: bool = False) -> Identity:
    """``certs issue``: :func:`issue` in the cell at ``root``, then its three files and what each is for."""
    cell = Cell(root)
    identity = issue(cell, name, role, hosts=hosts, days=days, force=force)
    cert, key, conf = (f.resolve() for f in files_of(cell, identity.name))
    print(f"issued {identity.name!r}, role {identity.role.value}, serial {identity.serial}, expires "
          f"{identity.not_after}, hosts {', '.join(identity.hosts) or '-'}:", file=out)
    print(f"  {cert}  its certificate", file=out)
    print(f"  {key}  its private key (mode 0600): copy it to {identity.name}'s host only", file=out)
    what = ("listens on tls/127.0.0.1:" if identity.role is Role.ROUTER
            else "add a router's endpoint to connect/endpoints, e.g. tls/HOST:")
    print(f"  {conf}  its Zenoh configuration: {what}{DEFAULT_PORT}", file=out)
    return identity


def report_list(root: Path, out: TextIO) -> None:
    """``certs list``: the identities of the cell at ``root`` as a table."""
    cell = Cell(root)
    identities = list_identities(cell)
    if not identities:
        print(f"no identities in {cell.root} (issue one with `jara-arm certs issue {root} NAME --role ROLE`)",
              file=out)
    else:
        print("\n".join(table(identities)), file=out)


def _hosts(parser: argparse.ArgumentParser, what: str) -> None:
    parser.add_argument("--host", action="append", default=[], metavar="H",
                        help=f"a DNS name or IP address the {what} may serve TLS on (repeatable; "
                        f"default: {', '.join(DEFAULT_HOSTS)})")


def _arguments(parser: argparse.ArgumentParser) -> None:
    """The actions, each with the report that runs it (``report``)."""
    actions = parser.add_subparsers(dest="certs_command", required=True, metavar="ACTION")
    making = actions.add_parser(
        "init", help="make a cell: its CA, and the identities router and service",
        description="Make the cell directory DIR (and its parents): a new certificate authority, an empty "
        "registry, and the identities that `jara-arm up --secure DIR` runs as: router (role router) and "
        "service (role service). Refuses a directory that already holds a CA.")
    making.add_argument("dir", type=Path, metavar="DIR", help="the cell directory to make")
    making.add_argument("--days", type=positive_int, default=CA_DAYS, metavar="N",
                        help=f"the CA's validity [days] (default: {CA_DAYS}); router's and "
                        f"service's: the same, or {ISSUE_DAYS} if shorter")
    _hosts(making, "router's and service's certificates")
    making.set_defaults(report=lambda args: report_init(args.dir, sys.stdout, days=args.days,
                                                        hosts=args.host or DEFAULT_HOSTS))
    issuing = actions.add_parser(
        "issue", help="issue an identity: its key, certificate and Zenoh configuration",
        description="Issue identity NAME with ROLE in the cell DIR (where its ca.key is): NAME.key, NAME.pem, "
        "NAME.json5, and its entry in the registry. Copy the three files to NAME's host, and cell.json "
        "to every router of the cell.")
    issuing.add_argument("dir", type=Path, metavar="DIR", help="the cell directory")
    issuing.add_argument("name", metavar="NAME",
                         help="the identity's name (its certificate's common name): 1-64 of [A-Za-z0-9_.-]")
    issuing.add_argument("--role", required=True, choices=[r.value for r in Role], metavar="ROLE",
                         help=f"what NAME may do: {', '.join(r.value for r in Role)}")
    _hosts(issuing, "certificate")
    issuing.add_argument("--days", type=positive_int, default=ISSUE_DAYS, metavar="N",
                         help=f"the certificate's validity [days] (default: {ISSUE_DAYS})")
    issuing.add_argument("--force", action="store_true",
                         help="replace an identity already issued (new key, new serial)")
    issuing.set_defaults(report=lambda args: report_issue(args.dir, args.name, Role(args.role), sys.stdout,
                                                          hosts=args.host or DEFAULT_HOSTS, days=args.days,
                                                          force=args.force))
    listing = actions.add_parser(
        "list", help="the identities of a cell: name, role, expiry, hosts",
        description="One line per identity of the cell's registry: name, role, expiry (EXPIRED once "
        "past), hosts.")
    listing.add_argument("dir", type=Path, metavar="DIR", help="the cell directory")
    listing.set_defaults(report=lambda args: report_list(args.dir, sys.stdout))


def _run(args: argparse.Namespace, parser: argparse.ArgumentParser) -> int:
    """What was made or found on stdout; a mistake (exit 2) on stderr."""
    try:
        args.report(args)
        return 0
    except (CertsError, CellError) as exc:
        print(f"{parser.prog}: {exc}", file=sys.stderr)
        return USAGE_ERROR


COMMAND = Command(
    "certs", arguments=_arguments, run=_run,
    help="make a secure cell's certificate authority and issue its certificates",
    description="A secure cell (--secure DIR) is a directory: its own certificate authority (ca.pem, "
    "ca.key), a registry of identities and their roles (cell.json), and for each identity NAME a "
    "certificate (common name NAME), a private key and a Zenoh configuration (NAME.pem, NAME.key, "
    "NAME.json5). Roles: " + ", ".join(r.value for r in Role) + ".")
