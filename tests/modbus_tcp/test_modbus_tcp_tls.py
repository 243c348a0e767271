"""Modbus/TCP Security: the modbus-tcp front over TLS with client certificates, on loopback.

A test CA signs the server's and one client's certificate (made here with ``cryptography``);
pymodbus's TLS client with that certificate reads and writes; a client without a certificate,
or with one the CA did not sign, gets no answer.
"""

from __future__ import annotations

import asyncio
import contextlib
import datetime
import ipaddress
import ssl
import struct
from pathlib import Path
from typing import Any

import pytest
from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import NameOID
from netkit import free_port
from pymodbus.client import AsyncModbusTlsClient

from fieldgate import Gateway, load_registry
from fieldgate.cli import loop_factory
from fieldgate.testing import in_this_process

# the tests reach into the front's server: it is built in this process (every gateway runs it
# in a child process of its own; tests/faults/test_modbus_tcp_attacks.py goes that way)
REGISTRY = in_this_process(load_registry(), "modbus-tcp")


def issue(
    name: str, ca: tuple[Any, Any] | None, folder: Path, server: bool = False
) -> tuple[Any, Any]:
    key = ec.generate_private_key(ec.SECP256R1())
    subject = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name)])
    now = datetime.datetime.now(datetime.UTC)
    builder = (
        x509.CertificateBuilder()
        .subject_name(subject)
        .issuer_name(ca[0].subject if ca else subject)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=1))
        .not_valid_after(now + datetime.timedelta(days=1))
        .add_extension(x509.BasicConstraints(ca=ca is None, path_length=None), critical=True)
    )
    if server:
        builder = builder.add_extension(
            x509.SubjectAlternativeName([x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]),
            critical=False,
        )
    cert = builder.sign(ca[1] if ca else key, hashes.SHA256())
    (folder / f"{name}.pem").write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    (folder / f"{name}.key").write_bytes(
        key.private_bytes(
            serialization.Encoding.PEM,
            serialization.PrivateFormat.PKCS8,
            serialization.NoEncryption(),
        )
    )
    return cert, key


def client_context(folder: Path, cert: str | None) -> ssl.SSLContext:
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
    ctx.load_verify_locations(folder / "ca.pem")
    if cert is not None:
        ctx.load_cert_chain(folder / f"{cert}.pem", folder / f"{cert}.key")
    return ctx


def tls_topology(tmp_path: Path, port: int, **front: Any) -> dict[str, Any]:
    ca = issue("ca", None, tmp_path)
    issue("server", ca, tmp_path, server=True)
    issue("scada", ca, tmp_path)
    issue("stranger", issue("other-ca", None, tmp_path), tmp_path)
    return {
        "gateway": {"name": "cell"},
        "fronts": [
            {
                "name": "mb",
                "type": "modbus-tcp",
                "listen": f"127.0.0.1:{port}",
                "writable": ["rs485/m4/ao0"],
                "tls": {
                    "cert_file": str(tmp_path / "server.pem"),
                    "key_file": str(tmp_path / "server.key"),
                    "client_ca_file": str(tmp_path / "ca.pem"),
                },
                **front,
            }
        ],
        "backs": [
            {
                "name": "rs485",
                "type": "modbus",
                "port": "/dev/null",
                "baudrate": 115200,
                "poll_ms": 20,
                "modules": [{"address": 4, "model": "M-7024", "counts": {"ao": 1}}],
            }
        ],
    }


async def tls_with_client_certificates(tmp_path: Path) -> None:
    port = free_port()
    gw = Gateway.load(tls_topology(tmp_path, port), registry=REGISTRY, simulate=True)
    await gw.start()
    try:
        client = AsyncModbusTlsClient(
            "127.0.0.1", port=port, sslctx=client_context(tmp_path, "scada"), timeout=2, retries=0
        )
        assert await client.connect()
        assert not (await client.write_register(0, 1234, device_id=1)).isError()
        assert (await client.read_holding_registers(0, count=1, device_id=1)).registers == [1234]
        client.close()
        assert gw.read("rs485/m4/ao0") == 1234
        assert gw.status()["fronts"]["mb"]["endpoint"] == f"modbus+tls://127.0.0.1:{port}"
        for who in (None, "stranger"):  # no certificate; one the plant's CA did not sign
            answered = b""
            try:
                reader, writer = await asyncio.open_connection(
                    "127.0.0.1",
                    port,
                    ssl=client_context(tmp_path, who),
                    server_hostname="127.0.0.1",
                )
                writer.write(struct.pack(">HHHB", 1, 0, 6, 1) + struct.pack(">BHH", 3, 0, 1))
                await writer.drain()
                answered = await asyncio.wait_for(reader.read(100), 3)
                writer.close()
            except (ssl.SSLError, ConnectionError):
                pass
            assert answered == b"", who
        assert gw.read("rs485/m4/ao0") == 1234
    finally:
        await gw.stop()


async def test_tls_with_client_certificates(tmp_path):
    await tls_with_client_certificates(tmp_path)


def test_tls_with_client_certificates_on_uvloop(tmp_path):
    """``fieldgate run``'s loop: its start_tls and buffered protocols."""
    pytest.importorskip("uvloop")
    with asyncio.Runner(loop_factory=loop_factory("uvloop")) as runner:
        runner.run(tls_with_client_certificates(tmp_path))


async def test_a_handshake_not_finished_in_time_is_closed(tmp_path):
    """A TLS client that connects and stays silent is closed after the request timeout
    (asyncio's own default is 60 s), and holds no slot meanwhile."""
    port = free_port()
    topology = tls_topology(tmp_path, port, request_timeout_s=0.5)
    gw = Gateway.load(topology, registry=REGISTRY, simulate=True)
    await gw.start()
    try:
        reader, writer = await asyncio.open_connection("127.0.0.1", port)  # no handshake
        await asyncio.sleep(0.1)
        assert gw.component("mb").connections() == []
        loop = asyncio.get_running_loop()
        started = loop.time()
        async with asyncio.timeout(3):
            assert await reader.read(100) == b""
        assert loop.time() - started < 2.5  # request_timeout_s 0.5; asyncio alone: 60 s
        writer.close()
    finally:
        await gw.stop()


async def test_a_peer_outside_allowed_peers_is_refused_even_with_a_certificate(tmp_path):
    port = free_port()
    topology = tls_topology(tmp_path, port, allowed_peers=["127.0.0.2"])
    gw = Gateway.load(topology, registry=REGISTRY, simulate=True)
    await gw.start()
    try:
        reader, writer = await asyncio.open_connection(
            "127.0.0.1", port, ssl=client_context(tmp_path, "scada"), server_hostname="127.0.0.1"
        )
        writer.write(struct.pack(">HHHB", 1, 0, 6, 1) + struct.pack(">BHH", 3, 0, 1))
        async with asyncio.timeout(3):
            with contextlib.suppress(ConnectionError, ssl.SSLError):
                assert await reader.read(100) == b""
        writer.close()
        assert gw.status()["fronts"]["mb"]["counters"]["refused_peer"] == 1
    finally:
        await gw.stop()
