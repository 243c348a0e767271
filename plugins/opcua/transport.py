"""asyncua's server with the front's guard on every connection (issue 29: D2, D4, D7, D8, D9).

asyncua 2.1 buffers whatever a client sends before it looks at it (``data_received``
appends to one bytes object, re-copied as it grows: 128 MB of a 0x7FFFFFFF chunk were
held), acknowledges any Hello, lets an exception from a malformed Hello escape with a
traceback and the connection left open, and refuses new connections once
``max_connections`` are open, however silent they are. Here, by subclassing (never by
editing the library):

* :class:`GuardedProtocol` feeds each connection's bytes to :class:`~.framing.Framer`
  (checks on each header before its body is waited for), answers the Hello itself, hands
  only checked chunks to asyncua's secure-channel layer, holds at most one chunk plus what
  asyncua has not processed yet (reading pauses beyond a budget), and answers any refusal
  with the Error message and a close; a client fault that asyncua's layer raises
  (undecodable request, wrong channel or token) gets the same, in one log line;
* :class:`Guard` is the server's :class:`~.admission.Admission` (per-peer and total budgets,
  Hello and activation timeouts, session eviction), its refusal counters and its
  rate-limited log lines;
* :class:`GuardedProcessor` checks a session's identity token against what the endpoint
  offers before asyncua does (so an anonymous or unsupported token is counted and answered
  Bad_IdentityTokenRejected in one line), admits a new session against the session budget
  (a second CreateSession on one connection closes the first: asyncua would leak it), counts
  every ServiceFault by status, and tells the client the real MaxRequestMessageSize.
"""

from __future__ import annotations

import asyncio
import logging
import socket
import time
from collections import Counter
from typing import Any, cast

from asyncua import Server, ua
from asyncua.common.connection import TransportLimits
from asyncua.common.utils import Buffer
from asyncua.crypto import uacrypto
from asyncua.server.binary_server_asyncio import BinaryServer, OPCUAProtocol
from asyncua.server.internal_session import SessionState
from asyncua.server.uaprocessor import UaProcessor
from asyncua.ua.ua_binary import header_from_binary, nodeid_from_binary, struct_from_binary

from fieldgate.plugin import one_line

from . import framing
from .admission import Admission, AdmissionLimits
from .framing import Chunk, Framer, FramingLimits, Hello, Refusal
from .logs import LogBudget

_log = logging.getLogger("asyncua.server.binary_server_asyncio")

CREATE_SESSION = ua.NodeId(ua.Int32(ua.ObjectIds.CreateSessionRequest_Encoding_DefaultBinary))
ACTIVATE_SESSION = ua.NodeId(ua.Int32(ua.ObjectIds.ActivateSessionRequest_Encoding_DefaultBinary))
SWEEP_S = 0.25
LINGER_S = 0.5  # after an Error message, before the socket closes


def peer_of(peername: Any) -> str:
    return str(peername[0]) if isinstance(peername, tuple) else str(peername)


def refusal_of(exc: BaseException) -> Refusal:
    """A client fault raised by asyncua's secure-channel layer, as the Error to answer."""
    text = one_line(exc)
    if isinstance(exc, ua.UaStatusCodeError):
        return Refusal(exc.code, text, "secure_channel_fault")
    if isinstance(exc, (ua.UaError, uacrypto.InvalidSignature)):
        return Refusal(framing.BAD_SECURITY_CHECKS_FAILED, text, "secure_channel_fault")
    return Refusal(framing.BAD_DECODING_ERROR, text, "decoding_error")


