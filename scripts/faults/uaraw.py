"""A hostile OPC UA client's toolkit: the Connection Protocol (Part 6 §7.1) by hand, no library.

The hostile-client probes (scripts/faults/opcua_attacks.py), their regression tests and the
header fuzzing build HEL messages and chunk headers byte by byte here and read the server's
answer (ACK, ERR with its status code, or the connection closing) with a deadline: what a
scanner or a broken client sends, not what a conforming stack would. The status codes are
Part 6 Table 55 / Part 4 numbers written out here, independent of the server's library.
"""

from __future__ import annotations

import asyncio
import socket
import struct
import time
from dataclasses import dataclass

STATUS = {
    0x807D0000: "Bad_TcpServerTooBusy",
    0x807E0000: "Bad_TcpMessageTypeInvalid",
    0x807F0000: "Bad_TcpSecureChannelUnknown",
    0x80800000: "Bad_TcpMessageTooLarge",
    0x80810000: "Bad_TcpNotEnoughResources",
    0x80820000: "Bad_TcpInternalError",
    0x80830000: "Bad_TcpEndpointUrlInvalid",
    0x800A0000: "Bad_Timeout",
    0x80B80000: "Bad_RequestTooLarge",
    0x80070000: "Bad_DecodingError",
    0x80130000: "Bad_SecurityChecksFailed",
    0x80220000: "Bad_SecureChannelIdInvalid",
    0x80550000: "Bad_SecurityPolicyRejected",
    0x80560000: "Bad_TooManySessions",
}
MIN_BUFFER = 8192


def header(message_type: bytes, chunk_type: bytes, size: int) -> bytes:
    """The 8-byte message header: 3 ASCII letters, the chunk type, the size (UInt32, any value)."""
    return message_type + chunk_type + struct.pack("<I", size & 0xFFFF_FFFF)


def hello(
    url: str = "opc.tcp://127.0.0.1:4840/",
    receive_buffer: int = 65535,
    send_buffer: int = 65535,
    max_message: int = 0,
    max_chunks: int = 0,
    version: int = 0,
    url_length: int | None = None,
) -> bytes:
    """A HEL message; ``url_length`` replaces the EndpointUrl's length field (a lie is allowed)."""
    raw = url.encode()
    length = len(raw) if url_length is None else url_length
    body = struct.pack(
        "<IIIIIi", version, receive_buffer, send_buffer, max_message, max_chunks, length
    )
    body += raw
    return header(b"HEL", b"F", 8 + len(body)) + body


@dataclass
class Answer:
    kind: str  # "ACK", "ERR", "closed" (no message, connection closed), "none" (still open, silent)
    status: int = 0
    reason: str = ""
    seconds: float = 0.0  # from the first byte sent to the answer (or the close)
    sent: int = 0  # bytes the server took before it answered or closed
    ack: tuple[int, int, int, int, int] | None = (
        None  # version, recv, send, max message, max chunks
    )

    @property
    def status_name(self) -> str:
        return STATUS.get(self.status, f"0x{self.status:08X}")

    def __str__(self) -> str:
        if self.kind == "ERR":
            return f"ERR {self.status_name}"
        if self.kind == "ACK" and self.ack is not None:
            return f"ACK (ReceiveBufferSize {self.ack[1]}, SendBufferSize {self.ack[2]})"
        return self.kind


def parse_messages(data: bytes) -> tuple[list[Answer], int]:
    """The complete messages at the start of ``data`` and how many bytes they took."""
    out: list[Answer] = []
    pos = 0
    while len(data) - pos >= 8:
        kind = data[pos : pos + 3].decode("latin-1")
        size = struct.unpack_from("<I", data, pos + 4)[0]
        if size < 8 or len(data) - pos < size:
            break
        if kind == "ACK" and size >= 28:
            out.append(Answer("ACK", ack=struct.unpack_from("<IIIII", data, pos + 8)))
        elif kind == "ERR" and size >= 16:
            status, length = struct.unpack_from("<Ii", data, pos + 8)
            text = data[pos + 16 : pos + 16 + max(length, 0)].decode("utf-8", "replace")
            out.append(Answer("ERR", status=status, reason=text))
        else:
            out.append(Answer(kind))
        pos += size
    return out, pos


async def exchange(
    host: str,
    port: int,
    parts: list[bytes],
    wait: float = 3.0,
    source: str | None = None,
    pace: float = 0.0,
) -> Answer:
    """Send ``parts`` one after the other (stopping once the server answered ERR or closed),
    then wait up to ``wait`` s for an ERR or the close. The answer: "ERR" (with its status),
    "closed" (closed without ERR), "ACK" (acknowledged and still open) or "none"."""
    reader, writer = await open_connection(host, port, source)
    return await exchange_on(reader, writer, parts, wait, pace)


