"""Receive paths onto the event loop: a receive thread on the virtual bus, add_reader on a descriptor, a receive thread (with quick answers)."""

from __future__ import annotations

import asyncio
import collections
import socket
import threading
import uuid

import can
import pytest

from fieldgate.can.busrx import start_receiver


def channel() -> str:
    return f"busrx-{uuid.uuid4().hex[:10]}"


def message(n: int) -> can.Message:
    return can.Message(
        arbitration_id=0x600 + (n % 100), data=n.to_bytes(4, "little"), is_extended_id=False
    )


async def collect(receiver_bus, send, count, timeout=5.0):
    loop = asyncio.get_running_loop()
    got, threads, done = [], set(), asyncio.Event()

    def on_message(msg):
        got.append(int.from_bytes(msg.data, "little"))
        threads.add(threading.get_ident())
        if len(got) == count:
            done.set()

    receiver = start_receiver(receiver_bus, loop, on_message)
    sender = threading.Thread(target=send)
    sender.start()
    await asyncio.wait_for(done.wait(), timeout)
    sender.join()
    return receiver, got, threads


async def test_virtual_bus_is_read_by_a_thread_in_order_and_batched_onto_the_loop():
    ch = channel()
    rx = can.Bus(interface="virtual", channel=ch)
    tx = can.Bus(interface="virtual", channel=ch)
    tx.send(message(0))  # received before the receiver starts: still delivered first

    def send():
        for n in range(1, 500):
            tx.send(message(n))

    receiver, got, threads = await collect(rx, send, 500)
    assert receiver.mode == "thread"
    assert got == list(range(500))
    assert threads == {threading.get_ident()}  # handled on the loop's thread
    assert receiver.idle
    receiver.stop()
    rx.shutdown()
    tx.shutdown()


async def test_virtual_bus_keeps_python_cans_filtering_and_its_own_sending():
    """Only public API: set_filters applies (python-can filters in recv), send still works."""
    ch = channel()
    rx = can.Bus(interface="virtual", channel=ch)
    tx = can.Bus(interface="virtual", channel=ch)
    rx.set_filters([{"can_id": 0x605, "can_mask": 0x7FF, "extended": False}])
    loop = asyncio.get_running_loop()
    got, done = [], asyncio.Event()

    def on_message(msg):
        got.append(msg.arbitration_id)
        if msg.data == b"end":
            done.set()

    receiver = start_receiver(rx, loop, on_message)
    for can_id in (0x181, 0x605, 0x7E5, 0x605):
        tx.send(can.Message(arbitration_id=can_id, data=b"x", is_extended_id=False))
    tx.send(can.Message(arbitration_id=0x605, data=b"end", is_extended_id=False))
    await asyncio.wait_for(done.wait(), 5)
    assert got == [0x605, 0x605, 0x605]
    rx.send(message(7))
    assert int.from_bytes(tx.recv(1.0).data, "little") == 7
    receiver.stop()
    rx.shutdown()
    tx.shutdown()


class SocketBus(can.BusABC):
    """A bus with a file descriptor, like SocketCAN: one byte on the socket per message."""

    def __init__(self, fail_next: bool = False, **kw):
        self._rx, self.wire = socket.socketpair()
        self._rx.setblocking(False)
        self.pending = collections.deque()
        self.lock = threading.Lock()
        self.fail_next = fail_next
        super().__init__(channel="fake", **kw)

    def inject(self, msg):
        with self.lock:
            self.pending.append(msg)
        self.wire.send(b"x")

    def fileno(self):
        return self._rx.fileno()

    def _recv_internal(self, timeout):
        if self.fail_next:
            self.fail_next = False
            self._rx.recv(1)
            with self.lock:
                self.pending.popleft()  # that message is lost
            raise can.CanOperationError("socket error")
        try:
            self._rx.recv(1)
        except BlockingIOError:
            return None, False
        with self.lock:
            return self.pending.popleft(), False

    def send(self, msg, timeout=None):
        pass

    def shutdown(self):
        super().shutdown()
        self._rx.close()
        self.wire.close()


