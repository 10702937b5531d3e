"""The UTIAS MR.CLAM dataset (Leung et al., IJRR 2011) as MCAP logs that every slamobs command reads.

A dataset folder holds, per robot ``N`` (1-5), ``RobotN_Odometry.dat`` (time, commanded forward and angular
velocity), ``RobotN_Measurement.dat`` (time, barcode, range, bearing) and ``RobotN_Groundtruth.dat`` (time, x,
y, heading from Vicon), and once ``Barcodes.dat`` (subject -> barcode) and ``Landmark_Groundtruth.dat`` (the
survey of the landmarks, subjects 6-20). Text columns separated by blanks, ``#`` comments.

One robot becomes one log (ROS 2 messages, CDR, definitions embedded):

* ``/robotN/velocity`` (geometry_msgs/TwistStamped, frame ``base_link``): the odometry, forward velocity along
  x and angular velocity about z (planar): both the angular and the linear velocity of a run;
* ``/robotN/landmarks`` (fiducial_msgs/FiducialTransformArray, frame ``base_link``): each measurement time's
  range-bearing pairs as points ``(r cos b, r sin b, 0)`` in the body frame, with the landmark's subject number
  as its id; measurements of the other robots (subjects 1-5) and of barcodes the dataset does not list are
  dropped and counted;
* ``/robotN/groundtruth`` (geometry_msgs/PoseStamped, frame ``world``): the Vicon poses, the run's truth;
* ``/slamobs/sim_truth`` (std_msgs/String, latched): the landmark survey as the JSON the readers take for
  landmark truth, so a run reports its map error against it.

Times are the dataset's (Unix seconds, millisecond resolution); every message is recorded at its stamp.
"""

from __future__ import annotations

import io
import json
import re
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from slamobs.pipeline.errors import InputError, one_line
from slamobs.pipeline.paths import read_text

#: Robots of a dataset and the subject numbers that are robots (the rest are landmarks).
ROBOTS = (1, 2, 3, 4, 5)
#: The MCAP header's library: ``--force`` replaces only a log this importer wrote.
WRITER = "slamobs-import-mrclam"
FRAME_BODY, FRAME_WORLD = "base_link", "world"
TOPIC_LANDMARK_TRUTH = "/slamobs/sim_truth"
TWIST, FIDUCIALS, POSE, STRING = (
    "geometry_msgs/msg/TwistStamped",
    "fiducial_msgs/msg/FiducialTransformArray",
    "geometry_msgs/msg/PoseStamped",
    "std_msgs/msg/String",
)


def topics(robot: int) -> dict[str, str]:
    """Topic -> message type of robot ``robot``'s log, latched landmark truth first."""
    return {
        TOPIC_LANDMARK_TRUTH: STRING,
        f"/robot{robot}/velocity": TWIST,
        f"/robot{robot}/landmarks": FIDUCIALS,
        f"/robot{robot}/groundtruth": POSE,
    }


@dataclass(frozen=True)
class Dataset:
    """The files of one MR.CLAM dataset folder that every robot shares."""

    folder: Path
    subject_of: dict[int, int]  # barcode -> subject
    landmark_ids: np.ndarray  # (L,) subject numbers
    landmark_xy: np.ndarray  # (L, 2) surveyed positions, m

    @property
    def robots(self) -> tuple[int, ...]:
        """The robots whose three files are in the folder."""
        return tuple(n for n in ROBOTS if all(_robot_file(self.folder, n, k).is_file() for k in _KINDS))


@dataclass(frozen=True)
class RobotLog:
    """One robot's streams, times in int64 nanoseconds."""

    robot: int
    odom_ns: np.ndarray  # (N,)
    odom: np.ndarray  # (N, 2) forward velocity m/s, angular velocity rad/s
    truth_ns: np.ndarray  # (K,)
    truth: np.ndarray  # (K, 3) x, y, heading
    det_ns: np.ndarray  # (M,) one per measurement kept
    det_ids: np.ndarray  # (M,) landmark subject numbers
    det_rb: np.ndarray  # (M, 2) range m, bearing rad
    other_robots: int  # measurements of other robots, dropped
    unknown: int  # measurements of barcodes the dataset does not list, dropped

    @property
    def frames(self) -> int:
        """Detection messages: one per measurement time."""
        return int(np.unique(self.det_ns).size)


_KINDS = ("Odometry", "Measurement", "Groundtruth")
_COLUMNS = {"Odometry": 3, "Measurement": 4, "Groundtruth": 4, "Barcodes": 2, "Landmark_Groundtruth": 5}


def _robot_file(folder: Path, robot: int, kind: str) -> Path:
    return folder / f"Robot{robot}_{kind}.dat"


