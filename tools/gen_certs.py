"""Certificates and Zenoh security configs for a fleet.

Writes a private certificate authority, one certificate per process (the coordinator and every
carrier), and one Zenoh JSON5 config per role that turns on TLS with mutual authentication and
access control keyed by certificate common name (see docs/security.md):

    python tools/gen_certs.py --out certs --scenario scenarios/tiny.yaml
    python tools/gen_certs.py --out certs --carriers c0 c1 c2 --hosts coord.lan 10.0.0.1

Files written to OUT (keys are unencrypted PEM, mode 0600):

    ca.pem ca.key                          the fleet's certificate authority
    coordinator.pem coordinator.key        CN "marsupial-coordinator", SANs = --hosts
    carrier-<id>.pem carrier-<id>.key      CN "marsupial-carrier-<id>"
    coordinator.json5 carrier-<id>.json5   Zenoh configs pointing at the files above (absolute paths)

Pass a config to a role with `python run_fleet.py SCENARIO --zenoh-config OUT/coordinator.json5`.
"""

from __future__ import annotations

import argparse
import datetime
import ipaddress
import json
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping, Sequence

try:  # the `security` extra (pip install -e '.[security]'); main() says so when it is missing
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID
except ImportError:  # pragma: no cover - exercised by a subprocess without the package
    x509 = None  # type: ignore[assignment]

#: What to install for this tool (pyproject.toml's extra).
INSTALL_HINT = "pip install -e '.[security]' (or: pip install cryptography)"
#: Modes whatever the umask: private keys and configs (they name the keys) owner-only, the
#: folder owner-only, certificates world-readable (they are public).
KEY_MODE, CONFIG_MODE, DIR_MODE, CERT_MODE = 0o600, 0o600, 0o700, 0o644

from planner.limits import TRANSPORT_MAX_MESSAGE_BYTES  # noqa: E402

COORDINATOR_CN = "marsupial-coordinator"
CA_CN = "marsupial-fleet-ca"
DEFAULT_HOSTS = ("localhost", "127.0.0.1")  # names the coordinator's certificate is valid for
DEFAULT_DAYS = 30  # validity of every certificate, days
KEY_PREFIX = "marsupial"  # first chunk of every key expression of the fleet

# Zenoh 1.x access-control message kinds (config key access_control.rules[].messages).
ALL_MESSAGES = (
    "put", "delete", "declare_subscriber", "query", "reply", "declare_queryable",
    "liveliness_token", "liveliness_query", "declare_liveliness_subscriber",
)
# What a carrier may send towards the coordinator on any fleet key: interest only, no data.
CARRIER_READ_MESSAGES = ("declare_subscriber", "query", "liveliness_query", "declare_liveliness_subscriber")
# What the coordinator forwards to a carrier on any fleet key: routing declarations, no data.
ROUTING_MESSAGES = ("declare_subscriber", "declare_queryable", "query", "liveliness_query",
                    "declare_liveliness_subscriber", "delete")
# The carriers' topics every carrier may read (a carrier deciding alone listens to them).
PEER_TOPICS = ("obs", "own", "confirm", "progress")
# What a carrier may send only under its own keys marsupial/<mission>/carrier/<id>/**.
CARRIER_WRITE_MESSAGES = ("put", "delete", "declare_queryable", "reply", "liveliness_token")


def operator_cn(operator_id: str) -> str:
    """Certificate common name of operator `operator_id` (docs/protocol.md, "Operator actions")."""
    return f"marsupial-operator-{operator_id}"


def carrier_cn(carrier_id: str) -> str:
    """Certificate common name of carrier `carrier_id`; the access-control subject matches it."""
    return f"marsupial-carrier-{carrier_id}"


@dataclass(frozen=True)
class Identity:
    """One process's credentials: certificate common name and PEM file paths."""

    cn: str
    cert: Path
    key: Path


@dataclass(frozen=True)
class FleetCerts:
    """Everything `generate_fleet_certs` wrote: the CA certificate and each process's identity."""

    ca: Path
    coordinator: Identity
    carriers: Mapping[str, Identity]
    operators: Mapping[str, Identity] = field(default_factory=dict)


def _name(cn: str) -> x509.Name:
    return x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, cn)])


