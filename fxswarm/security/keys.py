"""``fxswarm keys OUT CONFIG [--days N]``: a private CA and one certificate + key per process.

Writes into OUT:

* ``ca.pem``: the swarm's CA certificate (its key, ``ca.key``, signs new
  certificates: keep it off the robots; ``--add`` uses it to add a robot);
* ``NAME.pem`` + ``NAME.key`` for NAME in ``router``, ``world``, ``leader``,
  ``logger``, ``observer`` (the launcher's progress line and ``fxswarm
  health`` run by a person) and ``agent-<i>`` for each robot of CONFIG; the
  common name is NAME, which the router's access rules go by;
* ``access.json``: the rights of each NAME in that scenario (:mod:`.policy`),
  which ``fxswarm router --secure OUT`` enforces.

Keys are ECDSA P-256 (fast handshakes, small files), written mode 0600 and
never overwritten unless ``--force``. Every certificate serves TLS and
identifies its holder as a client (a mesh peer listens for its neighbours'
links); who may do what goes by the common name, in the rules every secure
process enforces (a robot's key that poses as the router gets a robot's
rights, no more: :func:`fxswarm.runtime.tls.session_rules`). Made with
``cryptography`` (the maintained binding to OpenSSL), no shell calls.
"""

from __future__ import annotations

import argparse
import datetime as dt
import ipaddress
import json
import os
import sys
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from fxswarm.core.scenario import Scenario
from fxswarm.runtime.files import write_atomic
from fxswarm.runtime.numbers import positive_int
from fxswarm.runtime.tls import KeyFileError, files_for, check
from fxswarm.security.policy import access_control, process_names

DEFAULT_DAYS = 365
#: Names the router's certificate answers to (compose service, this machine); --router-name adds more.
ROUTER_NAMES = ("router", "localhost", "127.0.0.1")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("out", help="folder to write the keys into (made if missing)")
    p.add_argument("config", help="scenario file (TOML): one agent-<i> key per robot")
    p.add_argument("--days", type=positive_int, default=DEFAULT_DAYS,
                   help=f"validity of every certificate, days (default {DEFAULT_DAYS})")
    p.add_argument("--router-name", action="append", default=[], metavar="HOST",
                   help="another DNS name or IP address of the router, put in its certificate (repeatable)")
    which = p.add_mutually_exclusive_group()  # a new CA, or the old one kept: not both
    which.add_argument("--force", action="store_true", help="overwrite keys already in OUT (a new CA: all change)")
    which.add_argument("--add", action="store_true",
                   help="keep OUT's CA and existing keys; make only the missing ones (a robot added to "
                        "the scenario) and rewrite access.json")


def _name(cn: str) -> x509.Name:
    return x509.Name([x509.NameAttribute(NameOID.ORGANIZATION_NAME, "fxswarm"),
                      x509.NameAttribute(NameOID.COMMON_NAME, cn)])


def new_key() -> ec.EllipticCurvePrivateKey:
    return ec.generate_private_key(ec.SECP256R1())


def make_ca(days: int, label: str = "fxswarm swarm CA", now: dt.datetime | None = None):
    """(key, certificate) of a new self-signed CA valid ``days`` days from ``now``."""
    now = now or dt.datetime.now(dt.timezone.utc)
    key = new_key()
    name = _name(label)
    cert = (x509.CertificateBuilder().subject_name(name).issuer_name(name).public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - dt.timedelta(minutes=5)).not_valid_after(now + dt.timedelta(days=days))
            .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
            .add_extension(x509.KeyUsage(digital_signature=True, key_cert_sign=True, crl_sign=True,
                                         content_commitment=False, key_encipherment=False, data_encipherment=False,
                                         key_agreement=False, encipher_only=False, decipher_only=False), critical=True)
            .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), critical=False)
            .sign(key, hashes.SHA256()))
    return key, cert


