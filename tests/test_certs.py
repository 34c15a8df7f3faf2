"""``jara-arm certs``: a secure cell's CA, its certificates, their Zenoh files (``launcher/secure/certs.py``).

Real files in ``tmp_path``, read back with ``cryptography``; and the proof that
they work: a router of the cell (``Cell.apply``) on a loopback TLS port of its
own serves a ``service`` to an ``operator`` that joins with nothing but its
``NAME.json5`` and an endpoint, and turns away a certificate of another cell and
an expired one. No system is started; the module takes a few seconds.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import ipaddress
import json
import shutil
import stat
from collections.abc import Iterator
from pathlib import Path

import pytest
import zenoh
from cryptography import x509
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from jara_arm.launcher import cli
from jara_arm.launcher.secure.certs import DEFAULT_HOSTS, CertsError, init_cell, issue, list_identities, table
from jara_arm.schema.keys import ArmKeys
from jara_arm.schema.operations import Interface
from jara_arm.schema.roles import Role
from jara_arm.services.runtime.cell import Cell
from jara_arm.services.runtime.zenoh_args import zenoh_config

from .support import bash_complete, free_port

ROLES = "roles: service, router, operator, low-level, observer"


def certificate(path: Path) -> x509.Certificate:
    return x509.load_pem_x509_certificate(path.read_bytes())


def mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


def common_name(cert: x509.Certificate) -> str:
    return str(cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value)


def extension(cert: x509.Certificate, kind: type) -> x509.Extension:  # type: ignore[type-arg]
    return cert.extensions.get_extension_for_class(kind)


def expired_identity(cell: Cell, name: str) -> None:
    """``name`` issued three days ago for one day."""
    issue(cell, name, Role.OPERATOR, days=1, not_before=dt.datetime.now(dt.UTC) - dt.timedelta(days=3))


# -- the files ---------------------------------------------------------------------------------------

def test_init_makes_a_ca_a_registry_and_the_identities_of_up(tmp_path: Path) -> None:
    root = tmp_path / "site" / "cell"  # parents made too
    cell = init_cell(root)
    assert cell.root == root and mode(cell.ca_key) == 0o600
    assert {i.name: i.role for i in list_identities(cell)} == {"router": Role.ROUTER, "service": Role.SERVICE}

    ca = certificate(cell.ca_certificate)
    assert common_name(ca) == "jara-arm cell CA (cell)" and ca.issuer == ca.subject
    ca.verify_directly_issued_by(ca)
    assert isinstance(ca.public_key(), ec.EllipticCurvePublicKey) and ca.public_key().curve.name == "secp256r1"
    constraints = extension(ca, x509.BasicConstraints)
    assert constraints.critical and constraints.value.ca and constraints.value.path_length == 0
    usage = extension(ca, x509.KeyUsage)
    assert usage.critical and usage.value.key_cert_sign and usage.value.crl_sign
    assert not usage.value.digital_signature
    ca_key_id = extension(ca, x509.SubjectKeyIdentifier).value.digest

    for identity in list_identities(cell):
        cert = certificate(cell.certificate(identity.name))
        cert.verify_directly_issued_by(ca)
        assert common_name(cert) == identity.name and mode(cell.private_key(identity.name)) == 0o600
        assert identity.hosts == DEFAULT_HOSTS and identity.serial == f"{cert.serial_number:x}"
        assert identity.not_after == cert.not_valid_after_utc.strftime("%Y-%m-%dT%H:%M:%SZ")
        assert cert.not_valid_after_utc <= ca.not_valid_after_utc
        assert extension(cert, x509.BasicConstraints).critical and not extension(cert, x509.BasicConstraints).value.ca
        usage = extension(cert, x509.KeyUsage)
        assert usage.critical and usage.value.digital_signature and usage.value.key_agreement
        assert not usage.value.key_cert_sign
        assert set(extension(cert, x509.ExtendedKeyUsage).value) == {ExtendedKeyUsageOID.SERVER_AUTH,
                                                                     ExtendedKeyUsageOID.CLIENT_AUTH}
        names = extension(cert, x509.SubjectAlternativeName).value
        assert names.get_values_for_type(x509.DNSName) == ["localhost"]
        assert names.get_values_for_type(x509.IPAddress) == [ipaddress.ip_address("127.0.0.1"),
                                                             ipaddress.ip_address("::1")]
        assert extension(cert, x509.AuthorityKeyIdentifier).value.key_identifier == ca_key_id
        assert extension(cert, x509.SubjectKeyIdentifier).value.digest != ca_key_id

    with pytest.raises(CertsError, match=r"already holds a cell \(ca.pem\); add to it with `jara-arm certs issue"):
        init_cell(root)  # a second CA would orphan every certificate of the first


def test_issue_refuses_a_name_twice_unless_forced(tmp_path: Path) -> None:
    cell = init_cell(tmp_path / "cell")
    first = issue(cell, "alice", Role.OPERATOR, hosts=["arm-pc.local", "10.0.0.5", "10.0.0.5"])
    assert first.hosts == ("arm-pc.local", "10.0.0.5")
    names = extension(certificate(cell.certificate("alice")), x509.SubjectAlternativeName).value
    assert names.get_values_for_type(x509.DNSName) == ["arm-pc.local"]
    assert names.get_values_for_type(x509.IPAddress) == [ipaddress.ip_address("10.0.0.5")]
    with pytest.raises(CertsError, match=rf"'alice' is already issued \(role operator, expires {first.not_after}\); "
                       "give --force"):
        issue(cell, "alice", Role.OBSERVER)
    assert cell.identities()["alice"] == first

    cell.private_key("alice").chmod(0o644)  # a key left readable: replaced by a new file, not rewritten in place
    second = issue(cell, "alice", Role.OBSERVER, force=True)
    assert second.serial != first.serial and second.role is Role.OBSERVER and second.hosts == DEFAULT_HOSTS
    assert cell.identities()["alice"] == second and mode(cell.private_key("alice")) == 0o600
    assert f"{certificate(cell.certificate('alice')).serial_number:x}" == second.serial
    assert [i.name for i in list_identities(cell)] == ["alice", "router", "service"]


@pytest.mark.parametrize("name, role, kwargs, message", [
    ("b b", Role.OPERATOR, {}, r"identity name 'b b' must be 1-64 characters of \[A-Za-z0-9_.-\]"),
    ("CA", Role.OPERATOR, {}, "taken by the cell's CA"),
    ("bob", "boss", {}, f"unknown role 'boss'; {ROLES}"),
    ("bob", Role.OPERATOR, {"hosts": ["bad_host!"]}, "host 'bad_host!' is neither an IP address"),
    ("bob", Role.OPERATOR, {"hosts": ["10.0.0.5:7447"]}, "host '10.0.0.5:7447' is neither"),
    ("bob", Role.OPERATOR, {"days": 0}, "days 0 must be a whole number from 1 to 36500"),
    ("bob", Role.OPERATOR, {"days": 4000}, r"would outlive the cell's CA, which expires .*; ask for at most 3650 days"),
])
def test_issue_refuses_bad_input_saying_what_is_allowed(tmp_path: Path, name: str, role: Role | str,
                                                        kwargs: dict, message: str) -> None:
    cell = init_cell(tmp_path / "cell")
    before = sorted(p.name for p in cell.root.iterdir())
    with pytest.raises(CertsError, match=message):
        issue(cell, name, role, **kwargs)
    assert sorted(p.name for p in cell.root.iterdir()) == before  # nothing written
    assert sorted(cell.identities()) == ["router", "service"]


def test_issue_needs_the_ca_key_and_a_cell(tmp_path: Path) -> None:
    cell = init_cell(tmp_path / "cell")
    copy = Cell(tmp_path / "copy")  # a router's copy: the CA's certificate and the registry only
    copy.root.mkdir()
    for file in (cell.ca_certificate, cell.registry_file):
        shutil.copy(file, copy.root)
    with pytest.raises(CertsError, match="this copy of the cell has no CA key .*; issue certificates where ca.key is"):
        issue(copy, "alice", Role.OPERATOR)
    with pytest.raises(CertsError, match=r"is not a cell directory \(no ca.pem; make one with `jara-arm certs init"):
        issue(Cell(tmp_path / "nowhere"), "alice", Role.OPERATOR)


def test_each_zenoh_file_loads_as_it_is(tmp_path: Path) -> None:
    cell = init_cell(tmp_path / "cell")
    issue(cell, "alice", Role.LOW_LEVEL)
    for name, role in (("router", Role.ROUTER), ("service", Role.SERVICE), ("alice", Role.LOW_LEVEL)):
        conf = zenoh.Config.from_file(str(cell.zenoh_file(name)))
        tls = json.loads(conf.get_json("transport/link/tls"))
        assert json.loads(conf.get_json("mode")) == ("router" if role is Role.ROUTER else "client")
        assert json.loads(conf.get_json("connect/endpoints")) == []
        assert json.loads(conf.get_json("scouting/multicast/enabled")) is False
        assert tls["enable_mtls"] is True and tls["root_ca_certificate"] == str(cell.ca_certificate.resolve())
        assert tls["connect_certificate"] == str(cell.certificate(name).resolve())
        assert tls["connect_private_key"] == str(cell.private_key(name).resolve())
        text = cell.zenoh_file(name).read_text()
        assert text.startswith(f"// Zenoh configuration of identity '{name}', role {role.value}")
        assert "no access_control" in text and "access_control\":" not in text
    router = zenoh.Config.from_file(str(cell.zenoh_file("router")))
    assert all(e.startswith("tls/") for e in json.loads(router.get_json("listen/endpoints")))  # never plain TCP
    assert "z_get --config alice.json5 -e tls/127.0.0.1:7447" in cell.zenoh_file("alice").read_text()


# -- the proof: a router of the cell --------------------------------------------------------------------

def joined(cell: Cell, name: str, endpoint: str) -> zenoh.Config:
    """What a user does with NAME.json5: load it, add the router's endpoint."""
    conf = zenoh.Config.from_file(str(cell.zenoh_file(name)))
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    return conf


