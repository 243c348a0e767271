"""The DeviceNet master of the end-to-end tests: the one the devicenet plugin ships for
integrators' tests too (``fieldgate.plugins.devicenet.testing``, fixture ``devicenet_scanner``)."""

from fieldgate.plugins.devicenet.testing import DeviceNetScanner as Master

__all__ = ["Master"]
