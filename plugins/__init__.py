"""fieldgate's built-in plugins. Each registers through the ``fieldgate.plugins`` entry-point group."""