@contextlib.contextmanager
def opened(conf: zenoh.Config) -> Iterator[zenoh.Session]:
    session = zenoh.open(conf)
    try:
        yield session
    finally:
        session.close()


def test_a_router_of_the_cell_serves_its_identities_and_turns_away_others(tmp_path: Path) -> None:
    cell = init_cell(tmp_path / "cell")
    issue(cell, "alice", Role.OPERATOR)
    expired_identity(cell, "old")
    other = init_cell(tmp_path / "other")
    issue(other, "mallory", Role.OPERATOR)
    endpoint = f"tls/127.0.0.1:{free_port()}"
    key = ArmKeys("arm0").interface(Interface.COMMON, "getState")

    router_conf = zenoh_config("router", [endpoint])
    cell.apply(router_conf, "router")
    service_conf = zenoh_config("client", connect=[endpoint])
    cell.apply(service_conf, "service")
    with opened(router_conf), opened(service_conf) as service, opened(joined(cell, "alice", endpoint)) as alice:
        queryable = service.declare_queryable(key, lambda query: query.reply(key, b'{"id": 0}'))
        try:
            replies = []
            for _ in range(50):  # the queryable's declaration reaches alice through the router
                replies = [r for r in alice.get(key, timeout=2.0) if r.ok is not None]
                if replies:
                    break
            assert [r.ok.payload.to_bytes() for r in replies] == [b'{"id": 0}']
        finally:
            queryable.undeclare()

        # Another cell's identity: neither side trusts the other's CA.
        with pytest.raises(zenoh.ZError, match="Unable to connect"):
            zenoh.open(joined(other, "mallory", endpoint)).close()
        # Another cell's certificate presented to a router it trusts: the router's mutual TLS refuses it.
        trusting = joined(other, "mallory", endpoint)
        trusting.insert_json5("transport/link/tls/root_ca_certificate", json.dumps(str(cell.ca_certificate.resolve())))
        with pytest.raises(zenoh.ZError, match="Unable to connect"):
            zenoh.open(trusting).close()
        # The cell's own certificate, expired.
        with pytest.raises(zenoh.ZError, match="Unable to connect"):
            zenoh.open(joined(cell, "old", endpoint)).close()


