"""TUM / KITTI parsing: every value equals Python's ``float()`` of its token and every stamp is exact, whichever
path (pyarrow's CSV reader for regular files, pandas for the rest) parsed the file."""

from __future__ import annotations

import numpy as np
import pytest

from slamobs.pipeline.errors import InputError
from slamobs.pipeline.readers import trajectory_files
from slamobs.pipeline.readers.trajectory_files import load_kitti, load_tum, stamp_ns

N = 2_000


def _tokens(rng: np.random.Generator, n: int) -> list[str]:
    """Numbers written the many ways trajectory files write them."""
    x = rng.standard_normal(n) * 10.0 ** rng.integers(-12, 12, n)
    forms = [repr, lambda v: f"{v:.6f}", lambda v: f"{v:.9e}", lambda v: f"{v:+.3E}", lambda v: f"{v:.20g}"]
    out = [forms[k % len(forms)](float(v)) for k, v in enumerate(x)]
    out[:4] = ["5.", "-.5", "7", "0.1000000000000000055511151231257827021181583404541015625"]
    return out


@pytest.fixture(scope="module")
def tum(tmp_path_factory) -> tuple[list[list[str]], str]:
    rng = np.random.default_rng(7)
    sec = 1_700_000_000 + np.arange(N)
    frac = rng.integers(0, 10**9, N)
    stamps = [f"{s}.{f:09d}"[: 11 + int(d)] for s, f, d in zip(sec, frac, rng.integers(0, 10, N), strict=True)]
    stamps[:3] = ["1700000000", "1.7e9", "1.0000000001234567895e9"]  # not plain: parsed one by one
    values = np.array(_tokens(rng, N * 7)).reshape(N, 7)
    values[:, 3:7] = [[f"{v:.17g}" for v in q] for q in rng.standard_normal((N, 4))]
    rows = [[t, *v] for t, v in zip(stamps, values.tolist(), strict=True)]
    return rows, "\n".join(" ".join(r) for r in rows) + "\n"


def _check(stream, rows: list[list[str]]) -> None:
    assert stream.t_ns.tolist() == [stamp_ns(r[0]) for r in rows]
    want = np.array([[float(v) for v in r[1:]] for r in rows])
    got = np.column_stack([stream.position, stream.quat_xyzw])
    assert np.array_equal(got.view(np.int64), want.view(np.int64))  # bit for bit, signed zeros included


@pytest.mark.parametrize(
    "layout",
    [
        lambda text: text,  # regular: the fast path
        lambda text: text.replace("\n", "\r\n"),
        lambda text: "# t x y z qx qy qz qw\n" + text,  # comment: the general path
        lambda text: text.replace(" ", "  ").replace("\n", " \n"),  # runs of spaces
        lambda text: text.replace(" ", ","),
        lambda text: text.replace(" ", "\t"),
    ],
)
def test_tum_values_equal_float_of_every_token(tmp_path, tum, layout):
    rows, text = tum
    path = tmp_path / "t.txt"
    path.write_text(layout(text))
    _check(load_tum(path), rows)


@pytest.mark.parametrize(("bad", "message"), [("nan", "not a finite number"), ("1.5x", "not a number")])
def test_bad_value_in_a_regular_file_is_named_by_its_line(tmp_path, tum, bad, message):
    rows, _ = tum
    broken = [list(r) for r in rows[:50]]
    broken[30][5] = bad
    path = tmp_path / "t.txt"
    path.write_text("\n".join(" ".join(r) for r in broken) + "\n")
    with pytest.raises(InputError, match=rf"t\.txt.*line 31: {message}"):
        load_tum(path)


def test_kitti_values_equal_float_of_every_token(tmp_path):
    rng = np.random.default_rng(3)
    rot = np.linalg.qr(rng.standard_normal((200, 3, 3)))[0]
    rot *= np.sign(np.linalg.det(rot))[:, None, None]
    pose = np.concatenate([rot, rng.standard_normal((200, 3, 1))], axis=2).reshape(200, 12)
    tokens = [[repr(float(v)) for v in row] for row in pose]
    path = tmp_path / "k.txt"
    path.write_text("\n".join(" ".join(r) for r in tokens) + "\n")
    want = np.array([[float(v) for v in r] for r in tokens]).reshape(-1, 3, 4)
    assert np.array_equal(load_kitti(path).position, want[:, :, 3])


def test_tum_stamps_all_decimal(tmp_path, tum):
    """Every stamp through pyarrow's decimal parse (no stamp with more than 9 decimals), negative ones too."""
    rows, _ = tum
    rows = [list(r) for r in rows[3:]] + [["1.7e9", *rows[5][1:]], ["-12.5", *rows[6][1:]]]
    path = tmp_path / "t.txt"
    path.write_text("\n".join(" ".join(r) for r in rows) + "\n")
    _check(load_tum(path), rows)


def test_stamp_beyond_int64_is_refused(tmp_path, tum):
    rows, _ = tum
    rows = [list(r) for r in rows[3:20]]
    rows[4][0] = "9300000000.5"  # 9.3e18 ns: past int64
    path = tmp_path / "t.txt"
    path.write_text("\n".join(" ".join(r) for r in rows) + "\n")
    with pytest.raises(InputError, match=r"row 5: timestamp '9300000000.5' is out of range"):
        load_tum(path)


def _outcome(path):
    """What ``load_tum`` makes of a file: its arrays, or its one-line error."""
    try:
        s = load_tum(path)
    except InputError as err:
        return str(err)
    return s.t_ns.tolist(), s.position.tobytes(), s.quat_xyzw.tobytes()


@pytest.mark.parametrize("char", list("#,\t\x0b\x0c\x1c\x1d\x1e\x1f"))
def test_separator_and_comment_characters_read_as_the_general_path_reads_them(tmp_path, tum, monkeypatch, char):
    """The fast path searches only the stamps' text for comment marks, commas and the other whitespace (every
    other field is parsed as a number, which refuses them but for a tab beside a number): wherever one stands in a
    line, the file reads as the general (pandas) path reads it."""
    rows, _ = tum
    base = [" ".join(r) for r in rows[3:23]]
    t, x, *rest = rows[10][:]
    places = [
        f"{char}{t} {x} {' '.join(rest)}",  # line start
        f"{t}{char} {x} {' '.join(rest)}",  # after the stamp
        f"{t[:4]}{char}{t[4:]} {x} {' '.join(rest)}",  # inside the stamp
        f"{t}{char}{x} {' '.join(rest)}",  # the stamp's separator
        f"{t} {char}{x} {' '.join(rest)}",  # before a number
        f"{t} {x}{char} {' '.join(rest)}",  # after a number
        f"{t} {x[:2]}{char}{x[2:]} {' '.join(rest)}",  # inside a number
        f"{t} {x} {' '.join(rest)}{char}",  # line end
        f"{t} {x} {' '.join(rest)} {char}",  # a field of its own at the end
    ]
    for k, line in enumerate(places):
        path = tmp_path / f"t{k}.txt"
        path.write_text("\n".join([*base[:7], line, *base[7:]]) + "\n")
        fast = _outcome(path)
        with monkeypatch.context() as m:
            m.setattr(trajectory_files, "_fast_rows", lambda *args: None)
            general = _outcome(path)
        assert fast == general, (repr(char), k, fast if isinstance(fast, str) else "", general)
