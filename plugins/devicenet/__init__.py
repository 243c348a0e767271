"""The ``devicenet`` front: a DeviceNet Group 2 Only slave serving the process image
(docs/devicenet.md). The engine (``engine.py``) composes one module per service; CONTRIBUTING.md
lists them.

Citations such as ``seed-003 §2.7`` name the I-7241D manual and its own section: the key is
docs/sources.md.
"""