def read_table(path: Path, kind: str) -> np.ndarray:
    """One ``.dat`` file as a float array with the columns its kind has; a one-line InputError otherwise."""
    if not path.is_file():
        raise InputError(path, f"missing: an MR.CLAM folder has {path.name} ({kind} data)")
    text = read_text(path, f"MR.CLAM {kind} file")
    want = _COLUMNS[kind]
    try:
        table = np.loadtxt(io.StringIO(text), comments="#", ndmin=2, dtype=np.float64)
    except ValueError as err:
        raise InputError(path, f"not an MR.CLAM {kind} file: {one_line(err)}") from None
    if table.size == 0:
        raise InputError(path, f"holds no {kind} rows")
    if table.shape[1] != want:
        raise InputError(path, f"{table.shape[1]} columns where an MR.CLAM {kind} file has {want}")
    bad = np.flatnonzero(~np.isfinite(table).all(axis=1))
    if bad.size:
        raise InputError(path, f"row {bad[0] + 1} of the data has a value that is not a finite number")
    return table


def _times(path: Path, seconds: np.ndarray) -> np.ndarray:
    """Dataset seconds (millisecond resolution) as int64 ns; times that go backwards are bad input."""
    t_ns = np.round(seconds * 1e3).astype(np.int64) * 1_000_000
    back = np.flatnonzero(np.diff(t_ns) < 0)
    if back.size:
        raise InputError(path, f"time goes backwards at data row {back[0] + 2} ({seconds[back[0] + 1]:.3f} s)")
    if t_ns.size and t_ns[0] <= 0:
        raise InputError(path, f"time {seconds[0]:g} s is not a Unix time")
    return t_ns


def _dataset_folders(folder: Path) -> list[str]:
    """The names of ``folder``'s subfolders that are MR.CLAM datasets (they hold ``Barcodes.dat``)."""
    return sorted(p.name for p in folder.iterdir() if (p / "Barcodes.dat").is_file())


def read_dataset(folder: str | Path) -> Dataset:
    """The shared files of an MR.CLAM folder (barcodes, landmark survey)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(folder, "not a directory (expected an MR.CLAM dataset folder such as MRCLAM_Dataset6)")
    if not (folder / "Barcodes.dat").is_file() and (inner := _dataset_folders(folder)):
        # the folder of the datasets (as downloaded), not one of them
        named = ", ".join(inner[:4]) + (", ..." if len(inner) > 4 else "")
        raise InputError(
            folder,
            f"holds MR.CLAM dataset folders ({named}), not one dataset's files: give one, e.g. {folder / inner[0]}",
        )
    codes = read_table(folder / "Barcodes.dat", "Barcodes").astype(np.int64)
    if np.unique(codes[:, 1]).size != len(codes):
        raise InputError(folder / "Barcodes.dat", "a barcode is listed for more than one subject")
    survey = read_table(folder / "Landmark_Groundtruth.dat", "Landmark_Groundtruth")
    ids = survey[:, 0].astype(np.int64)
    if np.unique(ids).size != ids.size or (ids <= max(ROBOTS)).any():
        raise InputError(folder / "Landmark_Groundtruth.dat", "landmark subjects repeat or include robots (1-5)")
    ds = Dataset(folder, {int(b): int(s) for s, b in codes}, ids, survey[:, 1:3].copy())
    if not ds.robots:
        raise InputError(folder, "no robot's Odometry, Measurement and Groundtruth files (RobotN_*.dat)")
    return ds


def read_robot(ds: Dataset, robot: int) -> RobotLog:
    """Robot ``robot``'s odometry, measurements (landmarks only) and Vicon truth."""
    if robot not in ds.robots:
        raise InputError(ds.folder, f"robot {robot} has no files here (robots: {', '.join(map(str, ds.robots))})")
    files = {kind: _robot_file(ds.folder, robot, kind) for kind in _KINDS}
    odom, meas, truth = (read_table(files[k], k) for k in _KINDS)
    subjects = np.array([ds.subject_of.get(int(b), -1) for b in meas[:, 1]], np.int64)
    robots = np.isin(subjects, ROBOTS)
    keep = np.isin(subjects, ds.landmark_ids)
    if (meas[keep, 2] <= 0).any():
        raise InputError(files["Measurement"], "a range is not positive")
    return RobotLog(
        robot,
        _times(files["Odometry"], odom[:, 0]),
        odom[:, 1:3].copy(),
        _times(files["Groundtruth"], truth[:, 0]),
        truth[:, 1:4].copy(),
        _times(files["Measurement"], meas[keep, 0]),
        subjects[keep],
        meas[keep, 2:4].copy(),
        int(robots.sum()),
        int((~keep & ~robots).sum()),
    )


