"""Parquet outputs: schemas, pandas round trip, metadata, compression, atomic run directories."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest

from slamobs.pipeline.lie import quat_to_rot, so3_exp
from slamobs.pipeline.observers import ObserverResult
from slamobs.pipeline.errors import OutputError
from slamobs.pipeline.paths import MANIFEST
from slamobs.pipeline.writers import atomic_directory, read_metadata, result_tables, write_result
from slamobs.schemas import TABLES, arrow_schema, table_spec


def _result(k=50, m=12):
    rng = np.random.default_rng(0)
    ids = np.array([4, 11, 30])
    det_ids = rng.choice(ids, size=m)
    return ObserverResult(
        t_ns=np.arange(k, dtype=np.int64) * 10_000_000 + 1_700_000_000 * 10**9,
        rotation=np.stack([so3_exp(rng.normal(size=3)) for _ in range(k)]),
        position=rng.normal(size=(k, 3)),
        gyro_bias=rng.normal(size=(k, 3)),
        vel_bias=rng.normal(size=(k, 3)),
        landmark_ids=ids,
        landmark_xyz=rng.normal(size=(3, 3)),
        det_t_ns=np.sort(rng.integers(0, 10**9, size=m)).astype(np.int64),
        det_ids=det_ids,
        track_xyz=rng.normal(size=(m, 3)),
        innovation=rng.normal(size=(m, 3)),
    )


def test_every_table_matches_its_schema_and_round_trips_through_pandas(tmp_path):
    res = _result()
    meta = {"observer": {"name": "test"}}
    write_result(tmp_path, res, meta)
    for name in TABLES:
        path = tmp_path / f"{name}.parquet"
        schema = pq.read_schema(path)
        assert schema.names == [f["name"] for f in table_spec(name)["fields"]]
        assert schema.remove_metadata().equals(arrow_schema(name).remove_metadata())
        assert schema.field(0).metadata[b"unit"] is not None
        assert read_metadata(path) == meta
        assert pq.ParquetFile(path).metadata.row_group(0).column(0).compression == "ZSTD"
        df = pd.read_parquet(path)
        nullable = [f["name"] for f in table_spec(name)["fields"] if f.get("nullable")]  # uncertainty: riekf, batch
        assert len(df) > 0 and not df.drop(columns=nullable).isna().any().any()
        assert df[nullable].isna().all().all()  # an observer's result has no covariance: null
        assert str(df.dtypes.iloc[0]) == "int64"


def test_statistics_are_kept_where_read_back_and_dropped_for_floats_that_cannot_be_null(tmp_path):
    """The writer computes no min/max of the long float columns (nothing reads them back); the times, ids and the
    nullable uncertainty columns keep theirs, so ``null_columns`` still finds the columns null throughout."""
    from slamobs.pipeline.writers import null_columns

    write_result(tmp_path, _result(), {"observer": {"name": "test"}})
    f = pq.ParquetFile(tmp_path / "poses.parquet")
    group = f.metadata.row_group(0)
    stats = {group.column(c).path_in_schema: group.column(c).statistics for c in range(group.num_columns)}
    assert stats["t_ns"] is not None and stats["t_ns"].min == 1_700_000_000 * 10**9
    assert all(stats[c] is None for c in ("x", "y", "z", "qx", "qy", "qz", "qw"))
    nullable = {field.name for field in arrow_schema("poses") if field.nullable}
    assert len(nullable) == 27 and null_columns(f) == nullable


def test_table_contents():
    res = _result()
    t = result_tables(res)
    # quaternions encode the same rotations, unit norm, w >= 0
    q = np.column_stack([t["poses"][c] for c in ("qx", "qy", "qz", "qw")])
    assert np.allclose(np.linalg.norm(q, axis=1), 1.0)
    assert np.allclose(np.stack([quat_to_rot(x) for x in q]), res.rotation, atol=1e-12)
    lm = pd.DataFrame(t["landmarks"])
    for _, row in lm.iterrows():
        mine = res.det_ids == row["id"]
        assert row["n_obs"] == mine.sum()
        assert row["first_seen_ns"] == res.det_t_ns[mine].min()
        assert row["last_seen_ns"] == res.det_t_ns[mine].max()
        i = int(np.flatnonzero(res.landmark_ids == row["id"])[0])
        assert np.allclose(row[["x", "y", "z"]].to_numpy(float), res.landmark_xyz[i])
    assert np.allclose(t["innovations"]["e_norm"], np.linalg.norm(res.innovation, axis=1))


def test_atomic_directory_success_failure_and_existing_output(tmp_path):
    out = tmp_path / "run"
    with atomic_directory(out) as tmp:
        (tmp / "run.json").write_text("1")
    assert (out / "run.json").read_text() == "1"
    # existing output is kept without force ...
    with pytest.raises(OutputError, match="use --force"):
        with atomic_directory(out):
            pass
    # ... and is not lost when a forced replacement fails half way
    with pytest.raises(RuntimeError):
        with atomic_directory(out, force=True) as tmp:
            (tmp / "partial.txt").write_text("x")
            raise RuntimeError("boom")
    assert (out / "run.json").read_text() == "1" and not (out / "partial.txt").exists()
    with atomic_directory(out, force=True) as tmp:
        (tmp / "run.json").write_text("2")
    assert sorted(p.name for p in out.iterdir()) == ["run.json", MANIFEST] and (out / "run.json").read_text() == "2"
    assert [p.name for p in tmp_path.iterdir()] == ["run"]  # no temporary or backup left behind
    # --force replaces only what slamobs wrote: a directory of the user's files is refused, untouched
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "thesis.tex").write_text("precious")
    with pytest.raises(OutputError, match="not a slamobs output"):
        with atomic_directory(mine, force=True):
            pass
    assert (mine / "thesis.tex").read_text() == "precious"
    # ... and one of its own changed since: a manifest lists every file slamobs wrote with its size
    assert json.loads((out / MANIFEST).read_text())["files"] == {"run.json": 1}
    (out / "run.json").write_text("22")
    with pytest.raises(OutputError, match="run.json is changed since slamobs wrote it"):
        with atomic_directory(out, force=True):
            pass


def test_a_directory_of_the_user_s_files_is_refused_without_suggesting_force(tmp_path):
    """Without --force an existing directory that holds a file slamobs did not write is refused for that reason:
    "use --force to replace it" would only lead to the refusal --force meets (round 24, `run -o mine`)."""
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("mine")
    with pytest.raises(OutputError, match="not a slamobs output") as err:
        with atomic_directory(mine):
            pass
    assert "use --force to replace it" not in str(err.value) and "notes.txt" in str(err.value)
    assert (mine / "notes.txt").read_text() == "mine"


def test_schema_files_are_valid_json_with_units():
    for name in TABLES:
        spec = json.loads((arrow_schema.__globals__["HERE"] / f"{name}.json").read_text())
        assert spec["name"] == name
        assert all({"name", "type", "unit", "description"} <= set(f) for f in spec["fields"])


def test_tables_written_stretch_by_stretch_equal_one_stretch(tmp_path):
    """Row groups written one stretch at a time read back as the whole table; encodings suit the columns."""
    from slamobs.pipeline.writers import TableWriter, read_frame, stretch_tables

    res = _result(k=300, m=90)
    whole = stretch_tables(res)
    sink = TableWriter(tmp_path, float_bits=52)
    for rows, dets in ((slice(0, 100), slice(0, 40)), (slice(100, 300), slice(40, 90))):
        part = ObserverResult(
            res.t_ns[rows],
            res.rotation[rows],
            res.position[rows],
            res.gyro_bias[rows],
            res.vel_bias[rows],
            res.landmark_ids,
            res.landmark_xyz,
            res.det_t_ns[dets],
            res.det_ids[dets],
            res.track_xyz[dets],
            res.innovation[dets],
        )
        sink.write(stretch_tables(part))
    meta = {"counts": {"internal_steps": 7}}
    sink.close(meta)
    for name, columns in whole.items():
        path = tmp_path / f"{name}.parquet"
        assert read_metadata(path) == meta and pq.ParquetFile(path).metadata.num_row_groups == 2
        df = pd.read_parquet(path)
        for column, values in columns.items():
            assert np.array_equal(df[column].to_numpy(), values), (name, column)
        assert read_frame(path).equals(df)
        chunk = pq.ParquetFile(path).metadata.row_group(0)
        encodings = {chunk.column(i).path_in_schema: chunk.column(i).encodings for i in range(chunk.num_columns)}
        assert "DELTA_BINARY_PACKED" in encodings["t_ns"]
        assert all("BYTE_STREAM_SPLIT" in e for c, e in encodings.items() if c not in ("t_ns", "id"))


def test_every_column_is_zstd_with_its_encoding_and_reads_back_bit_for_bit(tmp_path):
    """The codec and encodings kept for the hour's tables (docs/benchmarks.md, session 20): every column chunk
    zstd, floats byte-stream split, ``*_ns`` delta-packed, ids dictionary-encoded; pandas and
    pyarrow read the written (rounded) values back bit for bit."""
    from slamobs.pipeline.writers import FLOAT_BITS, round_mantissa, round_step
    from slamobs.schemas import fixed_steps

    res = _result(k=300, m=90)
    write_result(tmp_path, res, {"run": 1})
    for name, columns in result_tables(res).items():
        path = tmp_path / f"{name}.parquet"
        meta = pq.ParquetFile(path).metadata
        chunks = [meta.row_group(g).column(i) for g in range(meta.num_row_groups) for i in range(meta.num_columns)]
        assert {c.compression for c in chunks} == {"ZSTD"}, name
        for c in chunks:
            column = c.path_in_schema
            kind = "BYTE_STREAM_SPLIT" if c.physical_type == "DOUBLE" else None
            kind = "DELTA_BINARY_PACKED" if column.endswith("_ns") else kind
            assert (kind or "RLE_DICTIONARY") in c.encodings, (name, column, c.encodings)
        table, frame = pq.read_table(path), pd.read_parquet(path)
        for field in arrow_schema(name):
            if field.name not in columns:
                continue
            values = np.asarray(columns[field.name])
            if values.dtype == np.float64 and field.name in fixed_steps(name):
                values = round_step(values, fixed_steps(name)[field.name])
            elif values.dtype == np.float64:
                values = round_mantissa(values, FLOAT_BITS)
            assert table.column(field.name).to_numpy().tobytes() == values.tobytes(), (name, field.name)
            assert frame[field.name].to_numpy().tobytes() == values.tobytes(), (name, field.name)


def test_round_mantissa_bounds_the_relative_error_and_keeps_special_values():
    from slamobs.pipeline.writers import round_mantissa

    rng = np.random.default_rng(3)
    x = rng.normal(size=100_000) * 10.0 ** rng.integers(-12, 12, size=100_000)
    for bits in (10, 28, 40):
        r = round_mantissa(x, bits)
        assert np.max(np.abs(r - x) / np.abs(x)) <= 2.0 ** -(bits + 1)
        assert np.array_equal(round_mantissa(r, bits), r)  # idempotent
        assert np.all(r.view(np.uint64) & np.uint64((1 << (52 - bits)) - 1) == 0)  # low bits cleared
    assert np.array_equal(round_mantissa(x, 52), x)
    special = np.array([0.0, -0.0, np.inf, -np.inf])
    assert np.array_equal(round_mantissa(special, 20), special)
    big = np.array([np.finfo(float).max, -np.finfo(float).max])  # would round up to Inf: truncated instead
    assert np.all(np.isfinite(round_mantissa(big, 20))) and np.allclose(round_mantissa(big, 20), big, rtol=2.0**-20)
    assert np.isnan(round_mantissa(np.array([np.nan]), 20)).all()
    assert round_mantissa(x, 28) is not x and np.array_equal(x, x)  # the input is left as it was


def test_round_mantissa_keeps_a_fine_enough_step_far_from_the_origin():
    """``finest``: a value whose step at ``bits`` would be coarser than ``2**finest`` keeps more bits (an absolute
    error of at most ``2**(finest - 1)``); nearer values are rounded exactly as without it."""
    from slamobs.pipeline.writers import round_mantissa

    rng = np.random.default_rng(5)
    near = rng.normal(size=50_000) * 100.0  # |x| < 512 m: 28 bits are finer than 2**-20 m already
    far = np.concatenate([4.69e6 + rng.normal(size=50_000) * 50.0, -6.4e6 + rng.normal(size=1000)])
    x = np.concatenate([near, far, [0.0, -0.0, np.inf, -np.inf, np.nan, np.finfo(float).max]])
    r = round_mantissa(x, 28, -20)
    ok = np.isfinite(x)
    assert np.all(np.abs(r[ok] - x[ok]) <= np.maximum(2.0**-21, np.abs(x[ok]) * 2.0**-29))
    assert np.max(np.abs(r[near.size : near.size + far.size] - far)) <= 2.0**-21  # 1.6 cm steps without it
    assert np.max(np.abs(round_mantissa(far, 28) - far)) > 1e-3
    assert np.array_equal(r[: near.size], round_mantissa(near, 28))
    assert np.array_equal(round_mantissa(near, 28, -20), round_mantissa(near, 28))  # the one-shift path
    assert np.array_equal(round_mantissa(r, 28, -20), r, equal_nan=True)  # idempotent
    assert np.array_equal(r[-6:-2], x[-6:-2]) and np.isnan(r[-2]) and np.isfinite(r[-1])


def test_positions_in_a_far_away_frame_keep_micrometres(tmp_path):
    """A pose in a UTM-like truth frame (4,690 km from the origin) is stored to 1 µm, as near the origin: a length's
    step is 2**-20 m wherever it is (relative rounding on 28 bits would store it in 1.6 cm steps)."""
    from slamobs.pipeline.writers import FLOAT_BITS, round_mantissa, round_step

    res = _result(k=5000, m=40)
    res.position[:] = res.position * 30.0 + np.array([330_000.0, 4_690_000.0, 20.0])
    write_result(tmp_path, res, {})
    poses = pd.read_parquet(tmp_path / "poses.parquet")
    assert np.max(np.abs(poses[["x", "y", "z"]].to_numpy() - res.position)) <= 2.0**-21
    assert np.max(np.abs(round_mantissa(res.position[:, 1], FLOAT_BITS) - res.position[:, 1])) > 1e-3
    for c, values in zip("xyz", res.position.T, strict=True):
        assert np.array_equal(poses[c].to_numpy(), round_step(values, -20))  # far and near alike


def test_round_step_rounds_to_a_multiple_and_keeps_special_values():
    from slamobs.pipeline.writers import round_step

    rng = np.random.default_rng(4)
    x = rng.normal(size=100_000) * 10.0 ** rng.integers(-9, 9, size=100_000)
    for exp in (-26, -20, 3):
        r = round_step(x, exp)
        assert np.max(np.abs(r - x)) <= 2.0 ** (exp - 1)
        assert np.array_equal(r / 2.0**exp, np.round(r / 2.0**exp))  # multiples of the step
        assert np.array_equal(round_step(r, exp), r)  # idempotent
    special = np.array([0.0, np.inf, -np.inf, 2.0**60 + 2.0**8, -np.finfo(float).max])
    assert np.array_equal(round_step(special, -20), special)  # multiples already, or not finite
    assert np.isnan(round_step(np.array([np.nan]), -20)).all()
    tiny = round_step(np.array([-1e-9, -0.0]), -20)
    assert np.array_equal(tiny, [0.0, 0.0]) and not np.signbit(tiny).any()  # a small negative reads 0.0, not -0.0
    assert round_step(x, -20) is not x


def test_every_float_column_is_within_its_stated_rounding(tmp_path):
    """Every float column of every table written at the default ``float_bits`` is within its stated bound of the
    value written with ``float_bits=52`` (every bit): a fixed step ``2**e`` (schemas.fixed_steps: lengths
    2**-20 m, quaternions 2**-24, biases 2**-26) within ``2**(e-1)`` and a multiple of it; the others within a
    relative ``2**-(float_bits+1)``. ``float_bits=30`` makes each step four times finer."""
    from slamobs.schemas import fixed_steps

    res = _result(k=3000, m=900)
    res.position[:] *= 20.0
    res.gyro_bias[:] *= 0.01
    res.vel_bias[:] *= 0.05
    res.innovation[:] *= 0.02
    dirs = {bits: tmp_path / str(bits) for bits in (52, 28, 30)}
    for bits, out in dirs.items():
        out.mkdir()
        write_result(out, res, {}, float_bits=bits)
    checked = set()
    for name in TABLES:
        exact = pd.read_parquet(dirs[52] / f"{name}.parquet")
        steps = fixed_steps(name)
        for f in table_spec(name)["fields"]:
            if f["type"] != "float64" or exact[f["name"]].isna().all():
                continue
            x = exact[f["name"]].to_numpy()
            for bits, shift in ((28, 0), (30, 2)):
                r = pd.read_parquet(dirs[bits] / f"{name}.parquet")[f["name"]].to_numpy()
                if f["name"] in steps:
                    step = 2.0 ** (steps[f["name"]] - shift)
                    assert np.max(np.abs(r - x)) <= step / 2, (name, f["name"], bits)
                    assert np.array_equal(np.round(r / step) * step, r), (name, f["name"])  # multiples of the step
                else:
                    assert np.all(np.abs(r - x) <= np.abs(x) * 2.0 ** -(bits + 1)), (name, f["name"], bits)
                assert not np.array_equal(r, x), (name, f["name"])  # rounded at all
            checked.add((name, f["name"]))
    assert {("poses", "x"), ("poses", "qw"), ("biases", "gyro_bias_z"), ("innovations", "e_norm")} <= checked
    assert {("landmark_tracks", "z"), ("landmarks", "x"), ("biases", "vel_bias_x")} <= checked


def test_float_columns_are_stored_with_the_configured_precision(tmp_path):
    """Default output rounds a length to 2**-20 m and a quaternion to its schema's step (far below estimation
    accuracy, much smaller files); ``float_bits=52`` keeps every bit."""
    from slamobs.pipeline.writers import round_step
    from slamobs.schemas import LENGTH_STEP_EXP, fixed_steps

    res = _result(k=20_000, m=100)
    exact, rounded = tmp_path / "exact", tmp_path / "rounded"
    exact.mkdir(), rounded.mkdir()
    write_result(exact, res, {}, float_bits=52)
    write_result(rounded, res, {})
    a, b = pd.read_parquet(exact / "poses.parquet"), pd.read_parquet(rounded / "poses.parquet")
    assert np.array_equal(a["x"].to_numpy(), res.position[:, 0])
    assert np.array_equal(b["x"].to_numpy(), round_step(res.position[:, 0], LENGTH_STEP_EXP))
    assert np.array_equal(b["qw"].to_numpy(), round_step(a["qw"].to_numpy(), fixed_steps("poses")["qw"]))
    assert np.array_equal(a["t_ns"].to_numpy(), b["t_ns"].to_numpy())
    assert (rounded / "poses.parquet").stat().st_size < 0.8 * (exact / "poses.parquet").stat().st_size


def test_writing_tables_does_not_import_pandas(tmp_path):
    """pyarrow's ``pa.array`` and ``to_numpy`` import pandas (~0.8 s) on first use; a run never needs it (its
    report reads the tables back as NumPy columns)."""
    import subprocess
    import sys

    code = (
        "import sys, numpy as np; from slamobs.pipeline.writers import TableWriter; "
        "w = TableWriter(sys.argv[1]); t = np.arange(5, dtype=np.int64); x = np.linspace(0, 1, 5); "
        "cols = ('gyro_bias_x', 'gyro_bias_y', 'gyro_bias_z', 'vel_bias_x', 'vel_bias_y', 'vel_bias_z'); "
        "w.write({'biases': {'t_ns': t, **{c: x for c in cols}}}); "
        "w.close({}); from slamobs.pipeline.writers import read_columns; "
        "import slamobs.pipeline.evaluation.report, slamobs.pipeline.evaluation.run_dir, slamobs.pipeline.run; "
        "c = read_columns(sys.argv[1] + '/biases.parquet'); assert c['t_ns'].tolist() == list(range(5)); "
        "print('pandas' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code, str(tmp_path)], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
    table = pq.read_table(tmp_path / "biases.parquet")
    assert table.column("t_ns").to_pylist() == list(range(5)) and table.num_rows == 5


def test_read_columns_equals_read_frame(tmp_path):
    from slamobs.pipeline.writers import TableWriter, read_columns, read_frame

    rng = np.random.default_rng(1)
    sink = TableWriter(tmp_path)
    for k in range(3):  # three row groups
        t = np.arange(k * 4, k * 4 + 4, dtype=np.int64)
        sink.write(
            {
                "landmarks": {
                    "id": t,
                    "x": rng.normal(size=4),
                    "y": rng.normal(size=4),
                    "z": np.full(4, np.nan),
                    **{
                        c.name: np.zeros(4, dtype=c.type.to_pandas_dtype())
                        for c in arrow_schema("landmarks")
                        if c.name not in ("id", "x", "y", "z")
                    },
                }
            }
        )
    sink.close({})
    frame, cols = read_frame(tmp_path / "landmarks.parquet"), read_columns(tmp_path / "landmarks.parquet")
    assert list(cols) == list(frame.columns) and len(cols["x"]) == len(frame) == 12
    for name in cols:
        assert cols[name].dtype == frame[name].to_numpy().dtype
        np.testing.assert_array_equal(cols[name], frame[name].to_numpy())
    some = read_columns(tmp_path / "landmarks.parquet", wanted=lambda name: name in ("id", "y"))
    assert list(some) == ["id", "y"]
    np.testing.assert_array_equal(some["y"], cols["y"])


def test_report_reads_the_pose_columns_it_uses():
    """The run's report leaves out the poses' standard deviations and covariance cross terms (86 MB on batch's
    hour), and reads every column it uses."""
    from slamobs.pipeline.evaluation.trajectory_evaluation import report_pose_column

    names = [f.name for f in arrow_schema("poses")]
    read = {n for n in names if report_pose_column(n)}
    blocks = [
        f"cov_{a}_{b}" for axes in (("rx", "ry", "rz"), ("x", "y", "z")) for i, a in enumerate(axes) for b in axes[i:]
    ]
    assert read == {"t_ns", "x", "y", "z", "qx", "qy", "qz", "qw", *blocks} and len(blocks) == 12
    assert len(names) - len(read) == 15


def test_compiled_rounding_gives_the_bits_of_the_array_code(monkeypatch):
    """Long columns are rounded by a compiled pass (pipeline.rounding): the same bits as the array code for every
    kind of value (zeros, subnormals, NaN, ±Inf, values that would round into Inf), both signs, with and without
    ``finest`` (per value, and the shortcut when no value needs it)."""
    from slamobs.pipeline import writers

    rng = np.random.default_rng(11)
    n = 20_000
    x = rng.normal(size=n) * 10.0 ** rng.integers(-30, 30, size=n)
    x[::97], x[1::97], x[2::97], x[3::97], x[4::97] = 0.0, -0.0, np.nan, np.inf, -np.inf
    x[5::97] = 5e-324 * rng.integers(1, 1000, size=x[5::97].size)
    x[6::97] = np.finfo(np.float64).max * (1 - rng.random(x[6::97].size) * 1e-10)
    local = rng.normal(size=n) * 3.0  # every step fine enough at the bits: the shortcut
    for values in (x, -x, local):
        for bits in (1, 20, 28, 51):
            for finest in (None, -20, 5):
                monkeypatch.setattr(writers, "ROUND_KERNEL_ROWS", 1)
                compiled = writers.round_mantissa(values, bits, finest)
                monkeypatch.setattr(writers, "ROUND_KERNEL_ROWS", 1 << 62)
                array = writers.round_mantissa(values, bits, finest)
                assert np.array_equal(compiled.view(np.uint64), array.view(np.uint64)), (bits, finest)
                assert compiled is not values
        for exp in (-50, -30, -20, 0, 7, 40):  # a fixed step: round_step (float_bits 1..51: -44..7)
            monkeypatch.setattr(writers, "ROUND_KERNEL_ROWS", 1)
            compiled = writers.round_step(values, exp)
            monkeypatch.setattr(writers, "ROUND_KERNEL_ROWS", 1 << 62)
            array = writers.round_step(values, exp)
            assert np.array_equal(compiled.view(np.uint64), array.view(np.uint64)), exp
            assert compiled is not values


def test_tables_written_on_two_lanes_are_the_bytes_of_one(tmp_path, monkeypatch):
    """TableWriter writes the tables of a stretch on two threads: the files are byte for byte those written one
    table after the other, and an error on the helper's lane is raised by ``write``."""
    from slamobs.pipeline import writers
    from slamobs.pipeline.writers import TableWriter

    rng = np.random.default_rng(2)

    def stretch(n: int, t0: int) -> dict:
        t = t0 + np.arange(n, dtype=np.int64) * 5_000_000
        return {
            "poses": {"t_ns": t, **{c: rng.normal(size=n) for c in ("x", "y", "z", "qx", "qy", "qz", "qw")}},
            "biases": {"t_ns": t, **{f"{k}_bias_{a}": rng.normal(size=n) for k in ("gyro", "vel") for a in "xyz"}},
            "innovations": {
                "t_ns": t[::3],
                "id": np.arange(t[::3].size, dtype=np.int64) % 7,
                **{c: rng.normal(size=t[::3].size) for c in ("ex", "ey", "ez", "e_norm")},
            },
        }

    stretches = [stretch(3000, 0), stretch(2000, 3000 * 5_000_000)]
    for lanes in ("two", "one"):
        if lanes == "one":
            monkeypatch.setattr(writers, "_two_lanes", lambda tables: (list(tables.items()), []))
        (tmp_path / lanes).mkdir()
        sink = TableWriter(tmp_path / lanes, 28)
        for part in stretches:
            sink.write(part)
        sink.close({"run": 1})
    for name in stretches[0]:
        assert (tmp_path / "two" / f"{name}.parquet").read_bytes() == (
            tmp_path / "one" / f"{name}.parquet"
        ).read_bytes()
    bad = {**stretches[0], "biases": {"t_ns": stretches[0]["biases"]["t_ns"]}}  # a required column missing
    monkeypatch.setattr(
        writers, "_two_lanes", lambda tables: ([("poses", tables["poses"])], [("biases", tables["biases"])])
    )
    sink = TableWriter(tmp_path, 28)
    with pytest.raises(KeyError):
        sink.write(bad)
    sink.abort()