async def exchange_on(
    reader: asyncio.StreamReader,
    writer: asyncio.StreamWriter,
    parts: list[bytes],
    wait: float = 3.0,
    pace: float = 0.0,
) -> Answer:
    """:func:`exchange` on a connection already open (a Hello or a channel done); closes it."""
    started = time.perf_counter()
    got = bytearray()
    seen: list[Answer] = []
    done = asyncio.Event()
    ended: list[float] = []

    async def read() -> None:
        while True:
            try:
                more = await reader.read(65536)
            except (ConnectionError, OSError):
                more = b""
            if not more:
                ended.append(time.perf_counter())
                done.set()
                return
            got.extend(more)
            messages, used = parse_messages(bytes(got))
            del got[:used]
            seen.extend(messages)
            if any(m.kind != "ACK" for m in messages):
                ended.append(time.perf_counter())
                done.set()

    task = asyncio.create_task(read())
    sent = 0
    try:
        for part in parts:
            if done.is_set():
                break
            writer.write(part)
            try:
                async with asyncio.timeout(wait):
                    await writer.drain()
            except (ConnectionError, OSError, TimeoutError):
                break
            sent += len(part)
            if pace:
                await asyncio.sleep(pace)
        try:
            async with asyncio.timeout(wait):
                await done.wait()
        except TimeoutError:
            pass
    finally:
        task.cancel()
        writer.close()
    seconds = (ended[0] if ended else time.perf_counter()) - started
    errors = [m for m in seen if m.kind == "ERR"]
    acks = [m for m in seen if m.kind == "ACK"]
    if errors:
        answer = errors[0]
    elif ended and not [m for m in seen if m.kind not in ("ACK",)]:
        answer = Answer("closed")
    elif seen and seen[-1].kind != "ACK":
        answer = seen[-1]
    else:
        answer = Answer("ACK" if acks else "none")
    answer.ack = acks[0].ack if acks else None
    answer.seconds = seconds
    answer.sent = sent
    return answer


async def open_connection(
    host: str, port: int, source: str | None = None
) -> tuple[asyncio.StreamReader, asyncio.StreamWriter]:
    """A TCP connection, from ``source`` (another 127.0.0.0/8 address: another peer) if given."""
    if source is None:
        return await asyncio.open_connection(host, port)
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.setblocking(False)
    sock.bind((source, 0))
    await asyncio.get_running_loop().sock_connect(sock, (host, port))
    return await asyncio.open_connection(sock=sock)


NONE_POLICY = b"http://opcfoundation.org/UA/SecurityPolicy#None"
OPEN_REQUEST = 446  # OpenSecureChannelRequest_Encoding_DefaultBinary (Part 6 NodeIds.csv)


def _string(raw: bytes | None) -> bytes:
    return struct.pack("<i", -1) if raw is None else struct.pack("<i", len(raw)) + raw


def request_header(handle: int = 1) -> bytes:
    """A RequestHeader: null token, no timestamp, no diagnostics, no audit id, no extra header."""
    return (
        b"\x00\x00"
        + struct.pack("<qII", 0, handle, 0)
        + _string(None)
        + b"\x00\x00\x00\x00\x00\x00\x00"
    )


def open_secure_channel(
    sequence: int = 1, request_id: int = 1, lifetime_ms: int = 600_000
) -> bytes:
    """OPN for SecurityPolicy None, mode None (Part 6 §6.7.4), as bytes."""
    body = struct.pack("<BBH", 0x01, 0, OPEN_REQUEST)  # FourByte NodeId i=446
    body += request_header()
    body += struct.pack("<III", 0, 0, 1) + _string(b"") + struct.pack("<I", lifetime_ms)
    security = _string(NONE_POLICY) + _string(None) + _string(None)
    rest = struct.pack("<I", 0) + security + struct.pack("<II", sequence, request_id) + body
    return header(b"OPN", b"F", 8 + len(rest)) + rest


def secure_chunk(
    channel_id: int, token_id: int, sequence: int, request_id: int, payload: bytes, chunk: bytes
) -> bytes:
    """A MSG chunk on an open channel (security None): headers, then ``payload`` as the body."""
    rest = struct.pack("<IIII", channel_id, token_id, sequence, request_id) + payload
    return header(b"MSG", chunk, 8 + len(rest)) + rest


def parse_open_response(data: bytes) -> tuple[int, int] | None:
    """(SecureChannelId, TokenId) from an OPN response, None when ``data`` is not one."""
    if len(data) < 12 or data[:3] != b"OPN":
        return None
    pos = 12
    for _ in range(3):  # policy URI, sender certificate, receiver thumbprint
        length = struct.unpack_from("<i", data, pos)[0]
        pos += 4 + max(length, 0)
    pos += 8 + 4  # sequence header, the response's type NodeId (FourByte)
    pos += 8 + 4 + 4  # ResponseHeader: Timestamp, RequestHandle, ServiceResult
    mask = data[pos]
    if mask:  # diagnostics are never sent for a good answer; anything else is not understood here
        return None
    pos += 1
    count = struct.unpack_from("<i", data, pos)[0]  # StringTable
    pos += 4
    for _ in range(max(count, 0)):
        pos += 4 + max(struct.unpack_from("<i", data, pos)[0], 0)
    pos += 3 + 4  # AdditionalHeader (null), ServerProtocolVersion
    channel_id, token_id = struct.unpack_from("<II", data, pos)
    return channel_id, token_id


async def open_channel(
    host: str, port: int, source: str | None = None, url: str = "opc.tcp://127.0.0.1/"
) -> tuple[asyncio.StreamReader, asyncio.StreamWriter, int, int]:
    """HEL, ACK, OPN None: an open secure channel (reader, writer, channel id, token id);
    ConnectionError when the server refuses."""
    reader, writer = await open_connection(host, port, source)
    writer.write(hello(url) + open_secure_channel())
    data = b""
    async with asyncio.timeout(5):
        while True:
            more = await reader.read(65536)
            if not more:
                raise ConnectionError("closed before the secure channel opened")
            data += more
            for message in split_messages(data):
                if message[:3] == b"ERR":
                    raise ConnectionError(f"refused: {parse_messages(message)[0][0]}")
                ids = parse_open_response(message)
                if ids is not None:
                    return reader, writer, ids[0], ids[1]


def split_messages(data: bytes) -> list[bytes]:
    """The complete messages at the start of ``data``, each with its header."""
    out = []
    pos = 0
    while len(data) - pos >= 8:
        size = struct.unpack_from("<I", data, pos + 4)[0]
        if size < 8 or len(data) - pos < size:
            break
        out.append(data[pos : pos + size])
        pos += size
    return out
