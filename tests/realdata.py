"""Where the real recordings are: ``$SLAMOBS_REALDATA``, else ``../shared/realdata`` beside the repository.

Tests that read them skip cleanly when the folder is absent (a user's clone has none); everything else runs on
the logs the project ships or generates.
"""

from __future__ import annotations

import os
from pathlib import Path

REALDATA = Path(os.environ.get("SLAMOBS_REALDATA") or Path(__file__).resolve().parents[2] / "shared" / "realdata")