def test_tables_kept_by_the_writer_equal_the_files_read_back(tmp_path):
    """The tables a run hands to its report as written (``TableWriter.kept``) are ``read_columns`` of their
    files, column for column and bit for bit: rounded floats, int32 indices stored as int64, NaN, the observers'
    null uncertainty columns left out of the poses (``skip_null``) or read as NaN (landmarks); a table not kept
    is not handed over, a kept one only once."""
    from slamobs.pipeline.writers import TableWriter, read_columns, stretch_tables

    res = _result(k=300, m=90)
    sink = TableWriter(tmp_path, keep=("poses", "biases", "landmarks"))
    for rows in (slice(0, 120), slice(120, 300)):
        tables = stretch_tables(
            ObserverResult(
                res.t_ns[rows],
                res.rotation[rows],
                res.position[rows] * 1e3,
                res.gyro_bias[rows],
                res.vel_bias[rows],
                res.landmark_ids,
                res.landmark_xyz,
                res.det_t_ns[:0],
                res.det_ids[:0],
                res.track_xyz[:0],
                res.innovation[:0],
            )
        )
        tables["biases"]["gyro_bias_x"] = tables["biases"]["gyro_bias_x"].copy()
        tables["biases"]["gyro_bias_x"][3] = np.nan
        sink.write(tables)
    sink.write(
        {
            "landmarks": {
                "id": np.array([4, 11, 30], dtype=np.int32),
                "x": res.landmark_xyz[:, 0],
                "y": res.landmark_xyz[:, 1],
                "z": res.landmark_xyz[:, 2],
                "first_seen_ns": np.zeros(3, dtype=np.int64),
                "last_seen_ns": np.ones(3, dtype=np.int64),
                "n_obs": np.array([1, 2, 3], dtype=np.int32),
            }
        }
    )
    sink.close({})
    for name, skip in (("poses", True), ("biases", False), ("landmarks", False)):
        kept = sink.kept(name, skip_null=skip)
        assert sink.kept(name) is None  # handed over once
        want = read_columns(tmp_path / f"{name}.parquet", skip_null=skip)
        assert list(kept) == list(want), name
        for column in want:
            assert kept[column].dtype == want[column].dtype and kept[column].tobytes() == want[column].tobytes()
        if name == "poses":
            assert "cov_x_x" not in kept and not np.array_equal(kept["x"], res.position[:, 0] * 1e3)  # rounded
    assert sink.kept("innovations") is None


