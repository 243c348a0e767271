"""Certificates, trusted clients and users of the ``opcua`` front.

* The server certificate (Basic256Sha256 needs one) comes from ``certificate_file`` /
  ``private_key_file``, or is generated on first start into the state directory
  (``<front>.opcua-cert.der``, ``<front>.opcua-key.pem``, written atomically, the key mode 0600)
  and reused afterwards, so clients that trusted it keep trusting it.
* A client application certificate is accepted on Sign/SignAndEncrypt only when the same
  certificate is in the trusted directory (DER or PEM files, read again at each new session,
  so trusting a client needs no restart). A refused one is written to ``rejected/`` beside it,
  for an administrator to move into ``trusted/``: the usual OPC UA trust-list workflow.
* Users: name and password (from a file or the environment), compared in constant time.
"""

from __future__ import annotations

import datetime
import hashlib
import hmac
import logging
import socket
from collections.abc import Callable
from pathlib import Path
from typing import Any

from asyncua import ua
from asyncua.crypto import cert_gen
from asyncua.crypto.permission_rules import User, UserRole
from asyncua.server.user_managers import UserManager
from cryptography import x509
from cryptography.hazmat.primitives import serialization
from cryptography.x509.oid import ExtendedKeyUsageOID

from fieldgate.persist import write_atomic

log = logging.getLogger("fieldgate.front.opcua")

CERT_DAYS = 5 * 365


def ensure_certificate(
    cert_path: Path, key_path: Path, app_uri: str, name: str
) -> tuple[bytes, bytes]:
    """(certificate DER, key PEM): loaded, or generated when missing or expired. OSError on I/O."""
    if cert_path.is_file() and key_path.is_file():
        der = cert_path.read_bytes()
        cert = x509.load_der_x509_certificate(der)
        if cert.not_valid_after_utc > datetime.datetime.now(datetime.UTC):
            return der, key_path.read_bytes()
        log.warning(
            "server certificate %s expired on %s: generating a new one",
            cert_path,
            cert.not_valid_after_utc,
        )
    host = socket.gethostname()
    key = cert_gen.generate_private_key()
    cert = cert_gen.generate_self_signed_app_certificate(
        key,
        name,
        {"organizationName": "fieldgate"},
        [x509.UniformResourceIdentifier(app_uri), x509.DNSName(host), x509.DNSName("localhost")],
        extended=[ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH],
        days=CERT_DAYS,
    )
    der = cert.public_bytes(serialization.Encoding.DER)
    pem = cert_gen.dump_private_key_as_pem(key)
    write_atomic(key_path, pem)
    key_path.chmod(0o600)
    write_atomic(cert_path, der)
    log.info(
        "generated the server certificate %s (SHA-1 thumbprint %s, valid %d days)",
        cert_path,
        hashlib.sha1(der).hexdigest(),
        CERT_DAYS,
    )
    return der, pem


def certificate_der(path: Path) -> bytes:
    """A certificate file, DER or PEM, as DER; ValueError when it is neither."""
    data = path.read_bytes()
    if b"-----BEGIN CERTIFICATE-----" in data:
        return x509.load_pem_x509_certificate(data).public_bytes(serialization.Encoding.DER)
    x509.load_der_x509_certificate(data)
    return data


class TrustDirectory:
    """Client certificates: trusted when the same certificate is in ``trusted``."""

    def __init__(self, trusted: Path, on_reject: Callable[[str], None]):
        self.trusted = trusted
        self.rejected = trusted.parent / "rejected"
        self._on_reject = on_reject
        self._secured: dict[bytes, None] = {}  # certificates of secure channels, oldest first

    def trusted_certificates(self) -> set[bytes]:
        out: set[bytes] = set()
        if not self.trusted.is_dir():
            return out
        for path in sorted(self.trusted.iterdir()):
            if path.is_file():
                try:
                    out.add(certificate_der(path))
                except (OSError, ValueError) as exc:
                    log.warning("trusted certificate %s unreadable: %s", path, exc)
        return out

    def check(self, der: bytes) -> None:
        """Raise Bad_CertificateUntrusted (or Bad_CertificateTimeInvalid) unless the client
        certificate ``der`` is valid now and in the trusted directory."""
        cert = x509.load_der_x509_certificate(der)
        now = datetime.datetime.now(datetime.UTC)
        if not cert.not_valid_before_utc <= now <= cert.not_valid_after_utc:
            self._on_reject("certificate_expired")
            raise ua.uaerrors.BadCertificateTimeInvalid()  # type: ignore[no-untyped-call]  # generated, unannotated
        if der in self.trusted_certificates():
            return
        thumb = hashlib.sha1(der).hexdigest()
        try:
            write_atomic(self.rejected / f"{thumb}.der", der)
        except OSError as exc:
            log.warning("cannot keep the rejected certificate in %s: %s", self.rejected, exc)
        log.warning(
            "client certificate %s (SHA-1 %s) is not trusted; to trust it move %s into %s",
            cert.subject.rfc4514_string(),
            thumb,
            self.rejected / f"{thumb}.der",
            self.trusted,
        )
        self._on_reject("certificate_untrusted")
        raise ua.uaerrors.BadCertificateUntrusted()  # type: ignore[no-untyped-call]  # generated, unannotated

    def guard(self, factories: list[Any]) -> None:
        """Note the client certificate of every Sign / SignAndEncrypt secure channel as it
        opens; :meth:`__call__` (at CreateSession) checks only those. A session on a None
        channel is not checked: a client certificate means nothing there (Part 4 §5.6.2)."""
        for factory in factories:
            if factory.mode == ua.MessageSecurityMode.None_:
                continue
            create = factory.create

            def noted(peer_certificate: bytes | None, create: Any = create) -> Any:
                if peer_certificate:
                    self._secured[peer_certificate] = None
                    while len(self._secured) > 256:
                        del self._secured[next(iter(self._secured))]
                return create(peer_certificate)

            factory.create = noted

    async def __call__(self, cert: x509.Certificate, app: ua.ApplicationDescription) -> None:
        """asyncua's certificate validator, called at CreateSession with the client certificate."""
        der = cert.public_bytes(serialization.Encoding.DER)
        if der in self._secured:
            self.check(der)


class Users(UserManager):
    """Name/password check; anonymous sessions only when allowed (loopback without users)."""

    def __init__(
        self, passwords: dict[str, str], anonymous: bool, on_reject: Callable[[str], None]
    ):
        self._passwords = {name: pw.encode() for name, pw in passwords.items()}
        self._anonymous = anonymous
        self._on_reject = on_reject

    def get_user(
        self,
        iserver: Any,
        username: str | None = None,
        password: str | None = None,
        certificate: Any = None,
    ) -> User | None:
        if username is None:
            if self._anonymous:
                return User(role=UserRole.User)
            self._on_reject("anonymous_refused")
            return None
        expected = self._passwords.get(username)
        given = (password or "").encode()
        # compare even for an unknown name, so the time does not tell which names exist
        ok = hmac.compare_digest(
            given, expected if expected is not None else b"\0" * len(given) + b"x"
        )
        if expected is None or not ok:
            self._on_reject("bad_credentials")
            log.warning("OPC UA login refused for user %r: wrong name or password", username)
            return None
        return User(role=UserRole.User, name=username)
