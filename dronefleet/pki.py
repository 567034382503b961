"""`fleet pki init DIR` and `fleet pki issue DIR NAME --role …` (SPEC §9).

`init` makes the fleet's certificate authority (`ca.pem`, `ca.key`) and the ground's
command-signing key pair (`signing.key`, `signing.pub`, Ed25519). `issue` signs a
certificate for one node (`NAME.pem`, `NAME.key`; CN = NAME, OU = its role), usable
for TLS both ways (every router of the mesh is server and client). Private keys are
written 0600 and never overwritten. Certificates use ECDSA P-256, which every TLS
stack takes; commands are signed with Ed25519 (`schemas/auth.py`).
"""

from __future__ import annotations

import datetime
import ipaddress
import os
from pathlib import Path

import click

from dronefleet.schemas.keys import check_id

# relay: a drone that may carry its neighbours' traffic; sensor: a field sensor;
# observer: a ground that watches and never commands (`fleet ground --observer`, SPEC §14)
ROLES = ("drone", "relay", "ground", "operator", "sensor", "observer")
CA_YEARS, NODE_YEARS = 10, 2


def _write(path: Path, data: bytes, private: bool) -> None:
    """Create `path` (never overwrite); 0600 for a private key, from its first byte."""
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL
    fd = os.open(path, flags, 0o600 if private else 0o644)
    with os.fdopen(fd, "wb") as f:
        f.write(data)


def _pem_key(key: object) -> bytes:
    from cryptography.hazmat.primitives import serialization

    return key.private_bytes(  # type: ignore[attr-defined]
        serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption())


def init(directory: Path) -> list[Path]:
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec, ed25519
    from cryptography.x509.oid import NameOID

    directory.mkdir(parents=True, exist_ok=True)
    paths = [directory / n for n in ("ca.pem", "ca.key", "signing.key", "signing.pub")]
    existing = [p.name for p in paths if p.exists()]
    if existing:
        raise click.ClickException(f"{directory} already holds a fleet PKI ({', '.join(existing)}); "
                                   "use another directory, or remove them to start over")
    key = ec.generate_private_key(ec.SECP256R1())
    name = x509.Name([x509.NameAttribute(NameOID.ORGANIZATION_NAME, "fleet"),
                      x509.NameAttribute(NameOID.COMMON_NAME, "fleet CA")])
    now = datetime.datetime.now(datetime.UTC)
    cert = (x509.CertificateBuilder().subject_name(name).issuer_name(name).public_key(key.public_key())
            .serial_number(x509.random_serial_number()).not_valid_before(now - datetime.timedelta(minutes=5))
            .not_valid_after(now + datetime.timedelta(days=365 * CA_YEARS))
            .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
            .add_extension(x509.KeyUsage(digital_signature=True, key_cert_sign=True, crl_sign=True, content_commitment=False,
                                         key_encipherment=False, data_encipherment=False, key_agreement=False,
                                         encipher_only=False, decipher_only=False), critical=True)
            .sign(key, hashes.SHA256()))
    signing = ed25519.Ed25519PrivateKey.generate()
    _write(paths[1], _pem_key(key), private=True)
    _write(paths[0], cert.public_bytes(serialization.Encoding.PEM), private=False)
    _write(paths[2], _pem_key(signing), private=True)
    _write(paths[3], signing.public_key().public_bytes(serialization.Encoding.PEM,
                                                       serialization.PublicFormat.SubjectPublicKeyInfo), private=False)
    return paths


def issue(directory: Path, name: str, role: str, hosts: tuple[str, ...] = ()) -> list[Path]:
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.hazmat.primitives.serialization import load_pem_private_key
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    check_id(name, "name")
    ca_pem, ca_key_path = directory / "ca.pem", directory / "ca.key"
    if not ca_pem.exists() or not ca_key_path.exists():
        raise click.ClickException(f"{directory} holds no fleet CA: run `fleet pki init {directory}` first")
    pem, key_path = directory / f"{name}.pem", directory / f"{name}.key"
    if pem.exists() or key_path.exists():
        raise click.ClickException(f"{name} already has a certificate in {directory} ({pem.name}); "
                                   "choose another name, or remove both files to issue it again")
    ca_cert = x509.load_pem_x509_certificate(ca_pem.read_bytes())
    ca_key = load_pem_private_key(ca_key_path.read_bytes(), password=None)
    key = ec.generate_private_key(ec.SECP256R1())
    sans: list[x509.GeneralName] = [x509.DNSName(name), x509.DNSName("localhost"),
                                    x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]
    for host in hosts:
        try:
            sans.append(x509.IPAddress(ipaddress.ip_address(host)))
        except ValueError:
            sans.append(x509.DNSName(host))
    now = datetime.datetime.now(datetime.UTC)
    cert = (x509.CertificateBuilder()
            .subject_name(x509.Name([x509.NameAttribute(NameOID.ORGANIZATION_NAME, "fleet"),
                                     x509.NameAttribute(NameOID.ORGANIZATIONAL_UNIT_NAME, role),
                                     x509.NameAttribute(NameOID.COMMON_NAME, name)]))
            .issuer_name(ca_cert.subject).public_key(key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(now - datetime.timedelta(minutes=5)).not_valid_after(now + datetime.timedelta(days=365 * NODE_YEARS))
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(x509.SubjectAlternativeName(sans), critical=False)
            .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]), critical=False)
            .sign(ca_key, hashes.SHA256()))  # type: ignore[arg-type]
    _write(key_path, _pem_key(key), private=True)
    _write(pem, cert.public_bytes(serialization.Encoding.PEM), private=False)
    return [pem, key_path]


@click.group()
def pki() -> None:
    """The fleet's certificate authority and the ground's command-signing key (SPEC §9)."""


@pki.command("init")
@click.argument("directory", type=click.Path(file_okay=False, path_type=Path))
def pki_init(directory: Path) -> None:
    """Make the fleet CA and the ground's signing key pair in DIRECTORY."""
    for path in init(directory):
        click.echo(f"wrote {path}")
    click.echo(f"next: `fleet pki issue {directory} ground --role ground`, one `--role drone` per drone "
               f"(`--role relay` for those that may carry their neighbours' traffic); give each drone every "
               f"*.pem, its own NAME.key and signing.pub (never ca.key, signing.key or another's key)")


@pki.command("issue")
@click.argument("directory", type=click.Path(file_okay=False, exists=True, path_type=Path))
@click.argument("name")
@click.option("--role", type=click.Choice(ROLES), required=True, help="What the node is (its certificate's OU).")
@click.option("--host", "hosts", multiple=True, help="Another address or host name the node is reached at (repeatable).")
def pki_issue(directory: Path, name: str, role: str, hosts: tuple[str, ...]) -> None:
    """Issue NAME.pem and NAME.key (CN = NAME) from the fleet CA in DIRECTORY."""
    for path in issue(directory, name, role, hosts):
        click.echo(f"wrote {path}")