def test_writer_keeps_nothing_once_its_byte_limit_is_passed(tmp_path):
    """Kept values never pass ``keep_bytes``: a stretch that would stops the keeping of every table (the report
    then reads the files back), so what a run holds for its report is bounded whatever the table's width."""
    from slamobs.pipeline.writers import TableWriter, stretch_tables

    res = _result(k=300, m=90)
    one = stretch_tables(res)
    size = sum(v.nbytes for name in ("poses", "biases") for v in one[name].values() if isinstance(v, np.ndarray))
    for limit, kept in ((10 * size, True), (size // 2, False)):
        sink = TableWriter(tmp_path / str(limit), keep=("poses", "biases"), keep_bytes=limit)
        (tmp_path / str(limit)).mkdir()
        sink.write({k: one[k] for k in ("poses", "biases")})
        sink.close({})
        assert (sink.kept("poses") is not None) is kept and (sink.kept("biases") is not None) is kept, limit
    # told the rows to come, the writer keeps nothing from the first stretch on when the whole would not fit
    for rows, kept in ((2 * 300, True), (40 * 300, False)):
        out = tmp_path / f"rows{rows}"
        out.mkdir()
        sink = TableWriter(out, keep=("poses", "biases"), keep_bytes=10 * size, expected_rows={"poses": rows})
        sink.write({k: one[k] for k in ("poses", "biases")})
        sink.close({})
        assert (sink.kept("poses") is not None) is kept and (sink.kept("biases") is not None) is kept, rows
