"""Secure mode's files: one process's CA, certificate and key, checked before any session opens.

A keys folder (``fxswarm keys OUT CONFIG``, :mod:`fxswarm.security.keys`) holds
``ca.pem`` and, per process, ``NAME.pem`` + ``NAME.key`` (NAME: ``router``,
``world``, ``leader``, ``logger``, ``observer``, ``agent-<i>``). A process
with ``--secure KEYS`` uses its own pair; :func:`check` refuses, in one line
naming the file, a file that is missing, unreadable, not PEM, expired or not
yet valid, not signed by ``ca.pem``, or a key that is not the certificate's.
Zenoh would otherwise fail later, in every process at once, with an error
naming no file (or, for an expired certificate, only at the first handshake).

Zenoh's TLS settings (``transport/link/tls``) and the rules each secure
session enforces on its own links (:func:`session_rules`) are made here too:
mutual TLS both ways, trust resting on the private CA. Server-name checking
is off (the router's address differs per deployment: 127.0.0.1, ``router`` in
compose, a host name); instead every process trusts only the certificate
named ``router`` to forward, so another process's key that poses as the
router gets that process's rights and no more (docs/security.md).
"""

from __future__ import annotations

import datetime as _dt
import json
import os
from dataclasses import dataclass
from pathlib import Path

#: The environment variable a container (or a user) can set instead of ``--secure KEYS``.
SECURE_ENV = "FXSWARM_SECURE"


class KeyFileError(ValueError):
    """A key file that cannot be used; the message names the file and says why."""


@dataclass(frozen=True)
class TlsFiles:
    """One process's secure-mode files: the swarm's CA, its certificate and its private key."""

    ca: Path
    cert: Path
    key: Path
    name: str  # the certificate's common name: who the router's rules say this process is

    def zenoh_tls(self, listen: bool = False) -> dict:
        """The ``transport/link/tls`` section: mutual TLS with these files (router: ``listen``)."""
        out = {"root_ca_certificate": str(self.ca), "enable_mtls": True,
               "connect_certificate": str(self.cert), "connect_private_key": str(self.key),
               "verify_name_on_connect": False}
        if listen:
            out.update(listen_certificate=str(self.cert), listen_private_key=str(self.key))
        return out

    def insert_into(self, conf, listen: bool = False) -> None:
        """Put the TLS section into a ``zenoh.Config``."""
        conf.insert_json5("transport/link/tls", json.dumps(self.zenoh_tls(listen)))


def identity(role: str, ident: int | str = 0) -> str:
    """The certificate common name of a process: ``agent-3``, ``world``, ..."""
    return f"agent-{ident}" if role == "agent" else role


def files_for(keys: str | os.PathLike, name: str) -> TlsFiles:
    """The paths of ``name``'s files in the folder ``keys`` (not checked: :func:`check` does)."""
    folder = Path(keys)
    return TlsFiles(folder / "ca.pem", folder / f"{name}.pem", folder / f"{name}.key", name)


def _read(path: Path, what: str) -> bytes:
    if not path.exists():
        raise KeyFileError(f"{path}: missing ({what}; make the folder with `fxswarm keys OUT CONFIG`)")
    try:
        return path.read_bytes()
    except OSError as exc:
        raise KeyFileError(f"{path}: cannot read {what}: {exc.strerror or exc}") from None


def _cert(path: Path, what: str):
    from cryptography import x509

    data = _read(path, what)  # outside the try: its KeyFileError is a ValueError too
    try:
        return x509.load_pem_x509_certificate(data)
    except ValueError as exc:
        raise KeyFileError(f"{path}: not a PEM certificate ({what}): {exc}") from None


def _valid_now(cert, path: Path, what: str, now: _dt.datetime) -> None:
    if now < cert.not_valid_before_utc:
        raise KeyFileError(f"{path}: {what} is not valid before {cert.not_valid_before_utc:%Y-%m-%d %H:%M} UTC")
    if now > cert.not_valid_after_utc:
        raise KeyFileError(f"{path}: {what} expired on {cert.not_valid_after_utc:%Y-%m-%d %H:%M} UTC "
                           f"(make new keys: `fxswarm keys`, docs/security.md)")


def common_name(cert) -> str | None:
    from cryptography.x509.oid import NameOID

    names = cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)
    return str(names[0].value) if names else None


