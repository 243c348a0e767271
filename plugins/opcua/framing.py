"""The OPC UA Connection Protocol's framing (Part 6 §7.1), checked before anything is buffered.

Sans-I/O: :class:`Framer` is fed the bytes of one TCP connection as they arrive and returns
what they make: the client's :class:`Hello` (to acknowledge), complete :class:`Chunk` s (for
the secure channel layer, asyncua's), or one :class:`Refusal`, after which the connection
is answered with an Error message (:meth:`Refusal.encode`) and closed; it takes nothing
more. No library here: the rules, the status codes and the encoding are Part 6's.

What is checked, on the 8-byte header, before the body of a message is waited for:

* the first message is a Hello (``HEL``, chunk type ``F``), else Bad_TcpMessageTypeInvalid;
  of at most 4,128 bytes (its fields and a 4,096-byte EndpointUrl), else
  Bad_TcpEndpointUrlInvalid;
* after it only ``OPN``, ``MSG`` and ``CLO`` arrive (a second Hello, ``ACK``, ``ERR``,
  ``RHE`` or anything else: Bad_TcpMessageTypeInvalid), with chunk type ``F``, ``C`` or ``A``
  (``OPN`` and ``CLO`` in one ``F`` chunk);
* a chunk is no larger than the negotiated receive buffer (Bad_TcpMessageTooLarge) and no
  smaller than its headers (Bad_DecodingError);
* the chunks of one message add up to at most MaxMessageSize and are at most MaxChunkCount
  (Bad_RequestTooLarge): counted from the headers, so a message over the limit is refused
  at the chunk that would exceed it, not after it was received.

The Hello itself (§7.1.2.3): ReceiveBufferSize and SendBufferSize at least 8,192 and a
MaxMessageSize of 0 or at least 8,192, else Bad_TcpNotEnoughResources (the OPC
Foundation's .NET stack refuses out-of-range buffer sizes with it); an EndpointUrl of at
most 4,096 bytes of UTF-8 whose length matches the message, else Bad_TcpEndpointUrlInvalid.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

MIN_BUFFER = 8192  # Part 6 §7.1.2.3: the least ReceiveBufferSize / SendBufferSize
MAX_URL = 4096  # Part 6 §7.1.2.3: the EndpointUrl's longest encoding
HEADER = 8
HELLO_FIELDS = (
    20  # ProtocolVersion, ReceiveBufferSize, SendBufferSize, MaxMessageSize, MaxChunkCount
)
MAX_HELLO = HEADER + HELLO_FIELDS + 4 + MAX_URL
# a chunk's headers: message header + SecureChannelId, the security header at its smallest,
# the sequence header (Part 6 §6.7.2)
MIN_CHUNK = {b"OPN": 12 + 12 + 8, b"MSG": 12 + 4 + 8, b"CLO": 12 + 4 + 8}
SECURE_BODY_OFFSET = 12 + 4 + 8  # what a MSG chunk spends before its body (at least)

BAD_DECODING_ERROR = 0x8007_0000
BAD_TIMEOUT = 0x800A_0000
BAD_TCP_SERVER_TOO_BUSY = 0x807D_0000
BAD_TCP_MESSAGE_TYPE_INVALID = 0x807E_0000
BAD_TCP_MESSAGE_TOO_LARGE = 0x8080_0000
BAD_TCP_NOT_ENOUGH_RESOURCES = 0x8081_0000
BAD_TCP_INTERNAL_ERROR = 0x8082_0000
BAD_TCP_ENDPOINT_URL_INVALID = 0x8083_0000
BAD_REQUEST_TOO_LARGE = 0x80B8_0000
BAD_SECURITY_CHECKS_FAILED = 0x8013_0000
BAD_TOO_MANY_SESSIONS = 0x8056_0000

STATUS_NAMES = {
    BAD_DECODING_ERROR: "Bad_DecodingError",
    BAD_TIMEOUT: "Bad_Timeout",
    BAD_TCP_SERVER_TOO_BUSY: "Bad_TcpServerTooBusy",
    BAD_TCP_MESSAGE_TYPE_INVALID: "Bad_TcpMessageTypeInvalid",
    BAD_TCP_MESSAGE_TOO_LARGE: "Bad_TcpMessageTooLarge",
    BAD_TCP_NOT_ENOUGH_RESOURCES: "Bad_TcpNotEnoughResources",
    BAD_TCP_INTERNAL_ERROR: "Bad_TcpInternalError",
    BAD_TCP_ENDPOINT_URL_INVALID: "Bad_TcpEndpointUrlInvalid",
    BAD_REQUEST_TOO_LARGE: "Bad_RequestTooLarge",
    BAD_SECURITY_CHECKS_FAILED: "Bad_SecurityChecksFailed",
    BAD_TOO_MANY_SESSIONS: "Bad_TooManySessions",
}


@dataclass(frozen=True)
class FramingLimits:
    max_chunk_size: int  # the receive buffer offered (ACK ReceiveBufferSize at most this)
    max_message_size: int  # the sum of a request's chunk bodies
    max_chunk_count: int  # chunks of one request


@dataclass(frozen=True)
class Hello:
    version: int
    receive_buffer: int  # the largest chunk the client can receive
    send_buffer: int  # the largest chunk the client will send
    max_message_size: int
    max_chunk_count: int
    endpoint_url: str | None


@dataclass(frozen=True)
class Acknowledge:
    receive_buffer: int  # the largest chunk the server takes
    send_buffer: int  # the largest chunk the server sends
    max_message_size: int
    max_chunk_count: int

    def encode(self) -> bytes:
        body = struct.pack(
            "<IIIII",
            0,
            self.receive_buffer,
            self.send_buffer,
            self.max_message_size,
            self.max_chunk_count,
        )
        return b"ACKF" + struct.pack("<I", HEADER + len(body)) + body


@dataclass(frozen=True)
class Chunk:
    message_type: bytes  # OPN, MSG or CLO
    chunk_type: bytes  # F, C or A
    data: bytes  # the whole chunk, its header included


@dataclass(frozen=True)
class Refusal:
    status: int
    reason: str  # one line, for the Error message and the log
    counter: str  # the front's counter (``rejected_<counter>``)

    @property
    def status_name(self) -> str:
        return STATUS_NAMES.get(self.status, f"0x{self.status:08X}")

    def encode(self) -> bytes:
        return error_message(self.status, self.reason)


def error_message(status: int, reason: str) -> bytes:
    """An ERR message (Part 6 §7.1.2.5): the status and a reason of at most 4,096 bytes."""
    text = reason.encode("utf-8")[:MAX_URL]
    body = struct.pack("<Ii", status, len(text)) + text
    return b"ERRF" + struct.pack("<I", HEADER + len(body)) + body


def negotiate(hello: Hello, limits: FramingLimits) -> Acknowledge:
    """The Acknowledge for a valid Hello (§7.1.2.4): each buffer no larger than what the client
    asked for the other direction, nor than ours; our own message limits."""
    return Acknowledge(
        receive_buffer=min(hello.send_buffer, limits.max_chunk_size),
        send_buffer=min(hello.receive_buffer, limits.max_chunk_size),
        max_message_size=limits.max_message_size,
        max_chunk_count=limits.max_chunk_count,
    )


def decode_hello(data: bytes) -> Hello | Refusal:
    """A whole HEL message (header included): its fields, or why it is refused."""
    if len(data) < HEADER + HELLO_FIELDS + 4:
        return Refusal(
            BAD_DECODING_ERROR, f"Hello of {len(data)} bytes is too short", "hello_invalid"
        )
    version, receive, send, max_message, max_chunks, url_length = struct.unpack_from(
        "<IIIIIi", data, HEADER
    )
    for name, value in (("ReceiveBufferSize", receive), ("SendBufferSize", send)):
        if value < MIN_BUFFER:
            return Refusal(
                BAD_TCP_NOT_ENOUGH_RESOURCES,
                f"Hello {name} {value} is below {MIN_BUFFER} (Part 6 §7.1.2.3)",
                "hello_invalid",
            )
    if max_message != 0 and max_message < MIN_BUFFER:
        return Refusal(
            BAD_TCP_NOT_ENOUGH_RESOURCES,
            f"Hello MaxMessageSize {max_message} is below {MIN_BUFFER}",
            "hello_invalid",
        )
    rest = len(data) - HEADER - HELLO_FIELDS - 4
    if url_length == -1 and rest == 0:
        url = None
    elif not 0 <= url_length <= MAX_URL:
        return Refusal(
            BAD_TCP_ENDPOINT_URL_INVALID,
            f"Hello EndpointUrl length {url_length} is outside 0..{MAX_URL}",
            "endpoint_url_invalid",
        )
    elif url_length != rest:
        return Refusal(
            BAD_TCP_ENDPOINT_URL_INVALID,
            f"Hello EndpointUrl length {url_length} does not match the {rest} bytes that follow",
            "endpoint_url_invalid",
        )
    else:
        try:
            url = data[HEADER + HELLO_FIELDS + 4 :].decode("utf-8")
        except UnicodeDecodeError:
            return Refusal(
                BAD_TCP_ENDPOINT_URL_INVALID,
                "Hello EndpointUrl is not UTF-8",
                "endpoint_url_invalid",
            )
    return Hello(version, receive, send, max_message, max_chunks, url)


class Framer:
    """One connection's byte stream, cut into checked messages (see the module's text)."""

    def __init__(self, limits: FramingLimits):
        self.limits = limits
        self.receive_buffer = 0  # negotiated: 0 until the Hello was acknowledged
        self.closed = False
        self._buffer = bytearray()
        self._message_size = 0  # the chunk bodies of the message being received
        self._message_chunks = 0

    @property
    def buffered(self) -> int:
        return len(self._buffer)

    @property
    def hello_done(self) -> bool:
        return self.receive_buffer > 0

    def acknowledge(self, hello: Hello) -> Acknowledge:
        ack = negotiate(hello, self.limits)
        self.receive_buffer = ack.receive_buffer
        return ack

    def feed(self, data: bytes) -> list[Hello | Chunk | Refusal]:
        """What ``data`` completes; a :class:`Refusal` is always the last item, and after it
        the framer takes nothing more. A Hello must be :meth:`acknowledge` d before the next
        feed (the chunks after it are checked against the negotiated buffer)."""
        out: list[Hello | Chunk | Refusal] = []
        if self.closed:
            return out
        buffer = self._buffer
        buffer += data
        pos = 0
        while len(buffer) - pos >= HEADER:
            message_type = bytes(buffer[pos : pos + 3])
            chunk_type = bytes(buffer[pos + 3 : pos + 4])
            size = int.from_bytes(buffer[pos + 4 : pos + 8], "little")
            refusal = self._check(message_type, chunk_type, size)
            if refusal is not None:
                out.append(refusal)
                break
            if len(buffer) - pos < size:
                break
            whole = bytes(buffer[pos : pos + size])
            pos += size
            if message_type == b"HEL":
                hello = decode_hello(whole)
                out.append(hello)
                break  # what follows a Hello waits for its acknowledgement (feed again)
            if message_type == b"MSG":
                self._count(chunk_type, size)
            out.append(Chunk(message_type, chunk_type, whole))
        if out and isinstance(out[-1], Refusal):
            self.closed = True
            buffer.clear()
        else:
            del buffer[:pos]
        return out

    def _count(self, chunk_type: bytes, size: int) -> None:
        if chunk_type == b"C":
            self._message_size += size - SECURE_BODY_OFFSET
            self._message_chunks += 1
        else:  # F ends the message, A abandons it
            self._message_size = self._message_chunks = 0

    def _check(self, message_type: bytes, chunk_type: bytes, size: int) -> Refusal | None:
        """Why a message with this header is refused (None: it may come), before its body."""
        if not self.hello_done:
            if message_type != b"HEL":
                return Refusal(
                    BAD_TCP_MESSAGE_TYPE_INVALID,
                    f"the first message must be a Hello, not {_shown(message_type)}",
                    "not_hello_first",
                )
            if chunk_type != b"F":
                return Refusal(
                    BAD_TCP_MESSAGE_TYPE_INVALID,
                    f"a Hello has chunk type F, not {_shown(chunk_type)}",
                    "message_type_invalid",
                )
            if size > MAX_HELLO:  # only the EndpointUrl can make it longer
                return Refusal(
                    BAD_TCP_ENDPOINT_URL_INVALID,
                    f"a Hello of {size} bytes: its EndpointUrl would be over {MAX_URL} bytes",
                    "endpoint_url_invalid",
                )
            if size < HEADER:
                return Refusal(BAD_DECODING_ERROR, f"a message size of {size}", "decoding_error")
            return None
        minimum = MIN_CHUNK.get(message_type)
        if minimum is None:
            return Refusal(
                BAD_TCP_MESSAGE_TYPE_INVALID,
                f"message type {_shown(message_type)} after the Hello",
                "message_type_invalid",
            )
        if chunk_type not in (b"F", b"C", b"A") or (message_type != b"MSG" and chunk_type != b"F"):
            return Refusal(
                BAD_TCP_MESSAGE_TYPE_INVALID,
                f"chunk type {_shown(chunk_type)} on {_shown(message_type)}",
                "message_type_invalid",
            )
        if size > self.receive_buffer:
            return Refusal(
                BAD_TCP_MESSAGE_TOO_LARGE,
                f"a chunk of {size} bytes (the negotiated receive buffer is {self.receive_buffer})",
                "chunk_too_large",
            )
        if size < minimum:
            return Refusal(
                BAD_DECODING_ERROR,
                f"a {_shown(message_type)} chunk of {size} bytes cannot hold its headers",
                "decoding_error",
            )
        if message_type == b"MSG":
            if self._message_size + size - SECURE_BODY_OFFSET > self.limits.max_message_size:
                return Refusal(
                    BAD_REQUEST_TOO_LARGE,
                    f"a request over MaxMessageSize {self.limits.max_message_size}",
                    "message_too_large",
                )
            if self._message_chunks + 1 > self.limits.max_chunk_count:
                return Refusal(
                    BAD_REQUEST_TOO_LARGE,
                    f"a request in more than MaxChunkCount {self.limits.max_chunk_count} chunks",
                    "too_many_chunks",
                )
        return None


def _shown(raw: bytes) -> str:
    """Bytes off the wire for a log line: printable ASCII as is, the rest escaped."""
    return repr(raw.decode("latin-1"))
