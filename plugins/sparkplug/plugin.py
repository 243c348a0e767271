"""The ``sparkplug`` plugin's registration.

The front (:mod:`.front`) needs paho-mqtt and protobuf: it is imported in the front's own
child process (a north-facing front: docs/architecture.md, "Process layout"), never by the
fieldbus process, `validate` or `plugins` that load the plugins. Both are the extra
``fieldgate[sparkplug]``: without it a topology with a sparkplug front fails validation in
one line naming that install command.
"""

from __future__ import annotations

from typing import Any

from fieldgate.plugin import Front, GatewayContext, hookimpl

from .config import SparkplugFrontConfig


def make_front(config: SparkplugFrontConfig, context: GatewayContext) -> Front:
    from .front import SparkplugFront

    return SparkplugFront(config, context)


@hookimpl
def fieldgate_register(registry: Any) -> None:
    registry.add_front(
        "sparkplug",
        SparkplugFrontConfig,
        make_front,
        "MQTT Sparkplug B edge node with store-and-forward",
        north=True,
        needs=("paho.mqtt", "google.protobuf"),  # the extra fieldgate[sparkplug]
        install="pip install 'fieldgate[sparkplug]'",
    )