class Guard:
    """The budgets, counters and log lines of one server (see the module's text)."""

    def __init__(
        self,
        framing_limits: FramingLimits,
        admission_limits: AdmissionLimits,
        log: logging.Logger,
        anonymous_allowed: bool,
        rejected: Counter[str] | None = None,
    ):
        self.framing = framing_limits
        self.admission = Admission(admission_limits)
        self.log = log
        self.anonymous_allowed = anonymous_allowed
        # refusals and evictions, by reason (the front's counter: users and certificates too)
        self.rejected: Counter[str] = rejected if rejected is not None else Counter()
        self.faults: Counter[str] = Counter()  # ServiceFaults answered, by status name
        self.budget = LogBudget()
        self.protocols: dict[GuardedProtocol, None] = {}
        self.owners: dict[Any, GuardedProtocol | None] = {}  # session -> its connection
        self._sweeper: asyncio.Task[None] | None = None

    # -- log lines ----------------------------------------------------------------------
    def note(
        self, reason: str, peer: str, text: str, level: int = logging.WARNING, n: int = 1
    ) -> None:
        """Count a refusal and log it in one line (a few a minute per reason at most)."""
        self.rejected[reason] += n
        ok, held = self.budget.admit(reason)
        if ok and self.log.isEnabledFor(level):
            extra = f" ({held} more since the last line)" if held else ""
            self.log.log(level, "OPC UA client %s: %s%s", peer, text, extra)

    # -- connections --------------------------------------------------------------------
    def opened(self, protocol: GuardedProtocol) -> None:
        self.protocols[protocol] = None
        for key, reason in self.admission.open(protocol, protocol.peer, time.monotonic()):
            assert isinstance(key, GuardedProtocol)
            text = (
                "refused: every connection is in use"
                if key is protocol
                else f"connection closed to make room (over {self._limit_text()})"
            )
            key.refuse(Refusal(framing.BAD_TCP_SERVER_TOO_BUSY, text, reason), logging.INFO)

    def _limit_text(self) -> str:
        limits = self.admission.limits
        return (
            f"{limits.max_connections_per_peer} connections per address or "
            f"{limits.max_connections} in all"
        )

    def closed(self, protocol: GuardedProtocol) -> None:
        self.protocols.pop(protocol, None)
        self.admission.closed(protocol)
        for session, owner in list(self.owners.items()):
            if owner is protocol:
                self.owners[session] = None

    def start(self) -> None:
        if self._sweeper is None:
            self._sweeper = asyncio.get_running_loop().create_task(self._sweep())

    async def stop(self) -> None:
        if self._sweeper is not None:
            self._sweeper.cancel()
            await asyncio.gather(self._sweeper, return_exceptions=True)
            self._sweeper = None

    async def _sweep(self) -> None:
        limits = self.admission.limits
        while True:
            await asyncio.sleep(SWEEP_S)
            for key, reason in self.admission.expired(time.monotonic()):
                assert isinstance(key, GuardedProtocol)
                seconds = (
                    limits.hello_timeout if reason == "hello_timeout" else limits.activation_timeout
                )
                what = "no Hello" if reason == "hello_timeout" else "no activated session"
                key.refuse(
                    Refusal(framing.BAD_TIMEOUT, f"{what} within {seconds:g} s", reason),
                    logging.INFO,
                )

    # -- sessions -----------------------------------------------------------------------
    async def admit_session(self, processor: GuardedProcessor) -> bool:
        """Room for a new session from ``processor``'s peer: evict what must give way;
        False when nothing could (the caller answers Bad_TooManySessions)."""
        iserver = processor.iserver
        alive = [s for s in iserver._external_sessions.values() if s.state != SessionState.Closed]
        for session in list(self.owners):
            if session not in alive:
                del self.owners[session]
        self.admission.keep_sessions(alive)
        for session in alive:
            owner = self.owners.get(session)
            self.admission.session_state(
                session,
                session.state == SessionState.Activated,
                owner is not None and not owner.closing,
                session._last_activity,
            )
        token = object()
        victims = self.admission.session(token, processor.protocol.peer, time.monotonic())
        refused = False
        for key, reason in victims:
            if key is token:
                refused = True
                self.note(
                    reason, processor.protocol.peer, "session refused: every session is in use"
                )
                continue
            owner = self.owners.pop(key, None)
            self.admission.session_closed(key)
            self.note(
                reason, processor.protocol.peer, "an idle session closed to make room", logging.INFO
            )
            await cast(Any, key).close_session(True)  # an InternalSession
            if owner is not None:
                owner.refuse(
                    Refusal(framing.BAD_TCP_SERVER_TOO_BUSY, "session closed to make room", reason),
                    logging.DEBUG,
                    count=False,
                )
        self.admission.session_closed(token)
        return not refused

    def session_attached(self, session: Any, protocol: GuardedProtocol) -> None:
        if self.owners.get(session) is not protocol:
            self.owners[session] = protocol
            if session not in self.admission.sessions:
                self.admission.register_session(session, protocol.peer, time.monotonic())

    def session_created(self, session: Any, protocol: GuardedProtocol) -> None:
        self.owners[session] = protocol
        self.admission.register_session(session, protocol.peer, time.monotonic())


