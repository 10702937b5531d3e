"""Arrow schemas of the Parquet outputs and the JSON Schema of the run configuration.

The JSON files beside this module are the single source of truth; users can read them without Python.
"""

from __future__ import annotations

import json
from functools import cache
from pathlib import Path

HERE = Path(__file__).parent
TABLES = ("poses", "biases", "landmarks", "landmark_tracks", "innovations")
#: Tables only some runs write: the hybrid's jumps; tag corner and image logs' detections; the estimate aligned
#: into the truth's frame (runs with truth).
OPTIONAL_TABLES = ("jumps", "tag_detections", "poses_aligned", "landmarks_aligned")
#: Significant mantissa bits kept in float outputs (pipeline.writers.round_mantissa; 52 = float64 exactly); the
#: default of ``output.float_bits`` (pipeline.config), here so that writing outputs never imports the config.
DEFAULT_FLOAT_BITS = 28


@cache
def table_spec(name: str) -> dict:
    """The JSON description of output table ``name``."""
    return json.loads((HERE / f"{name}.json").read_text())


def arrow_schema(name: str):
    """``pyarrow.Schema`` of output table ``name``, with units and descriptions as field metadata."""
    import pyarrow as pa

    spec = table_spec(name)
    fields = [
        pa.field(
            f["name"],
            getattr(pa, f["type"])(),
            nullable=f.get("nullable", False),
            metadata={
                "unit": f["unit"],
                "description": f["description"],
                # the uncertainty columns: significant bits kept at most (output.float_bits applies below it)
                **({"float_bits": str(f["float_bits"])} if "float_bits" in f else {}),
            },
        )
        for f in spec["fields"]
    ]
    return pa.schema(fields, metadata={"description": spec["description"]})


@cache
def config_schema() -> dict:
    """JSON Schema of ``run.yaml``."""
    return json.loads((HERE / "config.json").read_text())
