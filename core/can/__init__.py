"""CAN plumbing shared by every CAN front (CANopen, DeviceNet, third parties).

* :mod:`.frame`: the immutable :class:`~.frame.Frame` engines consume and produce.
* :mod:`.adapter`: :class:`~.adapter.CanAdapter` binds any sans-I/O engine with
  ``boot/receive/tick/flush/next_deadline`` to a python-can bus and the event loop;
  :func:`~.adapter.open_bus` opens any python-can interface with one-line errors.
* :mod:`.busrx`: delivers received frames to the event loop.
"""
