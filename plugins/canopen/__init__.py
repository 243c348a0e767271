"""The ``canopen`` front: a CANopen slave serving the process image (docs/canopen.md).

One folder per CiA document, as CANopenNode has them, and the front's glue beside them:

* ``cia301/``: the node and NMT, the object dictionary and its entries, SDO (and extra
  server channels), EMCY, SYNC, TIME, store/restore, error control (guarding, heartbeat),
  ``pdo/`` (engine, TPDO, RPDO, mapping, communication parameters, the node's PDO service);
* ``cia305/``: LSS;
* ``cia401/``: the I/O device binding the generic I/O objects to the process image (its
  object tables, analog events, output batches, layouts, manufacturer objects, their store);
* ``na9161/``: what the CREVIS NA-9161 style adds (FnBus register, slot objects, special bytes);
* the glue: ``plugin.py`` (the front), ``config.py``, ``front401.py`` (the I/O device in
  the front), ``profiles.py`` (styles and master profiles), ``eds.py``, ``master_state.py``,
  ``canhealth.py``, ``locations.py``, ``testing.py`` (the ``canopen_master`` fixture).

Citations such as ``seed-000 §2.5`` or ``seed-004 TV-18`` name a device manual and its own
section or worked example: the key is docs/sources.md.
"""