class GuardedProtocol(OPCUAProtocol):
    """One client connection (see the module's text)."""

    def __init__(self, guard: Guard, **kwargs: Any):
        super().__init__(**kwargs)
        self.guard = guard
        self.framer = Framer(guard.framing)
        self.peer = "?"
        self.closing = False
        self._queued = 0  # bytes of chunks given to asyncua and not processed yet
        self._paused = False

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        # (uvloop's transports are not asyncio.Transport subclasses: duck typing only)
        transport = cast(asyncio.Transport, transport)
        self.peer_name = transport.get_extra_info("peername")
        self.peer = peer_of(self.peer_name)
        self.transport = transport
        processor = GuardedProcessor(self.iserver, transport, self.limits, self.guard, self)
        processor.set_policies(self.policies)  # type: ignore[no-untyped-call]  # asyncua's, unannotated
        self.processor = processor
        self.iserver.asyncio_transports.append(transport)
        self.clients.append(self)
        self._task = asyncio.get_running_loop().create_task(self._process_received_message_loop())
        self.guard.opened(self)

    def connection_lost(self, ex: BaseException | None) -> None:
        self.closing = True
        self.guard.closed(self)
        super().connection_lost(ex)

    def refuse(self, refusal: Refusal, level: int = logging.WARNING, count: bool = True) -> None:
        """Answer the Error message, close, count and log (once per connection)."""
        if self.closing:
            return
        self.closing = True
        if count:
            self.guard.note(
                refusal.counter, self.peer, f"{refusal.status_name}: {refusal.reason}", level
            )
        transport = self.transport
        if transport is None:
            return
        try:
            transport.write(refusal.encode())
            if transport.can_write_eof():
                # the Error and then the end of the stream; reading stops (nothing more is
                # taken) and the socket closes a moment later: closing at once with the
                # client's bytes unread would reset the connection, and the client would
                # never see why
                transport.write_eof()
                transport.pause_reading()
                asyncio.get_running_loop().call_later(LINGER_S, transport.close)
                return
        except Exception:  # noqa: BLE001  (already going away)
            pass
        transport.close()

    def data_received(self, data: bytes) -> None:
        if self.closing:
            return
        self.guard.admission.message(self, time.monotonic())
        events = self.framer.feed(data)
        while events:
            again: list[Hello | Chunk | Refusal] = []
            for event in events:
                if isinstance(event, Refusal):
                    self.refuse(event)
                    return
                if isinstance(event, Hello):
                    self._acknowledge(event)
                    again = self.framer.feed(b"")
                    break
                if not self._enqueue(event):
                    return
            events = again

    def _acknowledge(self, hello: Hello) -> None:
        ack = self.framer.acknowledge(hello)
        assert self.processor is not None
        limits = self.processor._limits
        limits.max_recv_buffer = ack.receive_buffer
        limits.max_send_buffer = ack.send_buffer
        limits.max_message_size = ack.max_message_size
        limits.max_chunk_count = ack.max_chunk_count
        assert self.transport is not None
        self.transport.write(ack.encode())
        self.guard.admission.hello(self)

    def _enqueue(self, chunk: Chunk) -> bool:
        buf = Buffer(chunk.data)
        header = header_from_binary(buf)
        try:
            self.messages.put_nowait((header, buf))
        except asyncio.QueueFull:
            self.refuse(
                Refusal(
                    framing.BAD_TCP_SERVER_TOO_BUSY,
                    f"more than {self.messages.maxsize} requests waiting",
                    "too_many_requests_queued",
                )
            )
            return False
        self._queued += len(chunk.data)
        if not self._paused and self._queued > 2 * self.guard.framing.max_message_size:
            self._paused = True
            assert self.transport is not None
            self.transport.pause_reading()
        return True

    async def _process_received_message_loop(self) -> None:
        while True:
            header, buf = await self.messages.get()
            if (header is None and buf is None) or self.closing:
                break
            self._queued -= header.packet_size
            if self._paused and self._queued <= self.guard.framing.max_message_size:
                self._paused = False
                if self.transport is not None and not self.closing:
                    self.transport.resume_reading()
            try:
                if not await self._process_one_msg(header, buf):
                    break
            except Exception as exc:  # noqa: BLE001  (a client's bad input: answer, close)
                self.refuse(refusal_of(exc))
                break


