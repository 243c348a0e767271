"""fieldgate's version, in a module of its own: any module of the package can import it
without importing the package's ``__init__`` (which imports the runtime)."""

__version__ = "0.1.0"
