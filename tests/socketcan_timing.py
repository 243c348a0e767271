"""Old name of socketcan_guest (kept while branches that import it are merged)."""

from socketcan_guest import SLOWDOWN, in_guest, scaled  # noqa: F401
