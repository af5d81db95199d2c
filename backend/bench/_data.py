"""Where benchmarks find third-party data: ``../shared/data`` beside the repository, or the
folder ``SFT_SHARED_DATA`` names (for checkouts elsewhere)."""

from __future__ import annotations

import os
from pathlib import Path

SHARED_DATA = Path(os.environ.get("SFT_SHARED_DATA") or Path(__file__).resolve().parents[3] / "shared" / "data")
