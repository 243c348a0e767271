"""The ``canopen-device`` front: any EDS/DCF served on a bus, with Python hooks and
process-image bindings (docs/canopen-device.md).

A front type of its own rather than a mode of ``canopen``: that front's keys (style, PDO
count, packing, error modes, master profiles) describe the CiA 401 I/O devices it builds,
while here the file says all of it; a separate type keeps each configuration's validation
exact (an I/O key on an EDS device is an error, not silently ignored).
"""

from __future__ import annotations

import asyncio
import io
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, cast

import canopen
from canopen import objectdictionary as cod

from fieldgate.can.adapter import CanEngine
from fieldgate.can.front import CanFront
from fieldgate.image import Change, Subscription
from fieldgate.plugin import EdsRequest, GatewayContext

from ..cia301.node import Node
from ..eds import with_file_info
from .config import CanopenDeviceConfig, parse_entry
from .hooks import ThreadRunner, load_setup
from .node import DeviceNode
from .odfile import read_device_file


class DeviceFront(CanFront):
    config: CanopenDeviceConfig

    def __init__(self, config: CanopenDeviceConfig, context: GatewayContext):
        super().__init__(config, context)
        self.device: DeviceNode | None = None
        self._subscription: Subscription | None = None
        self._loop: asyncio.AbstractEventLoop | None = None

    @property
    def node(self) -> Node | None:
        return cast("Node | None", self.engine)

    def build(self) -> Node:
        cfg = self.config
        if self.device is not None:
            self.device.table.runner.close()
        setup = load_setup(cfg.hooks) if cfg.hooks else None
        self.device = device = DeviceNode(
            read_device_file(cfg.eds),
            cfg.node_id,
            name=self.name,
            store_path=self.context.state_file(cfg.store_file, f"{self.name}.canopen.json"),
            lss_store_path=self.context.state_file(cfg.lss_store_file, f"{self.name}.lss.json"),
            lss=cfg.lss,
            bitrate=cfg.bitrate if isinstance(cfg.bitrate, int) else None,
            sdo_timeout_s=cfg.sdo_timeout_ms / 1000.0,
            serial=cfg.serial,
            hook_timeout_s=cfg.hook_timeout_ms / 1000.0,
            runner=ThreadRunner(cfg.hook_workers, self._deliver),
            setup=setup,
            run=self._run,
            clock=time.monotonic,
        )
        node = device.node
        self._bind_outputs(device)
        node.service("store").load()
        return node

    # -- LSS (when the file supports it) --------------------------------------------------------
    def _lss(self, engine: CanEngine) -> Any:
        try:
            return cast(Node, engine).service("lss")
        except KeyError:
            return None

    def start_bitrate(self, engine: CanEngine) -> int | None:
        """The bit rate LSS stored, else the configuration's."""
        lss = self._lss(engine)
        configured = self.config.bitrate
        stored: int | None = lss.bitrate if lss is not None else None
        return stored or (configured if isinstance(configured, int) else None)

    def adapter_options(self, engine: CanEngine) -> dict[str, Any]:
        lss = self._lss(engine)
        return {} if lss is None else {"transmit_allowed": lss.transmit_allowed}

    # -- from other threads onto the loop --------------------------------------------------
    def _deliver(self, action: Callable[[], None]) -> None:
        loop = self._loop
        if loop is not None and not loop.is_closed():
            loop.call_soon_threadsafe(self.pump, action)

    def _run(self, action: Callable[[], None]) -> None:
        """A hook module's call: on the loop's thread at once, from elsewhere through the loop."""
        loop = self._loop
        if loop is None:
            action()
            return
        try:
            running = asyncio.get_running_loop()
        except RuntimeError:
            running = None
        if running is loop:
            self.pump(action)
        else:
            self._deliver(action)

    # -- process image -----------------------------------------------------------------------
    def _bind_outputs(self, device: DeviceNode) -> None:
        image, od = self.context.image, device.node.od
        for key, cid in self.config.bind.items():
            index, sub = parse_entry(key)
            if cid in image and image[cid].is_output:

                def write(i: int, s: int, value: Any, want: int = sub, cid: str = cid) -> None:
                    if s == want:
                        image.write_output(cid, value, origin=self.name)

                od.on_write(index, write)

    def _inputs(self) -> dict[str, tuple[int, int]]:
        image = self.context.image
        return {
            cid: parse_entry(key)
            for key, cid in self.config.bind.items()
            if cid in image and not image[cid].is_output
        }

    def _inputs_changed(self, changes: list[Change]) -> None:
        device, inputs = self.device, self._inputs()
        if device is None:
            return

        def apply() -> None:
            for change in changes:
                value: Any = change.value  # (None: never read yet)
                if value is None:
                    continue
                index, sub = inputs[change.id]
                var = device.node.od.variable(index, sub)
                if var.data_type not in (0x08, 0x11) and not isinstance(value, (str, bytes)):
                    value = int(value)
                try:
                    device.set(index, sub, value)
                except (TypeError, ValueError) as exc:  # a value the entry cannot hold
                    self.log.warning("%s -> %s:%s not taken: %s", change.id, index, sub, exc)

        self.pump(apply)

    def after_start(self, engine: CanEngine, bitrate: int | None) -> None:
        self._loop = asyncio.get_running_loop()
        inputs = self._inputs()
        if inputs and self._subscription is None:
            self._subscription = self.context.image.subscribe_batch(
                self._inputs_changed, ids=list(inputs)
            )
        image = self.context.image
        current = [_Current(cid, image[cid].value) for cid in inputs]
        self._inputs_changed(cast("list[Change]", current))  # the values read before the boot
        node = cast(Node, engine)
        self.log.info(
            "CANopen device %s (%s) node %s on %s/%s",
            self.name,
            Path(self.config.eds).name,
            node.node_id if node.configured else "unconfigured",
            self.config.interface,
            self.config.channel,
        )

    def before_stop(self) -> None:
        if self._subscription is not None:
            self._subscription.cancel()
            self._subscription = None
        if self.device is not None:
            self.device.table.runner.close()

    def status(self) -> dict[str, Any]:
        if self.node is None or self.device is None:
            return {}
        return {
            **self.node.status(),
            "hooks": self.device.table.status(),
            "notes": list(self.device.notes),
            **self.bus_status(),
        }


class _Current:
    """An input's value as it stands (shaped as a :class:`Change` for :meth:`_inputs_changed`)."""

    def __init__(self, cid: str, value: Any):
        self.id, self.value = cid, value


# -- fieldgate eds ------------------------------------------------------------------------
def device_eds_text(front: DeviceFront, node: Node, file_name: str | None = None) -> str:
    """The served dictionary as an EDS: the file's objects with the values they start with
    (a DCF's ParameterValue becomes the DefaultValue), hidden engine objects left out."""
    device = front.device
    assert device is not None
    source = device.device.model
    out = cod.ObjectDictionary()
    out.device_information = source.device_information
    for index in sorted(node.od.model.indices):
        if index not in node.od.hidden:
            out.add_object(node.od.model.indices[index])
    buffer = io.StringIO()
    canopen.export_od(out, buffer, doc_type="eds")
    description = f"fieldgate canopen-device {front.name} from {Path(front.config.eds).name}"
    return with_file_info(buffer.getvalue(), file_name or f"{front.name}.eds", description)


def device_eds_for(request: EdsRequest) -> str:
    from ..eds import EdsError, build_front

    try:
        front, node = build_front(request.topology, request.front, request.registry)
    except (ValueError, OSError) as exc:
        raise EdsError(str(exc)) from None
    return device_eds_text(front, node, request.file_name)
