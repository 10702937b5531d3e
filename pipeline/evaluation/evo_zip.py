"""Result archives in the layout of evo 1.38.1 ``--save_results``, so ``evo_res`` and ``evo.tools.file_interface.
load_res_file`` read them: ``info.json`` (title, ref_name, est_name, label), ``stats.json`` (rmse, mean, median,
std, min, max, sse), one ``<name>.npy`` per array (``error_array``, ``timestamps``, ``seconds_from_start``,
``distances``, ``distances_from_start``, ``alignment_transformation_sim3``). The file format is written from
that description (NumPy ``.npy`` inside a plain zip); no evo code is used.
"""

from __future__ import annotations

import io
import json
import os
import zipfile
from pathlib import Path

import numpy as np

from slamobs.pipeline.evaluation.trajectory_error import ErrorResult
from slamobs.pipeline.writers import atomic_file


def _write_zip(target, result: ErrorResult) -> None:
    """The archive of ``result`` into ``target`` (a path or a binary file object), one array at a time."""
    info = {"title": result.title, "ref_name": result.ref_name, "est_name": result.est_name, "label": result.label}
    with zipfile.ZipFile(target, "w") as archive:
        archive.comment = COMMENT
        archive.writestr("info.json", json.dumps(info))
        archive.writestr("stats.json", json.dumps(result.evo_stats))
        for name, array in {"error_array": result.errors, **result.arrays}.items():
            npy = io.BytesIO()
            np.save(npy, np.asarray(array))
            archive.writestr(f"{name}.npy", npy.getbuffer())
            del npy


def result_zip_bytes(result: ErrorResult) -> bytes:
    """The archive of ``result`` as bytes."""
    buf = io.BytesIO()
    _write_zip(buf, result)
    return buf.getvalue()


#: The zip comment of an archive slamobs wrote: only such an archive is replaced by a later ``--save-results``.
COMMENT = b"written by slamobs"


def save_result_zip(path: str | Path, result: ErrorResult) -> Path:
    """Write the archive to ``path`` atomically (:func:`pipeline.writers.atomic_file`), streamed into the file
    rather than built in memory. An existing ``path`` is replaced only when it is an archive slamobs wrote."""
    path = Path(path)
    with atomic_file(path, why_kept=why_kept) as tmp:
        with open(tmp, "wb") as f:
            _write_zip(f, result)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
    return path


def why_kept(path: Path) -> str | None:
    """Why ``path`` must not be replaced: anything but an archive slamobs wrote (evo's own included) is the user's."""
    try:
        with zipfile.ZipFile(path) as archive:
            if archive.comment == COMMENT:
                return None
    except (OSError, zipfile.BadZipFile):
        pass
    return "exists and is not a result archive slamobs wrote: it is kept; remove it or choose another --save-results"


def load_result_zip(path: str | Path) -> tuple[dict, dict, dict[str, np.ndarray]]:
    """``(info, stats, arrays)`` of an evo-layout result archive (ours or evo's, ``.npy`` or old ``.npz`` names)."""
    with zipfile.ZipFile(path) as archive:
        info = json.loads(archive.read("info.json"))
        stats = json.loads(archive.read("stats.json"))
        arrays = {}
        for name in archive.namelist():
            if name.endswith((".npy", ".npz")):
                arrays[Path(name).stem] = np.load(io.BytesIO(archive.read(name)))
    return info, stats, arrays
