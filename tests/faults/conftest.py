"""The fault campaign's probes live in scripts/faults (runnable on their own); tests import them."""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "scripts" / "faults"))
