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
#: A length's rounding step at the default ``float_bits``, as a power of two in metres (2**-20 m ≈ 0.95 µm, the
#: error at most half that, near the origin and in a UTM or ECEF frame alike): every column in metres but the
#: uncertainty columns (their own ``float_bits``) has this fixed step; other columns may state one (``step_exp``).
LENGTH_STEP_EXP = -20


@cache
def table_spec(name: str) -> dict:
    """The JSON description of output table ``name``."""
    return json.loads((HERE / f"{name}.json").read_text())


@cache
def fixed_steps(name: str) -> dict[str, int]:
    """The float columns of table ``name`` stored at a fixed step, as the step's power of two at
    :data:`DEFAULT_FLOAT_BITS` (pipeline.writers.round_step): the entry's ``step_exp``, else a length's
    :data:`LENGTH_STEP_EXP`; the uncertainty columns (``float_bits`` in their entry) are rounded relative to
    their value instead."""
    return {
        f["name"]: f.get("step_exp", LENGTH_STEP_EXP)
        for f in table_spec(name)["fields"]
        if f["type"] == "float64" and "float_bits" not in f and ("step_exp" in f or f["unit"] == "m")
    }


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