def make_leaf(name: str, ca_key, ca_cert: x509.Certificate, days: int, server_names: tuple[str, ...] = (),
              now: dt.datetime | None = None):
    """(key, certificate) for process ``name`` (its common name), signed by the CA.

    Every process's certificate serves TLS too (a mesh peer listens); ``server_names`` (DNS
    names or IP addresses, the router's) are put in it, else ``name``. Names are not checked on
    connect (addresses differ per deployment; docs/security.md): the CA and the rules are.
    """
    now = now or dt.datetime.now(dt.timezone.utc)
    key = new_key()
    usages = [ExtendedKeyUsageOID.CLIENT_AUTH, ExtendedKeyUsageOID.SERVER_AUTH]
    server_names = server_names or (name,)
    builder = (x509.CertificateBuilder().subject_name(_name(name)).issuer_name(ca_cert.subject)
               .public_key(key.public_key()).serial_number(x509.random_serial_number())
               .not_valid_before(now - dt.timedelta(minutes=5)).not_valid_after(now + dt.timedelta(days=days))
               .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
               .add_extension(x509.KeyUsage(digital_signature=True, key_cert_sign=False, crl_sign=False,
                                            content_commitment=False, key_encipherment=False,
                                            data_encipherment=False, key_agreement=False, encipher_only=False,
                                            decipher_only=False), critical=True)
               .add_extension(x509.ExtendedKeyUsage(usages), critical=False)
               .add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()),
                              critical=False))
    builder = builder.add_extension(x509.SubjectAlternativeName([_general_name(n) for n in server_names]),
                                    critical=False)
    return key, builder.sign(ca_key, hashes.SHA256())


def _general_name(text: str) -> x509.GeneralName:
    try:
        return x509.IPAddress(ipaddress.ip_address(text))
    except ValueError:
        return x509.DNSName(text)


def _write(path: Path, data: bytes, private: bool) -> None:
    """Write atomically; a private key is created mode 0600 (never readable by others, not even briefly)."""
    write_atomic(path, data, private)


def _key_pem(key) -> bytes:
    return key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                             serialization.NoEncryption())


def _cert_pem(cert: x509.Certificate) -> bytes:
    return cert.public_bytes(serialization.Encoding.PEM)


def write_keys(out: str | os.PathLike, scenario: Scenario, days: int = DEFAULT_DAYS,
               router_names: tuple[str, ...] = (), force: bool = False, add: bool = False,
               now: dt.datetime | None = None) -> list[str]:
    """Make the CA (unless ``add``) and every process's key in ``out``; return the names written.

    Raises FileExistsError if ``out`` already holds keys and neither ``force`` nor ``add``;
    KeyFileError if ``add`` and ``out`` has no usable CA.
    """
    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    names = process_names(scenario)
    if add:
        ca_key_path, ca_path = folder / "ca.key", folder / "ca.pem"
        if not ca_key_path.exists():
            raise KeyFileError(f"{ca_key_path}: missing (the CA's key, needed to add keys to {folder})")
        try:
            ca_key = serialization.load_pem_private_key(ca_key_path.read_bytes(), password=None)
            ca_cert = x509.load_pem_x509_certificate(ca_path.read_bytes())
        except (OSError, ValueError) as exc:
            raise KeyFileError(f"{folder}: cannot load the CA (ca.pem, ca.key): {exc}") from None
        todo = [n for n in names if not (folder / f"{n}.pem").exists()]
    else:
        existing = [p.name for p in (folder / "ca.pem", folder / "ca.key") if p.exists()]
        if existing and not force:
            raise FileExistsError(f"{folder}: already holds keys ({', '.join(existing)}); --force makes a new CA "
                                  f"(every process needs its new key), --add adds missing ones")
        ca_key, ca_cert = make_ca(days, now=now)
        _write(folder / "ca.key", _key_pem(ca_key), private=True)
        _write(folder / "ca.pem", _cert_pem(ca_cert), private=False)
        todo = names
    for name in todo:
        server = tuple(dict.fromkeys((*ROUTER_NAMES, *router_names))) if name == "router" else ()
        key, cert = make_leaf(name, ca_key, ca_cert, days, server, now=now)
        _write(folder / f"{name}.key", _key_pem(key), private=True)
        _write(folder / f"{name}.pem", _cert_pem(cert), private=False)
    write_access(folder / "access.json", scenario)
    return todo


def write_access(path: Path, scenario: Scenario, swarm: str = "*") -> Path:
    """The router's ``access_control`` section for ``scenario`` as JSON (which JSON5 reads as is)."""
    _write(Path(path), (json.dumps(access_control(scenario, swarm), indent=1) + "\n").encode(), private=False)
    return Path(path)


def main(args: argparse.Namespace) -> int:
    from fxswarm.runtime.config import load_or_exit

    sc = load_or_exit(args.config)
    try:
        written = write_keys(args.out, sc, args.days, tuple(args.router_name), args.force, args.add)
        for name in written:
            check(files_for(args.out, name))  # what we wrote must pass the check every process makes
    except (FileExistsError, KeyFileError) as exc:
        print(f"fxswarm keys: {exc}", file=sys.stderr)
        return 2
    what = ", ".join(written) if written else "no new key"
    print(f"fxswarm keys: wrote {what} into {args.out} (valid {args.days} days; ca.key signs new keys: "
          f"keep it off the robots). Use: fxswarm run {args.config} --secure {args.out}", file=sys.stderr)
    return 0
