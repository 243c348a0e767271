"""MQTT Sparkplug B edge-node front with store-and-forward (docs/sparkplug.md)."""
