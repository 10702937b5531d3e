"""A command's last line, ``wrote DIR/ (files)``: only what is there once the command has finished."""

from __future__ import annotations

from pathlib import Path

#: Bookkeeping files of an output directory, not named in the listing.
UNLISTED = frozenset({"slamobs-output.json"})


def wrote_line(out_dir: Path, names: tuple[str, ...] | None = None, more: str = "") -> str:
    """``wrote DIR/ (a, b, ...)``: ``names`` that exist in ``out_dir`` (None: every file of it, sorted), then
    ``more`` (e.g. the run directories) when given."""
    out_dir = Path(out_dir)
    if names is None:
        names = tuple(sorted(p.name for p in out_dir.iterdir() if p.is_file() and p.name not in UNLISTED))
    found = [n for n in names if (out_dir / n).exists()]
    listed = ", ".join([*found, *([more] if more else [])])
    return f"{out_dir}/" + (f" ({listed})" if listed else "")
