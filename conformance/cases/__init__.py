"""The conformance cases, one module per profile; :mod:`..catalog` lists and imports them."""