def landmark_truth_json(ds: Dataset) -> str:
    """The survey as the readers' landmark truth (``{"landmarks": {id: [x, y, 0]}}``), with its source."""
    marks = {str(int(i)): [float(x), float(y), 0.0] for i, (x, y) in zip(ds.landmark_ids, ds.landmark_xy)}
    return json.dumps({"landmarks": marks, "source": f"MR.CLAM {ds.folder.name}/Landmark_Groundtruth.dat"})


def _stamp_columns(t_ns: np.ndarray) -> dict[tuple[str, ...], np.ndarray]:
    return {("header", "stamp", "sec"): t_ns // 1_000_000_000, ("header", "stamp", "nanosec"): t_ns % 1_000_000_000}


class _Messages:
    """The serialised messages of one robot's log."""

    def __init__(self, ds: Dataset, log: RobotLog, ts) -> None:
        self.ds, self.log, self.ts = ds, log, ts
        t = ts.types
        self.Time, self.Header = t["builtin_interfaces/msg/Time"], t["std_msgs/msg/Header"]
        self.Vector3, self.Quaternion = t["geometry_msgs/msg/Vector3"], t["geometry_msgs/msg/Quaternion"]

    def header(self, t_ns: int, frame: str):
        return self.Header(stamp=self.Time(sec=int(t_ns // 10**9), nanosec=int(t_ns % 10**9)), frame_id=frame)

    def serialize(self, msg, msgtype: str) -> bytes:
        return bytes(self.ts.serialize_cdr(msg, msgtype))

    def velocity(self) -> np.ndarray:
        """TwistStamped rows: v along x, omega about z."""
        from slamobs.pipeline.simulate.logwriter import fixed_rows

        t, log = self.ts.types, self.log
        zero = self.Vector3(x=0.0, y=0.0, z=0.0)
        template = t[TWIST](
            header=self.header(int(log.odom_ns[0]), FRAME_BODY),
            twist=t["geometry_msgs/msg/Twist"](linear=zero, angular=zero),
        )
        n = log.odom_ns.size
        cols = {
            **_stamp_columns(log.odom_ns),
            ("twist", "linear", "x"): log.odom[:, 0],
            ("twist", "linear", "y"): np.zeros(n),
            ("twist", "linear", "z"): np.zeros(n),
            ("twist", "angular", "x"): np.zeros(n),
            ("twist", "angular", "y"): np.zeros(n),
            ("twist", "angular", "z"): log.odom[:, 1],
        }
        return fixed_rows(self.ts, TWIST, self.serialize(template, TWIST), cols, ros1=False)

    def truth(self) -> np.ndarray:
        """PoseStamped rows: the Vicon position at z = 0 and the heading as a rotation about z."""
        from slamobs.pipeline.simulate.logwriter import fixed_rows

        t, log = self.ts.types, self.log
        pose = t["geometry_msgs/msg/Pose"](
            position=t["geometry_msgs/msg/Point"](x=0.0, y=0.0, z=0.0),
            orientation=self.Quaternion(x=0.0, y=0.0, z=0.0, w=1.0),
        )
        template = t[POSE](header=self.header(int(log.truth_ns[0]), FRAME_WORLD), pose=pose)
        n, half = log.truth_ns.size, log.truth[:, 2] / 2
        cols = {
            **_stamp_columns(log.truth_ns),
            ("pose", "position", "x"): log.truth[:, 0],
            ("pose", "position", "y"): log.truth[:, 1],
            ("pose", "position", "z"): np.zeros(n),
            ("pose", "orientation", "x"): np.zeros(n),
            ("pose", "orientation", "y"): np.zeros(n),
            ("pose", "orientation", "z"): np.sin(half),
            ("pose", "orientation", "w"): np.cos(half),
        }
        return fixed_rows(self.ts, POSE, self.serialize(template, POSE), cols, ros1=False)

    def detections(self, lo: int, hi: int) -> bytes:
        """The measurements ``lo:hi`` (one time) as one FiducialTransformArray."""
        t, log = self.ts.types, self.log
        rot = self.Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)
        items = []
        for k in range(lo, hi):
            r, b = log.det_rb[k]
            xyz = self.Vector3(x=float(r * np.cos(b)), y=float(r * np.sin(b)), z=0.0)
            items.append(
                t["fiducial_msgs/msg/FiducialTransform"](
                    fiducial_id=int(log.det_ids[k]),
                    transform=t["geometry_msgs/msg/Transform"](translation=xyz, rotation=rot),
                    image_error=0.0,
                    object_error=0.0,
                    fiducial_area=0.0,
                )
            )
        msg = t[FIDUCIALS](header=self.header(int(log.det_ns[lo]), FRAME_BODY), image_seq=0, transforms=items)
        return self.serialize(msg, FIDUCIALS)

    def landmark_truth(self) -> bytes:
        return self.serialize(self.ts.types[STRING](data=landmark_truth_json(self.ds)), STRING)


def messages(ds: Dataset, log: RobotLog, ts) -> Iterator[tuple[str, int, bytes]]:
    """``(topic, record ns, CDR bytes)`` of robot ``log``'s MCAP in record-time order (ties in topic order)."""
    names = list(topics(log.robot))
    make = _Messages(ds, log, ts)
    starts = np.flatnonzero(np.r_[True, np.diff(log.det_ns) != 0]) if log.det_ns.size else np.zeros(0, np.int64)
    ends = np.r_[starts[1:], log.det_ns.size].astype(np.int64)
    first = min(int(log.odom_ns[0]), int(log.truth_ns[0]), *(log.det_ns[:1].tolist()))
    rows = {1: make.velocity(), 3: make.truth()}
    stamps = [np.array([first]), log.odom_ns, log.det_ns[starts], log.truth_ns]
    rec = np.concatenate(stamps)
    which = np.concatenate([np.full(s.size, k) for k, s in enumerate(stamps)])
    index = np.concatenate([np.arange(s.size) for s in stamps])
    for j in np.lexsort((index, which, rec)):
        k, i = int(which[j]), int(index[j])
        if k == 0:
            data = make.landmark_truth()
        elif k == 2:
            data = make.detections(int(starts[i]), int(ends[i]))
        else:
            data = rows[k][i].tobytes()
        yield names[k], int(rec[j]), data


def why_kept(path: Path, *, overwrite: bool) -> str | None:
    """Why an existing ``path`` must not be replaced: anything without ``overwrite``, and anything but a log this
    importer wrote (:func:`.writers.kept_unless`)."""
    from slamobs.pipeline.readers.mcap import mcap_library
    from slamobs.pipeline.writers import kept_unless

    return kept_unless(
        lambda head: mcap_library(head) == WRITER,
        "exists and is not a log slamobs import wrote: --force replaces only those",
        force=overwrite,
        links=False,
    )(path)


@dataclass(frozen=True)
class Imported:
    """What one robot's import wrote."""

    path: Path
    robot: int
    seconds: float
    counts: dict[str, int]  # topic -> messages
    observations: int  # landmark measurements kept
    other_robots: int
    unknown: int

    def line(self) -> str:
        counts = ", ".join(f"{t} {n}" for t, n in self.counts.items())
        return (
            f"wrote {self.path} (robot {self.robot}, {self.seconds:.0f} s): {counts}; {self.observations} landmark "
            f"observations, dropped {self.other_robots} of other robots and {self.unknown} of unlisted barcodes"
        )


def import_robot(
    ds: Dataset,
    robot: int,
    out: str | Path,
    *,
    overwrite: bool = False,
    progress: Callable[[str], None] | None = None,
) -> Imported:
    """Write robot ``robot`` of ``ds`` as the MCAP ``out`` (a temporary name, renamed when complete)."""
    from functools import partial

    from slamobs.pipeline.simulate.logwriter import make_typestore, write_mcap
    from slamobs.pipeline.writers import atomic_file

    say = progress or (lambda _msg: None)
    say(f"reading robot {robot} of {ds.folder.name}")
    log = read_robot(ds, robot)
    ts = make_typestore(ros1=False)
    say(f"writing robot {robot} to {Path(out).name}")
    with atomic_file(Path(out), why_kept=partial(why_kept, overwrite=overwrite)) as tmp:
        types = topics(robot)
        write_mcap(tmp, types, messages(ds, log, ts), ts, latched={TOPIC_LANDMARK_TRUTH}, library=WRITER)
    counts = dict(zip(types, (1, log.odom_ns.size, log.frames, log.truth_ns.size)))
    span = (max(log.odom_ns[-1], log.truth_ns[-1]) - min(log.odom_ns[0], log.truth_ns[0])) / 1e9
    return Imported(Path(out), robot, float(span), counts, int(log.det_ns.size), log.other_robots, log.unknown)


def robot_number(text: str) -> int | None:
    """``--robot`` as a robot number, None for ``all``; ValueError otherwise."""
    if text.strip().lower() == "all":
        return None
    if not re.fullmatch(r"\s*[1-5]\s*", text):
        raise ValueError(f"{text!r} is not a robot number 1-5 or 'all'")
    return int(text)


__all__ = [
    "Dataset",
    "Imported",
    "RobotLog",
    "import_robot",
    "landmark_truth_json",
    "messages",
    "read_dataset",
    "read_robot",
    "robot_number",
    "topics",
    "why_kept",
]
