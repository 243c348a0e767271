"""CAN plumbing shared by every CAN front (CANopen, DeviceNet, third parties).

* :mod:`.front`: :class:`~.front.CanFront`, the base of a front on a CAN bus (bus settings
  :class:`~.front.CanBusConfig`, start/run/stop, module health, coalesced wake-ups).
* :mod:`.frame`: the immutable :class:`~.frame.Frame` engines consume and produce.
* :mod:`.adapter`: :class:`~.adapter.CanAdapter` binds any sans-I/O engine with
  ``boot/receive/tick/flush/next_deadline`` to a python-can bus and the event loop (timers,
  sending, acceptance filters); :func:`~.adapter.open_bus` opens any python-can interface
  with one-line errors.
* :mod:`.receive`: what happens to each received frame before the engine (quick answers on
  the receive thread); :mod:`.busrx`: delivers received frames to the event loop.
* :mod:`.controller`: bus-off, the controller's error state, overruns, bit-rate switches.
* :mod:`.filters`, :mod:`.socketcan_raw`, :mod:`.busmetrics`: acceptance filters, the
  SocketCAN fast path, the bus's series for /metrics.
"""