def check(files: TlsFiles, now: _dt.datetime | None = None):
    """Raise :class:`KeyFileError` naming the file unless ``files`` can be used right now; return
    the certificate, as read.

    Checks: each file exists and is readable PEM; CA and certificate are within their
    validity; the certificate is signed by that CA and its common name is ``files.name``;
    the private key belongs to the certificate.
    """
    from cryptography.exceptions import InvalidSignature
    from cryptography.hazmat.primitives import serialization
    from cryptography.hazmat.primitives.asymmetric import ec, padding, rsa

    now = now or _dt.datetime.now(_dt.timezone.utc)
    ca = _cert(files.ca, "the swarm's CA certificate")
    _valid_now(ca, files.ca, "the CA certificate", now)
    cert = _cert(files.cert, f"{files.name}'s certificate")
    _valid_now(cert, files.cert, f"{files.name}'s certificate", now)
    if cert.issuer != ca.subject:
        raise KeyFileError(f"{files.cert}: not issued by the CA in {files.ca} (issuer {cert.issuer.rfc4514_string()}, "
                           f"CA {ca.subject.rfc4514_string()}): keys from another `fxswarm keys` run?")
    pub = ca.public_key()
    try:
        if isinstance(pub, rsa.RSAPublicKey):
            pub.verify(cert.signature, cert.tbs_certificate_bytes, padding.PKCS1v15(), cert.signature_hash_algorithm)
        elif isinstance(pub, ec.EllipticCurvePublicKey):
            pub.verify(cert.signature, cert.tbs_certificate_bytes, ec.ECDSA(cert.signature_hash_algorithm))
        else:
            cert.verify_directly_issued_by(ca)
    except (InvalidSignature, ValueError, TypeError):
        raise KeyFileError(f"{files.cert}: its signature does not verify against the CA in {files.ca}: "
                           f"signed by another CA of the same name?") from None
    cn = common_name(cert)
    if cn != files.name:
        raise KeyFileError(f"{files.cert}: its common name is {cn!r}, expected {files.name!r}")
    data = _read(files.key, f"{files.name}'s private key")  # outside the try: its KeyFileError is a ValueError
    try:
        key = serialization.load_pem_private_key(data, password=None)
    except (ValueError, TypeError) as exc:
        raise KeyFileError(f"{files.key}: not an unencrypted PEM private key: {exc}") from None
    same = serialization.PublicFormat.SubjectPublicKeyInfo
    if key.public_key().public_bytes(serialization.Encoding.DER, same) != \
            cert.public_key().public_bytes(serialization.Encoding.DER, same):
        raise KeyFileError(f"{files.key}: does not belong to the certificate {files.cert}")
    return cert


def checked(keys: str | os.PathLike, name: str, server: bool = False) -> TlsFiles:
    """``files_for(keys, name)``, checked (raises :class:`KeyFileError`); ``server``: it must also
    serve TLS (a mesh peer listens for its neighbours' links)."""
    files = files_for(keys, name)
    if not Path(keys).is_dir():
        raise KeyFileError(f"{keys}: not a folder of keys (make one with `fxswarm keys OUT CONFIG`)")
    cert = check(files)
    if server and not serves_tls(cert):
        raise KeyFileError(f"{files.cert}: not a TLS server certificate, which a mesh peer needs (keys made "
                           f"by an older fxswarm: make new ones with `fxswarm keys --force`, or run routed)")
    return files


def serves_tls(cert) -> bool:
    """Whether ``cert`` may serve TLS (extended key usage ``serverAuth``, or none given)."""
    from cryptography import x509
    from cryptography.x509.oid import ExtendedKeyUsageOID

    try:
        usage = cert.extensions.get_extension_for_class(x509.ExtendedKeyUsage).value
    except x509.ExtensionNotFound:
        return True
    return ExtendedKeyUsageOID.SERVER_AUTH in usage


def load_access(path: str | os.PathLike) -> dict:
    """The ``access_control`` section from ``path``; raises KeyFileError naming the file."""
    p = Path(path)
    try:
        data = json.loads(p.read_text())
    except FileNotFoundError:
        raise KeyFileError(f"{p}: missing (the access rules; `fxswarm keys` writes them)") from None
    except OSError as exc:
        raise KeyFileError(f"{p}: cannot read the access rules: {exc.strerror or exc}") from None
    except ValueError as exc:
        raise KeyFileError(f"{p}: not JSON: {exc}") from None
    if not isinstance(data, dict) or data.get("default_permission") != "deny" or not data.get("enabled"):
        raise KeyFileError(f"{p}: expected an enabled access_control section with default_permission \"deny\"")
    return data


#: Every Zenoh message kind the access-control interceptor knows (for "the router may say all").
ALL_MESSAGES = ("put", "delete", "declare_subscriber", "query", "declare_queryable", "reply",
                "liveliness_token", "declare_liveliness_subscriber", "liveliness_query")


def session_rules(mode: str, access: dict | None) -> dict:
    """The ``access_control`` section a secure process enforces on its own links (default deny).

    Every process trusts the router (certificate common name ``router``) with everything: the router
    enforces the swarm's rules on each sender before it forwards. A client has no other link, so its
    rules are only that: a process holding another key that poses as the router (it answers at the
    router's address) gets nothing in or out. A mesh peer also has direct links to other peers, on
    which it enforces the swarm's rules itself (``access``: the router's section, :mod:`fxswarm.security.policy`).
    """
    rules = [{"id": "router-forwards", "messages": list(ALL_MESSAGES), "flows": ["ingress", "egress"],
              "permission": "allow", "key_exprs": ["**"]}]
    subjects = [{"id": "s-router-forwards", "cert_common_names": ["router"]}]
    policies = [{"id": "p-router-forwards", "rules": ["router-forwards"], "subjects": ["s-router-forwards"]}]
    if mode != "client":
        if access is None:
            raise ValueError("a secure mesh peer needs the swarm's rules (--access FILE)")
        rules = [*access.get("rules", []), *rules]
        subjects = [*access.get("subjects", []), *subjects]
        policies = [*access.get("policies", []), *policies]
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects,
            "policies": policies}


def tls_endpoints(endpoints, option: str) -> None:
    """Raise ValueError unless every endpoint is ``tls/``: secure mode has no plaintext link."""
    for e in endpoints:
        if not e.startswith("tls/"):
            raise ValueError(f"{option} {e}: secure mode takes tls/HOST:PORT endpoints only (nothing in plaintext)")
