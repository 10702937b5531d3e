"""Parquet outputs of a run (schemas in ``schemas/``) and the atomic run directory that holds them."""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from pipeline.lie import rots_to_quats
from pipeline.observers.base import ObserverResult
from schemas import arrow_schema

COMPRESSION = "zstd"
METADATA_KEY = b"slamobs"


def result_tables(res: ObserverResult) -> dict[str, dict[str, np.ndarray]]:
    """Columns of every output table, named as in ``schemas/``."""
    q = rots_to_quats(np.ascontiguousarray(res.rotation)) if len(res.t_ns) else np.zeros((0, 4))
    ids, first, last, n_obs = _landmark_summary(res)
    order = np.searchsorted(res.landmark_ids, ids)
    return {
        "poses": {"t_ns": res.t_ns, "x": res.position[:, 0], "y": res.position[:, 1], "z": res.position[:, 2],
                  "qx": q[:, 0], "qy": q[:, 1], "qz": q[:, 2], "qw": q[:, 3]},
        "biases": {"t_ns": res.t_ns,
                   **{f"gyro_bias_{a}": res.gyro_bias[:, i] for i, a in enumerate("xyz")},
                   **{f"vel_bias_{a}": res.vel_bias[:, i] for i, a in enumerate("xyz")}},
        "landmarks": {"id": ids, **{a: res.landmark_xyz[order, i] for i, a in enumerate("xyz")},
                      "first_seen_ns": first, "last_seen_ns": last, "n_obs": n_obs},
        "landmark_tracks": {"t_ns": res.det_t_ns, "id": res.det_ids,
                            **{a: res.track_xyz[:, i] for i, a in enumerate("xyz")}},
        "innovations": {"t_ns": res.det_t_ns, "id": res.det_ids,
                        **{f"e{a}": res.innovation[:, i] for i, a in enumerate("xyz")},
                        "e_norm": np.linalg.norm(res.innovation, axis=1)},
    }


def _landmark_summary(res: ObserverResult):
    """First/last detection time and detection count per landmark id."""
    ids, inv, n_obs = np.unique(res.det_ids, return_inverse=True, return_counts=True)
    first = np.full(ids.shape, np.iinfo(np.int64).max, dtype=np.int64)
    last = np.full(ids.shape, np.iinfo(np.int64).min, dtype=np.int64)
    np.minimum.at(first, inv, res.det_t_ns)
    np.maximum.at(last, inv, res.det_t_ns)
    return ids.astype(np.int64), first, last, n_obs.astype(np.int64)


def write_table(path: Path, name: str, columns: dict[str, np.ndarray], metadata: dict) -> None:
    """Write one table with its schema, run metadata in the key-value metadata, zstd-compressed."""
    schema = arrow_schema(name)
    arrays = [pa.array(np.asarray(columns[f.name]), type=f.type) for f in schema]
    meta = dict(schema.metadata or {})
    meta[METADATA_KEY] = json.dumps(metadata, sort_keys=True).encode()
    table = pa.Table.from_arrays(arrays, schema=schema.with_metadata(meta))
    pq.write_table(table, path, compression=COMPRESSION)


def write_result(out_dir: Path, res: ObserverResult, metadata: dict) -> list[Path]:
    """All five tables of a run into ``out_dir``."""
    written = []
    for name, cols in {**result_tables(res), **res.extra_tables}.items():
        path = out_dir / f"{name}.parquet"
        write_table(path, name, cols, metadata)
        written.append(path)
    return written


def read_metadata(path: Path) -> dict:
    """Run metadata stored in a table written by :func:`write_table`."""
    meta = pq.read_schema(path).metadata or {}
    return json.loads(meta[METADATA_KEY]) if METADATA_KEY in meta else {}


def write_json(path: Path, obj: dict) -> None:
    path.write_text(json.dumps(obj, indent=2, sort_keys=True, default=_json_default) + "\n")


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


@contextmanager
def atomic_directory(final: Path, *, force: bool = False):
    """Yield a temporary sibling directory that becomes ``final`` only if the block succeeds.

    An existing non-empty ``final`` is kept unless ``force``; with ``force`` it is replaced only after
    the new output is complete, so a failure never loses the previous run.
    """
    final = Path(final)
    if final.exists() and not force and (not final.is_dir() or any(final.iterdir())):
        raise FileExistsError(f"{final}: output exists (use --force to replace it)")
    final.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{final.name}.tmp-", dir=final.parent))
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o777 & ~umask)  # mkdtemp makes it private; a run directory is ordinary output
    try:
        yield tmp
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    old = None
    if final.exists():
        old = final.parent / f".{final.name}.old-{os.getpid()}"
        os.replace(final, old)
    os.replace(tmp, final)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True) if old.is_dir() else old.unlink()