# -- the command line -----------------------------------------------------------------------------------

def test_the_certs_command(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    root = tmp_path / "cell"
    assert cli.main(["certs", "init", str(root), "--host", "arm-pc.local"]) == 0
    out = capsys.readouterr().out
    assert f"made the cell {root}" in out and f"{root / 'ca.key'}" in out
    assert [line.split()[:2] for line in out.splitlines() if line.startswith(("  router", "  service"))] == \
        [["router", "router"], ["service", "service"]]
    assert Cell(root).identities()["router"].hosts == ("arm-pc.local",)

    issue_alice = ["certs", "issue", str(root), "alice", "--role", "operator", "--days", "30"]
    assert cli.main(issue_alice) == 0
    out = capsys.readouterr().out
    assert out.startswith("issued 'alice', role operator, serial ")
    assert all(str(root / f"alice.{ext}") in out for ext in ("pem", "key", "json5"))
    assert cli.main(issue_alice) == 2
    err = capsys.readouterr().err
    assert err.startswith("jara-arm certs: identity 'alice' is already issued (role operator") and "--force" in err
    assert cli.main([*issue_alice, "--force"]) == 0
    capsys.readouterr()

    for argv, message in [
        (["certs", "issue", str(root), "bob", "--role", "boss"],
         "invalid choice: 'boss' (choose from 'service', 'router', 'operator', 'low-level', 'observer')"),
        (["certs", "issue", str(root), "bob", "--role", "observer", "--host", "a..b"],
         "jara-arm certs: host 'a..b' is neither an IP address"),
        (["certs", "issue", str(root), "ca", "--role", "observer"], "jara-arm certs: identity name 'ca' is taken"),
        (["certs", "issue", str(root), "bob", "--role", "observer", "--days", "0"],
         "expected a whole number of 1 or more"),
        (["certs", "init", str(root)], "jara-arm certs: " + f"{root} already holds a cell"),
        (["certs", "list", str(tmp_path / "nowhere")], "is not a cell directory"),
        (["certs"], "the following arguments are required: ACTION"),
    ]:
        assert cli.main(argv) == 2, argv
        err = capsys.readouterr().err
        assert message in err and "Traceback" not in err, (argv, err)

    expired_identity(Cell(root), "old")
    assert cli.main(["certs", "list", str(root)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].split() == ["NAME", "ROLE", "EXPIRES", "HOSTS"]
    rows = {line.split()[0]: line for line in lines[1:]}
    assert list(rows) == ["alice", "old", "router", "service"]
    assert "EXPIRED" in rows["old"] and not any("EXPIRED" in rows[n] for n in ("alice", "router", "service"))
    assert rows["router"].split()[1:] == ["router", Cell(root).identities()["router"].not_after, "arm-pc.local"]
    assert table([]) == ["NAME  ROLE  EXPIRES  HOSTS"]


@pytest.mark.skipif(shutil.which("bash") is None, reason="no bash to run the script")
def test_bash_completes_the_certs_actions_and_their_options() -> None:
    assert bash_complete(["jara-arm", "cer"]) == ["certs"]
    assert bash_complete(["jara-arm", "certs", "i"]) == ["init", "issue"]
    assert bash_complete(["jara-arm", "certs", "issue", "--f"]) == ["--force"]
    assert bash_complete(["jara-arm", "certs", "init", "--"]) == ["--help", "--days", "--host"]
    assert bash_complete(["jara-arm", "certs", "issue", "--role", "o"]) == []  # an option's value
    assert bash_complete(["jara-arm", "certs", "list", "l"]) == []  # DIR is not an action