def _write_key(path: Path, key: ec.EllipticCurvePrivateKey) -> None:
    data = key.private_bytes(
        serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()
    )
    _write_private(path, data, KEY_MODE)


def _write_private(path: Path, data: bytes, mode: int) -> None:
    """Write ``data`` to ``path`` with ``mode`` exactly: set on the open file before anything is
    written (an existing file's looser mode is fixed first; the umask is not consulted)."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, mode)
    os.fchmod(fd, mode)
    with os.fdopen(fd, "wb") as f:
        f.write(data)


def _write_cert(path: Path, cert: x509.Certificate) -> None:
    _write_private(path, cert.public_bytes(serialization.Encoding.PEM), CERT_MODE)


def _validity(days: float) -> tuple[datetime.datetime, datetime.datetime]:
    now = datetime.datetime.now(datetime.timezone.utc)
    # Backdated a few minutes so that hosts with slightly skewed clocks accept a fresh certificate.
    return now - datetime.timedelta(minutes=5), now + datetime.timedelta(days=days)


def make_ca(out: Path, cn: str = CA_CN, days: float = DEFAULT_DAYS, stem: str = "ca") -> Identity:
    """Write a self-signed CA certificate and key (ECDSA P-256) as OUT/STEM.pem and OUT/STEM.key."""
    out.mkdir(parents=True, exist_ok=True)
    key = ec.generate_private_key(ec.SECP256R1())
    not_before, not_after = _validity(days)
    usage = x509.KeyUsage(
        digital_signature=True, key_cert_sign=True, crl_sign=True, content_commitment=False,
        key_encipherment=False, data_encipherment=False, key_agreement=False,
        encipher_only=False, decipher_only=False,
    )
    cert = (
        x509.CertificateBuilder()
        .subject_name(_name(cn))
        .issuer_name(_name(cn))
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(not_before)
        .not_valid_after(not_after)
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
        .add_extension(usage, critical=True)
        .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), critical=False)
        .sign(key, hashes.SHA256())
    )
    identity = Identity(cn, out / f"{stem}.pem", out / f"{stem}.key")
    _write_cert(identity.cert, cert)
    _write_key(identity.key, key)
    return identity


def issue(
    ca: Identity, out: Path, stem: str, cn: str, hosts: Sequence[str] = DEFAULT_HOSTS,
    days: float = DEFAULT_DAYS,
) -> Identity:
    """Write a certificate for CN signed by `ca`, usable as TLS server and client.

    `hosts` become subject alternative names (IP addresses or DNS names): a process that connects
    with `verify_name_on_connect` checks the listener's certificate against the host it dialled.
    """
    ca_key = serialization.load_pem_private_key(ca.key.read_bytes(), password=None)
    ca_cert = x509.load_pem_x509_certificate(ca.cert.read_bytes())
    key = ec.generate_private_key(ec.SECP256R1())
    names: list[x509.GeneralName] = []
    for host in hosts:
        try:
            names.append(x509.IPAddress(ipaddress.ip_address(host)))
        except ValueError:
            names.append(x509.DNSName(host))
    not_before, not_after = _validity(days)
    builder = (
        x509.CertificateBuilder()
        .subject_name(_name(cn))
        .issuer_name(ca_cert.subject)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(not_before)
        .not_valid_after(not_after)
        .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        .add_extension(
            x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]),
            critical=False,
        )
        .add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()), critical=False)
    )
    if names:
        builder = builder.add_extension(x509.SubjectAlternativeName(names), critical=False)
    identity = Identity(cn, out / f"{stem}.pem", out / f"{stem}.key")
    _write_cert(identity.cert, builder.sign(ca_key, hashes.SHA256()))
    _write_key(identity.key, key)
    return identity


def fleet_layout(out: Path, carrier_ids: Sequence[str], operator_ids: Sequence[str] = ()) -> FleetCerts:
    """The file names `generate_fleet_certs` uses under OUT, without writing anything."""
    out = Path(out)
    return FleetCerts(
        out / "ca.pem",
        Identity(COORDINATOR_CN, out / "coordinator.pem", out / "coordinator.key"),
        {cid: Identity(carrier_cn(cid), out / f"carrier-{cid}.pem", out / f"carrier-{cid}.key")
         for cid in carrier_ids},
        {op: Identity(operator_cn(op), out / f"operator-{op}.pem", out / f"operator-{op}.key") for op in operator_ids},
    )


def generate_fleet_certs(
    out: Path, carrier_ids: Sequence[str], hosts: Sequence[str] = DEFAULT_HOSTS,
    days: float = DEFAULT_DAYS, operator_ids: Sequence[str] = (),
) -> FleetCerts:
    """Write a CA, the coordinator's certificate (valid for `hosts`), one per carrier and one per
    operator console (`operator_ids`).

    Returns the `fleet_layout` of OUT made absolute.
    """
    out = Path(out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    os.chmod(out, DIR_MODE)
    layout = fleet_layout(out, carrier_ids, operator_ids)
    ca = make_ca(out, days=days)
    issue(ca, out, "coordinator", COORDINATOR_CN, hosts, days)
    for cid in carrier_ids:
        issue(ca, out, f"carrier-{cid}", carrier_cn(cid), DEFAULT_HOSTS, days)
    for op in operator_ids:
        issue(ca, out, f"operator-{op}", operator_cn(op), DEFAULT_HOSTS, days)
    return layout


def tls_section(ca_cert: Path, identity: Identity | None, verify_name: bool = True) -> dict:
    """`transport.link.tls` for mutual TLS: the CA to trust and the process's own key pair.

    The same pair serves listening and connecting. `identity=None` builds a config that trusts
    the CA but presents no certificate (what an unauthorised process has).
    """
    tls: dict = {
        "root_ca_certificate": str(ca_cert),
        "enable_mtls": True,
        "verify_name_on_connect": verify_name,
    }
    if identity is not None:
        tls.update(
            listen_private_key=str(identity.key), listen_certificate=str(identity.cert),
            connect_private_key=str(identity.key), connect_certificate=str(identity.cert),
        )
    return tls


def coordinator_acl(carrier_ids: Sequence[str], prefix: str = KEY_PREFIX, operator_ids: Sequence[str] = ()) -> dict:
    """Access control for the coordinator's session (the hub every carrier connects to).

    Default deny. Every carrier certificate may subscribe and query under `prefix/**`; carrier
    `id` may put, delete, reply, declare queryables and liveliness tokens only under
    `prefix/*/carrier/<id>/**`. Anything else a carrier sends (a decision under
    `prefix/<mission>/coordinator/**`, another carrier's observation) is dropped on ingress.
    Least privilege for reads (egress): carrier `id` receives the Decisions and End, its own
    Accepted and Refusal, State replies, the carriers' observations, accounts, confirmations and
    Progress (what a carrier deciding alone reads, docs/protocol.md [P-8.3]) and the liveliness
    tokens; not another carrier's Hello, Bye, Pose, Accepted or Refusal.
    """
    rules = [
        {"id": "carriers-read", "messages": list(CARRIER_READ_MESSAGES), "flows": ["ingress"],
         "permission": "allow", "key_exprs": [f"{prefix}/**"]},
        {"id": "carriers-routing", "messages": list(ROUTING_MESSAGES), "flows": ["egress"],
         "permission": "allow", "key_exprs": [f"{prefix}/**"]},
        {"id": "carriers-receive", "messages": ["put"], "flows": ["egress"], "permission": "allow",
         "key_exprs": [f"{prefix}/*/coordinator/decision", f"{prefix}/*/coordinator/end",
                       *(f"{prefix}/*/carrier/*/{topic}" for topic in PEER_TOPICS)]},
        {"id": "carriers-state", "messages": ["reply"], "flows": ["egress"], "permission": "allow",
         "key_exprs": [f"{prefix}/*/coordinator/state"]},
        {"id": "carriers-presence", "messages": ["liveliness_token"], "flows": ["egress"], "permission": "allow",
         "key_exprs": [f"{prefix}/*/coordinator/alive", f"{prefix}/*/carrier/*/alive"]},
    ]
    subjects = [{"id": "carriers", "cert_common_names": [carrier_cn(c) for c in carrier_ids]}]
    policies = [{"id": "carriers", "rules": ["carriers-read", "carriers-routing", "carriers-receive", "carriers-state",
                                             "carriers-presence"], "subjects": ["carriers"]}]
    for cid in carrier_ids:
        rules.append({
            "id": f"own-{cid}", "messages": list(CARRIER_WRITE_MESSAGES), "flows": ["ingress"],
            "permission": "allow", "key_exprs": [f"{prefix}/*/carrier/{cid}/**"],
        })
        rules.append({
            "id": f"answers-{cid}", "messages": ["put"], "flows": ["egress"], "permission": "allow",
            "key_exprs": [f"{prefix}/*/coordinator/accepted/{cid}", f"{prefix}/*/coordinator/refusal/{cid}"],
        })
        subjects.append({"id": f"carrier-{cid}", "cert_common_names": [carrier_cn(cid)]})
        policies.append({"id": f"carrier-{cid}", "rules": [f"own-{cid}", f"answers-{cid}"],
                         "subjects": [f"carrier-{cid}"]})
    for op in operator_ids:  # an operator puts its actions under its own subtree, reads its answers
        rules += [
            {"id": f"operator-{op}-act", "messages": ["put"], "flows": ["ingress"], "permission": "allow",
             "key_exprs": [f"{prefix}/*/operator/{op}/action"]},
            {"id": f"operator-{op}-read", "messages": ["declare_subscriber"], "flows": ["ingress"],
             "permission": "allow", "key_exprs": [f"{prefix}/*/coordinator/operator/{op}"]},
            {"id": f"operator-{op}-answers", "messages": list(ALL_MESSAGES), "flows": ["egress"],
             "permission": "allow", "key_exprs": [f"{prefix}/*/coordinator/operator/{op}"]},
        ]
        subjects.append({"id": f"operator-{op}", "cert_common_names": [operator_cn(op)]})
        policies.append({"id": f"operator-{op}", "rules": [f"operator-{op}-act", f"operator-{op}-read",
                                                           f"operator-{op}-answers"],
                         "subjects": [f"operator-{op}"]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects,
            "policies": policies}


def carrier_acl(prefix: str = KEY_PREFIX) -> dict:
    """Access control for a carrier's session: it exchanges fleet messages with the coordinator only.

    Default deny; the subject is the coordinator's certificate common name, so a decision that
    reaches a carrier over any other link (e.g. straight from another carrier) is dropped.
    """
    return {
        "enabled": True, "default_permission": "deny",
        "rules": [{"id": "coordinator", "messages": list(ALL_MESSAGES), "flows": ["ingress", "egress"],
                   "permission": "allow", "key_exprs": [f"{prefix}/**"]}],
        "subjects": [{"id": "coordinator", "cert_common_names": [COORDINATOR_CN]}],
        "policies": [{"id": "coordinator", "rules": ["coordinator"], "subjects": ["coordinator"]}],
    }


def coordinator_config(certs: FleetCerts, listen: Sequence[str] = ("tls/127.0.0.1:7447",)) -> dict:
    """A whole Zenoh config for the coordinator: TLS-only listener, mutual TLS, per-carrier ACL."""
    return {
        "listen": {"endpoints": list(listen)},
        "scouting": {"multicast": {"enabled": False}},
        "transport": {"link": {"protocols": ["tls"], "tls": tls_section(certs.ca, certs.coordinator),
                               "rx": {"max_message_size": TRANSPORT_MAX_MESSAGE_BYTES}}},
        "access_control": coordinator_acl(sorted(certs.carriers), operator_ids=sorted(certs.operators)),
    }


def carrier_config(
    certs: FleetCerts, carrier_id: str, connect: Sequence[str] = ("tls/127.0.0.1:7447",), identity=None,
) -> dict:
    """A whole Zenoh config for carrier `carrier_id` (or another `identity`: an operator console):
    connects over mutual TLS, listens nowhere, talks to the coordinator only."""
    return {
        "connect": {"endpoints": list(connect)},
        "listen": {"endpoints": []},
        "scouting": {"multicast": {"enabled": False}},
        "transport": {"link": {"protocols": ["tls"], "tls": tls_section(
            certs.ca, identity if identity is not None else certs.carriers[carrier_id]),
                               "rx": {"max_message_size": TRANSPORT_MAX_MESSAGE_BYTES}}},
        "access_control": carrier_acl(),
    }


def write_json5(path: Path, config: dict, comment: str = "") -> Path:
    """Write `config` as JSON5 (plain JSON plus a `//` comment header)."""
    header = "".join(f"// {line}\n" for line in comment.splitlines())
    _write_private(Path(path), (header + json.dumps(config, indent=2) + "\n").encode(), CONFIG_MODE)
    return path


def write_fleet_configs(
    out: Path, certs: FleetCerts, listen: Sequence[str] = ("tls/127.0.0.1:7447",),
    connect: Sequence[str] | None = None,
) -> dict[str, Path]:
    """Write OUT/coordinator.json5 and OUT/carrier-<id>.json5; returns {role name: path}."""
    out = Path(out)
    connect = list(connect) if connect is not None else list(listen)
    paths = {"coordinator": write_json5(
        out / "coordinator.json5", coordinator_config(certs, listen),
        "Zenoh config of the coordinator, written by tools/gen_certs.py (docs/security.md).",
    )}
    for cid in certs.carriers:
        paths[f"carrier-{cid}"] = write_json5(
            out / f"carrier-{cid}.json5", carrier_config(certs, cid, connect),
            f"Zenoh config of carrier {cid}, written by tools/gen_certs.py (docs/security.md).",
        )
    for op, identity in certs.operators.items():
        paths[f"operator-{op}"] = write_json5(
            out / f"operator-{op}.json5", carrier_config(certs, "", connect, identity),
            f"Zenoh config of operator console {op}, written by tools/gen_certs.py (docs/security.md).",
        )
    return paths


def scenario_carrier_ids(path: Path) -> list[str]:
    """Carrier ids of a scenario file (its `carriers[].id`); ValueError with a one-line reason."""
    import yaml

    try:
        doc = yaml.safe_load(Path(path).read_text())
    except OSError as exc:
        raise ValueError(f"{path}: cannot read: {exc.strerror}") from None
    except yaml.YAMLError as exc:
        raise ValueError(f"{path}: not valid YAML: {str(exc).splitlines()[0]}") from None
    carriers = doc.get("carriers") if isinstance(doc, dict) else None
    if not isinstance(carriers, list) or not carriers:
        raise ValueError(f"{path}: carriers: expected a non-empty list, found {type(carriers).__name__}")
    ids = []
    for i, c in enumerate(carriers):
        if not isinstance(c, dict) or not isinstance(c.get("id"), (str, int)):
            raise ValueError(f"{path}: carriers[{i}].id: expected a string, found {c!r}")
        ids.append(str(c["id"]))
    return ids


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("certs"), help="output directory (default: certs)")
    who = parser.add_mutually_exclusive_group(required=True)
    who.add_argument("--scenario", type=Path, help="take the carrier ids from this scenario file")
    who.add_argument("--carriers", nargs="+", metavar="ID", help="carrier ids")
    parser.add_argument("--hosts", nargs="+", default=list(DEFAULT_HOSTS),
                        help="DNS names / IP addresses the coordinator is reached at (certificate SANs)")
    parser.add_argument("--listen", nargs="+", default=["tls/127.0.0.1:7447"],
                        help="coordinator listen endpoints written to coordinator.json5")
    parser.add_argument("--connect", nargs="+", default=None,
                        help="endpoints carriers connect to (default: the --listen endpoints)")
    parser.add_argument("--days", type=float, default=DEFAULT_DAYS, help="certificate validity, days")
    parser.add_argument("--operators", nargs="+", default=[], metavar="ID",
                        help="operator consoles allowed to send operator actions (docs/protocol.md, section 12)")
    args = parser.parse_args(argv)
    if x509 is None:
        print(f"error: tools/gen_certs.py needs the cryptography package: {INSTALL_HINT}", file=sys.stderr)
        return 2
    try:
        ids = scenario_carrier_ids(args.scenario) if args.scenario else list(args.carriers)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    for endpoint in [*args.listen, *(args.connect or [])]:
        if not endpoint.startswith("tls/"):
            print(f"error: endpoint {endpoint!r}: expected tls/HOST:PORT, found another protocol", file=sys.stderr)
            return 2
    try:
        certs = generate_fleet_certs(args.out, ids, args.hosts, args.days, args.operators)
        paths = write_fleet_configs(args.out, certs, args.listen, args.connect)
    except OSError as exc:
        print(f"error: {args.out}: cannot write: {exc.strerror}", file=sys.stderr)
        return 2
    print(f"CA {certs.ca}")
    for role, path in paths.items():
        print(f"{role}: {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
