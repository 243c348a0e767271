"""North-facing parts in child processes: the fieldbus side shares no event loop, interpreter
lock or memory budget with anything that accepts network clients.

A front whose plugin registers it as north-facing (``registry.add_front(..., north=True)``:
OPC UA, Modbus TCP, Sparkplug) and the HTTP status server run each in a child process of
their own (docs/architecture.md, "Process layout"):

* the fieldbus process (CAN fronts, serial backs, the process image, persistence) feeds each
  child a mirror of the gateway: a snapshot when the child starts, then every image batch,
  module health change, master change and event (:mod:`.feed`), encoded once for all
  children; a child that does not keep up loses its queue and gets a fresh snapshot
  (a *resync*), so what it can make the fieldbus process hold is bounded;
* the child runs the front's own code unchanged against that mirror (:mod:`.mirror`,
  :mod:`.child`); a client write comes back as one command (:meth:`GatewayContext.set_outputs`),
  checked against the front's writable outputs, applied by the fieldbus process and only
  then acknowledged;
* the fieldbus process supervises each child (:mod:`.supervisor`): a liveness check over the
  same channel, a memory limit, restart with back-off through the runtime's supervision,
  its state in ``fieldgate status``, /metrics and the live page.

Trust runs one way: the fieldbus process sends pickles (the child trusts its parent), and
reads only size-bounded JSON from a child, checked field by field (:mod:`.wire`).
"""