async def test_bus_with_a_descriptor_is_read_by_the_loop():
    bus = SocketBus()
    threads_before = threading.active_count()

    def send():
        for n in range(300):
            bus.inject(message(n))

    receiver, got, threads = await collect(bus, send, 300)
    assert receiver.mode == "add-reader"
    assert got == list(range(300)) and threads == {threading.get_ident()}
    assert threading.active_count() == threads_before
    receiver.stop()
    bus.shutdown()


async def test_receive_errors_on_a_descriptor_are_counted_not_raised():
    bus = SocketBus(fail_next=True)

    def send():
        for n in range(3):
            bus.inject(message(n))

    receiver, got, _ = await collect(bus, send, 2)
    assert receiver.errors == 1
    assert got == [1, 2]
    receiver.stop()
    bus.shutdown()


class ThreadOnlyBus(can.BusABC):
    """Neither virtual nor a descriptor: wraps a virtual bus."""

    def __init__(self, ch):
        self.inner = can.Bus(interface="virtual", channel=ch)
        super().__init__(channel=ch)

    def _recv_internal(self, timeout):
        return self.inner.recv(timeout), False

    def send(self, msg, timeout=None):
        self.inner.send(msg)

    def shutdown(self):
        super().shutdown()
        self.inner.shutdown()


async def test_other_buses_use_a_receive_thread_and_hop_to_the_loop():
    ch = channel()
    bus = ThreadOnlyBus(ch)
    tx = can.Bus(interface="virtual", channel=ch)

    def send():
        for n in range(200):
            tx.send(message(n))

    receiver, got, threads = await collect(bus, send, 200)
    assert receiver.mode == "thread"
    assert got == list(range(200)) and threads == {threading.get_ident()}
    receiver.stop()
    bus.shutdown()
    tx.shutdown()


class ErroringSocketBus(can.BusABC):
    """A descriptor that reports a kernel error (EPOLLERR), as SocketCAN does with ENETDOWN when
    its interface goes down: a UDP socket on 127.0.0.1 connected to a port nobody listens on,
    so its first datagram comes back as "connection refused"."""

    def __init__(self, **kw):
        closed = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        closed.bind(("127.0.0.1", 0))
        self.peer_address = closed.getsockname()
        closed.close()
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.connect(self.peer_address)
        self.sock.setblocking(False)
        super().__init__(channel="udp", **kw)

    def fileno(self):
        return self.sock.fileno()

    def _recv_internal(self, timeout):
        try:
            data = self.sock.recv(
                8
            )  # the pending error is raised here once (ConnectionRefusedError)
        except BlockingIOError:
            return None, False
        return can.Message(arbitration_id=0x181, data=data, is_extended_id=False), False

    def send(self, msg, timeout=None):
        pass

    def shutdown(self):
        super().shutdown()
        self.sock.close()


@pytest.mark.parametrize("loop_name", ["asyncio", "uvloop"])
def test_a_descriptor_that_reported_an_error_is_still_heard_afterwards(loop_name):
    """uvloop stops watching a descriptor after an error event; the receiver registers it again."""
    factory = (
        asyncio.new_event_loop
        if loop_name == "asyncio"
        else pytest.importorskip("uvloop").new_event_loop
    )

    async def scenario():
        loop = asyncio.get_running_loop()
        bus = ErroringSocketBus()
        got, heard = [], asyncio.Event()
        receiver = start_receiver(bus, loop, lambda msg: (got.append(bytes(msg.data)), heard.set()))
        assert receiver.mode == "add-reader"
        bus.sock.send(b"lost")  # -> ICMP port unreachable -> an error on our socket
        for _ in range(200):
            if receiver.errors:
                break
            await asyncio.sleep(0.005)
        assert receiver.errors == 1
        peer = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)  # now somebody is there
        peer.bind(bus.peer_address)
        peer.sendto(b"\x05", bus.sock.getsockname())
        try:
            await asyncio.wait_for(heard.wait(), 2.0)
        finally:
            peer.close()
            receiver.stop()
            bus.shutdown()
        assert got == [b"\x05"]

    with asyncio.Runner(loop_factory=factory) as runner:
        runner.run(scenario())


