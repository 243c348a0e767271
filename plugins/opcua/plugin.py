"""The ``opcua`` plugin's registration.

The front (:mod:`.front`) needs asyncua, which with cryptography is about 200 modules and
0.4 s to import: it is imported when a topology has an opcua front, not by every gateway,
`validate` or `plugins` that loads the plugins (in the SocketCAN guest, where each module
is read over hostfs, that is seconds of every `fieldgate run` start). asyncua is the extra
``fieldgate[opcua]``: without it a topology with an opcua front fails validation in one
line naming that install command.
"""

from __future__ import annotations

from typing import Any

from fieldgate.plugin import Front, GatewayContext, hookimpl

from .config import OpcUaFrontConfig


def make_front(config: OpcUaFrontConfig, context: GatewayContext) -> Front:
    from .front import OpcUaFront

    return OpcUaFront(config, context)


@hookimpl
def fieldgate_register(registry: Any) -> None:
    registry.add_front(
        "opcua",
        OpcUaFrontConfig,
        make_front,
        "OPC UA server on the process image (asyncua)",
        north=True,
        needs=("asyncua",),  # the extra fieldgate[opcua] (with cryptography)
        install="pip install 'fieldgate[opcua]'",
    )
