"""asyncua's server as the ``opcua`` front's configuration sets it up, before it starts:
the client guard (framing and admission limits), the limits on sessions and subscriptions,
the endpoint, security policies and identity tokens, the certificate and trusted clients.

The front (:mod:`.front`) then builds the address space (:mod:`.nodes`) and starts it.
"""

from __future__ import annotations

import logging
import socket
from collections import Counter
from collections.abc import Callable
from pathlib import Path

from asyncua import Server, ua

from fieldgate.plugin import PluginStartError

from .admission import AdmissionLimits
from .config import OpcUaFrontConfig
from .framing import FramingLimits
from .security import TrustDirectory, certificate_der, ensure_certificate
from .subscriptions import GuardedSubscriptions, SubscriptionLimits
from .transport import Guard, GuardedServer

POLICY = {
    "None": ua.SecurityPolicyType.NoSecurity,
    "Sign": ua.SecurityPolicyType.Basic256Sha256_Sign,
    "SignAndEncrypt": ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt,
}


def new_guard(cfg: OpcUaFrontConfig, log: logging.Logger, rejected: Counter[str]) -> Guard:
    """What a client can make the server hold, checked before anything is buffered."""
    return Guard(
        FramingLimits(cfg.max_chunk_size, cfg.max_message_size, cfg.max_chunk_count),
        AdmissionLimits(
            cfg.max_connections,
            cfg.max_connections_per_peer,
            cfg.max_sessions,
            cfg.max_sessions_per_peer,
            cfg.hello_timeout_s,
            cfg.activation_timeout_s,
        ),
        log,
        cfg.anonymous_allowed,
        rejected,
    )


def limit(
    server: GuardedServer, cfg: OpcUaFrontConfig, on_event: Callable[[str, int], None]
) -> GuardedSubscriptions:
    """The configuration's limits on asyncua's internal server (before it is started)."""
    iserver = server.iserver
    iserver.max_session_timeout_ms = cfg.max_session_timeout_ms
    iserver.max_monitored_item_queue_size = cfg.max_queue_size
    iserver.max_unacked_messages_per_subscription = cfg.max_retransmission_queue
    iserver.max_subscriptions = cfg.max_sessions * cfg.max_subscriptions_per_session
    subscriptions = GuardedSubscriptions(
        iserver.aspace,
        iserver,
        SubscriptionLimits(
            cfg.min_publishing_interval_ms,
            cfg.min_sampling_interval_ms,
            cfg.max_subscriptions_per_session,
            cfg.max_monitored_items_per_subscription,
            cfg.max_monitored_items_per_session,
            cfg.max_queue_size,
        ),
        on_event,
    )
    iserver.subscription_service = subscriptions
    iserver.isession.subscription_service = subscriptions
    return subscriptions


async def set_endpoint(server: Server, cfg: OpcUaFrontConfig, name: str, app_uri: str) -> str:
    """Endpoint URL, server name, application URI, security policies and identity tokens;
    returns the URL (on every interface: the host's name, the server bound to all)."""
    host, port = cfg.host_port
    host_text = f"[{host}]" if ":" in host else host
    url = f"opc.tcp://{host_text}:{port}/"
    if host in ("0.0.0.0", "::"):
        url = f"opc.tcp://{socket.gethostname()}:{port}/"
        server.socket_address = (host, port)
    server.set_endpoint(url)
    server.set_server_name(name)
    await server.set_application_uri(app_uri)
    server.set_security_policy([POLICY[m] for m in cfg.security])
    tokens: list[type] = []
    if cfg.anonymous_allowed:
        tokens.append(ua.AnonymousIdentityToken)
    if cfg.users:
        tokens.append(ua.UserNameIdentityToken)
    server.set_identity_tokens(tokens)
    return url


async def load_security(
    server: Server,
    cfg: OpcUaFrontConfig,
    *,
    front: str,
    gateway: str,
    app_uri: str,
    state: Path,
    base_dir: Path,
    reject: Callable[[str], None],
) -> TrustDirectory:
    """The server certificate (the configured one, or one generated into ``state``) and
    the trusted clients' directory, which validates client certificates from now on."""
    try:
        if cfg.certificate_file is not None and cfg.private_key_file is not None:
            cert_path = resolve(base_dir, cfg.certificate_file)
            key_path = resolve(base_dir, cfg.private_key_file)
            cert, key = certificate_der(cert_path), key_path.read_bytes()
        else:
            cert, key = ensure_certificate(
                state / f"{front}.opcua-cert.der",
                state / f"{front}.opcua-key.pem",
                app_uri,
                f"fieldgate {gateway}",
            )
        await server.load_certificate(cert, format="DER")
        await server.load_private_key(key, format="PEM")
    except (OSError, ValueError) as exc:
        raise PluginStartError(f"server certificate: {exc}") from None
    trusted = (
        resolve(base_dir, cfg.trusted_clients_dir)
        if cfg.trusted_clients_dir is not None
        else state / f"{front}.opcua-pki" / "trusted"
    )
    trusted.mkdir(parents=True, exist_ok=True)
    trust = TrustDirectory(trusted, reject)
    server.set_certificate_validator(trust)
    return trust


def resolve(base: Path, name: str) -> Path:
    path = Path(name)
    return path if path.is_absolute() else base / path