class GuardedProcessor(UaProcessor):
    """asyncua's request processing for one connection, with the guard's session rules."""

    def __init__(
        self,
        iserver: Any,
        transport: Any,
        limits: TransportLimits,
        guard: Guard,
        protocol: GuardedProtocol,
    ):
        super().__init__(iserver, transport, limits)
        self.guard = guard
        self.protocol = protocol

    def send_response(
        self,
        requesthandle: Any,
        seqhdr: Any,
        response: Any,
        msgtype: bytes = ua.MessageType.SecureMessage,
    ) -> None:
        if self.protocol.closing:  # refused meanwhile: the Error message was the last word
            return
        if isinstance(response, ua.ServiceFault):
            self.guard.faults[response.ResponseHeader.ServiceResult.name] += 1
        elif isinstance(response, ua.CreateSessionResponse):
            response.Parameters.MaxRequestMessageSize = self.guard.framing.max_message_size
        super().send_response(requesthandle, seqhdr, response, msgtype)  # type: ignore[no-untyped-call]

    def _fault(self, seqhdr: Any, body: Buffer, code: int) -> bool:
        data = body.copy()
        nodeid_from_binary(data)
        header = struct_from_binary(ua.RequestHeader, data)
        response = ua.ServiceFault()
        response.ResponseHeader.ServiceResult = ua.StatusCode(ua.UInt32(code))
        self.send_response(header.RequestHandle, seqhdr, response)
        return True

    async def process_message(self, seqhdr: Any, body: Buffer) -> bool:
        typeid = nodeid_from_binary(body.copy())
        if typeid == CREATE_SESSION:
            if self.session is not None and self.session.state != SessionState.Closed:
                await self.session.close_session(True)  # one session per connection
                self.session = None
            if not await self.guard.admit_session(self):
                return self._fault(seqhdr, body, ua.StatusCodes.BadTooManySessions)
            result = await super().process_message(seqhdr, body)  # type: ignore[no-untyped-call]
            if self.session is not None:
                self.guard.session_created(self.session, self.protocol)
            return bool(result)
        if typeid == ACTIVATE_SESSION:
            refused = self._identity_refused(body)
            if refused is not None:
                reason, text = refused
                self.guard.note(reason, self.protocol.peer, text)
                return self._fault(seqhdr, body, ua.StatusCodes.BadIdentityTokenRejected)
            result = await super().process_message(seqhdr, body)  # type: ignore[no-untyped-call]
            if self.session is not None and self.session.is_activated():
                self.guard.admission.activated(self.protocol)
                self.guard.session_attached(self.session, self.protocol)  # (a reconnect too)
            return bool(result)
        return bool(await super().process_message(seqhdr, body))  # type: ignore[no-untyped-call]

    def _identity_refused(self, body: Buffer) -> tuple[str, str] | None:
        """(counter, text) when the ActivateSession's identity token is not one the endpoint
        offers; None otherwise (or when it does not decode: asyncua answers that)."""
        data = body.copy()
        try:
            nodeid_from_binary(data)
            struct_from_binary(ua.RequestHeader, data)
            params = struct_from_binary(ua.ActivateSessionParameters, data)
        except Exception:  # noqa: BLE001
            return None
        token = params.UserIdentityToken
        anonymous = isinstance(token, ua.AnonymousIdentityToken) or (
            isinstance(token, ua.ExtensionObject)
            and token.TypeId == ua.NodeId(ua.Int32(ua.ObjectIds.Null))
        )
        if anonymous:
            if self.guard.anonymous_allowed:
                return None
            return "anonymous_refused", "anonymous session refused (the endpoint needs a user)"
        if not isinstance(token, self.iserver.supported_tokens):
            kind = type(token).__name__
            return "identity_token_rejected", f"identity token {kind} is not offered here"
        return None


class GuardedBinaryServer(BinaryServer):
    def __init__(self, guard: Guard, *args: Any, **kwargs: Any):
        super().__init__(*args, **kwargs)
        self.guard = guard

    def _make_protocol(self) -> GuardedProtocol:
        return GuardedProtocol(
            self.guard,
            iserver=self.iserver,
            policies=self._policies,
            clients=self.clients,
            closing_tasks=self.closing_tasks,
            limits=self.limits,
        )

    async def start(self) -> None:
        await super().start()
        self.guard.start()

    async def stop(self) -> None:
        await self.guard.stop()
        await super().stop()


class GuardedServer(Server):
    """asyncua's Server listening through :class:`GuardedBinaryServer`."""

    def __init__(self, guard: Guard, **kwargs: Any):
        super().__init__(**kwargs)
        self.guard = guard
        buffer = guard.framing.max_chunk_size
        self.limits = TransportLimits(
            max_recv_buffer=buffer,
            max_send_buffer=buffer,
            max_chunk_count=guard.framing.max_chunk_count,
            max_message_size=guard.framing.max_message_size,
        )
        iserver = self.iserver
        iserver.max_pending_activation_seconds = 0  # the guard's activation timeout instead
        iserver.max_connections = 1 << 30  # the guard admits connections

    async def start(self) -> None:  # asyncua's, with the guarded listener
        if self.iserver.certificate is not None:
            uacrypto.check_certificate(
                self.iserver.certificate, self._application_uri, socket.gethostname()
            )
        await self._setup_server_nodes()
        await self.iserver.start()
        try:
            host, port = self._get_bind_socket_info()
            self.bserver = GuardedBinaryServer(self.guard, self.iserver, host, port, self.limits)
            self.bserver.set_policies(self._policies)
            await self.bserver.start()
        except Exception:
            await self.iserver.stop()
            raise