# -- quick answers on the receive thread ----------------------------------------------------


async def test_with_a_quick_answerer_the_virtual_bus_gets_a_receive_thread_that_asks_it_first():
    ch = channel()
    rx = can.Bus(interface="virtual", channel=ch)
    tx = can.Bus(interface="virtual", channel=ch)
    loop = asyncio.get_running_loop()
    quick_threads, answered, on_loop = set(), [], []

    def quick(msg):  # even numbers are answered on the receive thread
        quick_threads.add(threading.get_ident())
        n = int.from_bytes(msg.data, "little")
        if n % 2:
            return False
        answered.append(n)
        return True

    receiver = start_receiver(
        rx, loop, lambda msg: on_loop.append(int.from_bytes(msg.data, "little")), quick
    )
    assert receiver.mode == "thread"
    for n in range(40):
        tx.send(message(n))
        for _ in range(500):  # until the message is through, either way
            if len(answered) + len(on_loop) == n + 1:
                break
            await asyncio.sleep(0.002)
    receiver.stop()
    assert answered == list(range(0, 40, 2)) and on_loop == list(range(1, 40, 2))
    assert quick_threads and threading.get_ident() not in quick_threads
    assert receiver.idle
    rx.shutdown()
    tx.shutdown()


async def test_the_quick_answerer_is_not_asked_while_an_earlier_message_waits_for_the_loop():
    """Answers keep the order of requests: nothing overtakes a message handed to the loop."""
    bus = ThreadOnlyBus(channel())
    loop = asyncio.get_running_loop()
    asked, on_loop = [], []
    receiver = start_receiver(
        bus,
        loop,
        lambda msg: on_loop.append(msg.data[0]),
        lambda msg: asked.append(msg.data[0]) or msg.data[0] != 1,
    )
    try:
        one, two, three = (can.Message(arbitration_id=0x601, data=[n]) for n in (1, 2, 3))
        receiver._from_thread(one)  # declined: handed to the loop, which has not run since
        assert not receiver.idle
        receiver._from_thread(two)  # would be answered quickly, but must wait behind 1
        assert asked == [1] and not receiver.idle
        await asyncio.sleep(0)  # the loop handles 1, then 2
        await asyncio.sleep(0)
        assert on_loop == [1, 2] and receiver.idle
        receiver._from_thread(three)
        assert asked == [1, 3] and on_loop == [1, 2]  # 3 answered on the "receive thread"
    finally:
        receiver.stop()
        bus.shutdown()


async def test_a_bus_with_a_descriptor_keeps_its_reader_even_with_a_quick_answerer():
    bus = ErroringSocketBus()
    receiver = start_receiver(bus, asyncio.get_running_loop(), lambda msg: None, lambda msg: True)
    try:
        assert receiver.mode == "add-reader"
    finally:
        receiver.stop()
        bus.shutdown()


async def test_a_handler_that_raises_on_the_loop_does_not_stop_quick_answers():
    """The loop's handler failing must still count the message as handled, or the receive
    thread would wait for it forever and never answer quickly again."""
    bus = ThreadOnlyBus(channel())
    loop = asyncio.get_running_loop()
    errors = []
    loop.set_exception_handler(lambda loop, context: errors.append(context.get("exception")))
    asked = []

    def on_message(msg):
        raise RuntimeError("handler bug")

    receiver = start_receiver(
        bus, loop, on_message, lambda msg: asked.append(msg.data[0]) or msg.data[0] != 1
    )
    try:
        receiver._from_thread(
            can.Message(arbitration_id=0x601, data=[1])
        )  # declined: to the loop, which raises
        await asyncio.sleep(0)
        assert isinstance(errors[0], RuntimeError) and receiver.idle
        receiver._from_thread(can.Message(arbitration_id=0x601, data=[2]))
        assert asked == [1, 2]  # asked again: the failed message no longer holds the thread back
    finally:
        loop.set_exception_handler(None)
        receiver.stop()
        bus.shutdown()
