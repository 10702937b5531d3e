"""Outputs never delete what slamobs did not write (issue 28): what appears at OUT while a run works, a second run on
the same OUT, a directory of the user's files passed to ``--force``, and the commands that write single files.

Races use real processes: a run is started, stopped with SIGSTOP once its hidden ``.OUT.tmp-*`` exists (it is
then inside its observer stage, before publishing), the other party acts, and SIGCONT lets it finish.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from slamobs.pipeline.paths import MANIFEST, NAME_MAX
from slamobs.pipeline.simulate import simulate, write_log

SLAMOBS = Path(sys.executable).with_name("slamobs")
HANG = 300.0  # seconds after which a process that has not ended counts as hung (a loaded machine is slow)


def _default_signals() -> None:
    # as from a shell: a pytest-xdist worker may ignore SIGINT (inherited through exec)
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.signal(signal.SIGHUP, signal.SIG_DFL)


def _start(*args: object) -> subprocess.Popen:
    return subprocess.Popen(
        [str(SLAMOBS), *map(str, args)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=_default_signals,
    )


def _end(proc: subprocess.Popen) -> tuple[int, str]:
    try:
        _, err = proc.communicate(timeout=HANG)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate()
        pytest.fail("the command hung")
    return proc.returncode, err


def _cli(*args: object) -> tuple[int, str]:
    return _end(_start(*args))


def _one_line(code: int, err: str, *needles: str) -> str:
    assert code == 2, (code, err)
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])
    return lines[0]


def _temporaries(parent: Path, name: str) -> list[Path]:
    return [p for p in parent.iterdir() if p.name.startswith(f".{name}.tmp-")]


def _stopped_in_observer(proc: subprocess.Popen, parent: Path, name: str) -> None:
    """SIGSTOP the run as soon as its temporary output exists (it has checked OUT and not yet published)."""
    deadline = time.monotonic() + HANG
    while not _temporaries(parent, name):
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, "the run never reached the observer stage"
        time.sleep(0.01)
    proc.send_signal(signal.SIGSTOP)


@pytest.fixture(scope="module")
def log(tmp_path_factory) -> Path:
    base = tmp_path_factory.mktemp("own")
    return write_log(simulate("figure8", duration=6.0, seed=16, imu_rate=100.0), base / "f8.bag")


@pytest.fixture(scope="module")
def cfg(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("cfg") / "quick.yaml"
    path.write_text("evaluation:\n  plots: false\n")
    return path


@pytest.fixture(scope="module")
def earlier(log, cfg, tmp_path_factory) -> Path:
    """A complete run directory (with its manifest) to copy where a test needs an earlier run."""
    out = tmp_path_factory.mktemp("earlier") / "run"
    code, err = _cli("run", log, "-o", out, "--config", cfg, "-q")
    assert code == 0, err
    return out


def _copy_run(src: Path, dst: Path) -> None:
    import shutil

    shutil.copytree(src, dst)


def _tree(root: Path) -> dict[str, bytes | None]:
    return {str(p.relative_to(root)): (p.read_bytes() if p.is_file() else None) for p in sorted(root.rglob("*"))}


@pytest.mark.parametrize("what", ["directory", "file"])
def test_what_appears_at_out_during_a_run_is_kept(log, cfg, tmp_path, what):
    """The report: a user's directory (or file) made at OUT while the run worked was deleted and the run said
    'wrote precious/' (rc 0)."""
    out = tmp_path / "precious"
    proc = _start("run", log, "-o", out, "--config", cfg, "-q")
    _stopped_in_observer(proc, tmp_path, "precious")
    if what == "directory":
        out.mkdir()
        (out / "important.txt").write_text("data\n")
    else:
        out.write_text("data\n")
    proc.send_signal(signal.SIGCONT)
    code, err = _end(proc)
    _one_line(code, err, str(out), "appeared while this command was writing")
    assert (out / "important.txt" if what == "directory" else out).read_text() == "data\n"
    if what == "directory":
        assert sorted(p.name for p in out.iterdir()) == ["important.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["precious"]  # no temporary left


def test_a_second_run_on_the_same_out_is_refused(log, cfg, tmp_path):
    """Two runs on one -o without --force both said 'wrote same/' (rc 0): one output silently replaced the other.
    Now the one that finishes second is refused and the first one's output is intact."""
    out = tmp_path / "same"
    first = _start("run", log, "-o", out, "--config", cfg, "-q")
    _stopped_in_observer(first, tmp_path, "same")
    code, err = _cli("run", log, "-o", out, "--config", cfg, "-q")  # the second run, start to end
    assert code == 0, err
    published = _tree(out)
    first.send_signal(signal.SIGCONT)
    code, err = _end(first)
    _one_line(code, err, str(out), "appeared while this command was writing")
    assert _tree(out) == published
    assert sorted(p.name for p in tmp_path.iterdir()) == ["same"]


@pytest.mark.parametrize("change", ["replaced", "added"])
def test_force_replaces_only_the_run_it_checked(log, cfg, earlier, tmp_path, change):
    """--force swaps in the new run only if OUT is still the earlier run it checked: a directory put in its place,
    or a user's file added to it, while the run works is left as it is."""
    out = tmp_path / "out"
    _copy_run(earlier, out)
    proc = _start("run", log, "-o", out, "--config", cfg, "-q", "--force")
    _stopped_in_observer(proc, tmp_path, "out")
    if change == "replaced":
        os.rename(out, tmp_path / "moved")
        out.mkdir()
    (out / "thesis.tex").write_text("precious")
    expected = _tree(out)
    proc.send_signal(signal.SIGCONT)
    code, err = _end(proc)
    _one_line(code, err, str(out), "was replaced" if change == "replaced" else "thesis.tex")
    assert _tree(out) == expected
    assert not _temporaries(tmp_path, "out")


def test_force_refuses_a_directory_with_a_run_json_and_the_users_files(log, cfg, tmp_path):
    """The report: a run.json alone made a directory 'an earlier run', and --force deleted thesis.tex and src/."""
    proj = tmp_path / "proj"
    (proj / "src").mkdir(parents=True)
    (proj / "run.json").write_text("{}")
    (proj / "thesis.tex").write_text("x")
    before = _tree(proj)
    code, err = _cli("run", log, "-o", proj, "--config", cfg, "-q", "--force")
    _one_line(code, err, "not a slamobs output", "src", "not written by slamobs")
    assert _tree(proj) == before


def test_force_replaces_runs_it_wrote_and_refuses_changed_ones(log, cfg, earlier, tmp_path):
    """A run directory with its manifest is replaced; one whose files were changed or added to is not; one from
    before manifests is replaced only when every file has a name slamobs writes."""
    out = tmp_path / "out"
    _copy_run(earlier, out)
    doc = json.loads((out / MANIFEST).read_text())
    assert doc["writer"] == "slamobs" and doc["files"]["poses.parquet"] == (out / "poses.parquet").stat().st_size
    with open(out / "report.md", "a") as f:
        f.write("my notes\n")
    code, err = _cli("run", log, "-o", out, "--config", cfg, "-q", "--force")
    _one_line(code, err, "report.md", "changed since slamobs wrote it")
    _copy_run(earlier, tmp_path / "ok")
    code, err = _cli("run", log, "-o", tmp_path / "ok", "--config", cfg, "-q", "--force")
    assert code == 0, err
    legacy = tmp_path / "legacy"
    _copy_run(earlier, legacy)
    (legacy / MANIFEST).unlink()
    code, err = _cli("run", log, "-o", legacy, "--config", cfg, "-q", "--force")
    assert code == 0, err
    assert (legacy / MANIFEST).is_file()
    (legacy / MANIFEST).unlink()
    (legacy / "notes.txt").write_text("mine")
    code, err = _cli("run", log, "-o", legacy, "--config", cfg, "-q", "--force")
    _one_line(code, err, "notes.txt")
    assert (legacy / "notes.txt").read_text() == "mine"


def test_sighup_is_handled_like_sigterm(log, cfg, tmp_path):
    """The report: SIGHUP exited 129 with no message and left the hidden temporary until the next run."""
    proc = _start("run", log, "-o", tmp_path / "out", "--config", cfg, "-q")
    _stopped_in_observer(proc, tmp_path, "out")
    proc.send_signal(signal.SIGHUP)
    proc.send_signal(signal.SIGCONT)
    code, err = _end(proc)
    assert code == 129, err
    assert err.strip().splitlines() == [
        "interrupted (SIGHUP): stopped; nothing was written and an existing output is unchanged"
    ]
    assert list(tmp_path.iterdir()) == []


def test_a_name_of_any_valid_length_gets_its_temporary(log, cfg, tmp_path):
    """The report: a valid 250-character OUT was refused because '.NAME.tmp-XXXXXXXX' was too long."""
    name = "r" * 250
    code, err = _cli("run", log, "-o", tmp_path / name, "--config", cfg, "-q")
    assert code == 0, err
    assert (tmp_path / name / "poses.parquet").is_file() and [p.name for p in tmp_path.iterdir()] == [name]
    code, err = _cli("run", log, "-o", tmp_path / ("r" * (NAME_MAX + 1)), "--config", cfg, "-q")
    _one_line(code, err, f"longer than {NAME_MAX} bytes")


def test_an_out_name_that_is_not_utf8(log, cfg, tmp_path):
    """The report: a byte that is not UTF-8 in OUT's name gave a UnicodeEncodeError traceback (pyarrow opens only
    UTF-8 paths). The run now writes it (its temporary has a UTF-8 name); report, which reads it with pyarrow, says
    so in one line."""
    out = Path(os.fsdecode(bytes(tmp_path) + b"/bad\xffname"))
    code, err = _cli("run", log, "-o", out, "--config", cfg, "-q")
    assert code == 0, err
    assert (out / "poses.parquet").is_file() and os.listdir(tmp_path) == [out.name]
    code, err = _cli("report", out)
    _one_line(code, err, "not UTF-8 (0xff)")


def test_report_refuses_a_run_missing_a_table(earlier, tmp_path):
    """The report: with landmarks.parquet deleted, `report` exited 0, dropped the map section and deleted
    landmarks_aligned.parquet (and landmarks.png) without a word."""
    run = tmp_path / "run"
    _copy_run(earlier, run)
    (run / "landmarks.parquet").unlink()
    before = _tree(run)
    assert "landmarks_aligned.parquet" in before
    code, err = _cli("report", run)
    _one_line(code, err, str(run / "landmarks.parquet"), "missing")
    assert _tree(run) == before


@pytest.fixture
def full_disk(tmp_path):
    """A directory on a file system with no space left (a small tmpfs filled up); skipped where it cannot be
    mounted (not root, or no mount in this container)."""
    where = tmp_path / "full"
    where.mkdir()
    if (
        os.geteuid() != 0
        or subprocess.run(
            ["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(where)], capture_output=True, timeout=30
        ).returncode
        != 0
    ):
        pytest.skip("cannot mount a small tmpfs here")
    try:
        with pytest.raises(OSError, match="No space left"):  # noqa: PT012 - until the file system is full
            with open(where / ".filler", "wb", buffering=0) as f:
                while True:
                    f.write(b"\0" * 4096)
        yield where
    finally:
        subprocess.run(["umount", str(where)], capture_output=True, timeout=30)


def test_a_full_disk_names_the_file(log, earlier, tmp_path, full_disk):
    """export / evaluate / simulate on a full disk said 'No space left on device' without the file."""
    cases = {
        "export": ("export", earlier, "--mcap", full_disk / "r.mcap"),
        "evaluate": (
            "evaluate",
            f"{log}:/mocap/pose",
            earlier / "poses.parquet",
            "-q",
            "--save-results",
            full_disk / "ape.zip",
        ),
        "simulate": ("simulate", "circle", "--duration", "1", "-q", "-o", full_disk / "s.mcap"),
    }
    for args in cases.values():
        code, err = _cli(*args)
        _one_line(code, err, str(args[-1]), "No space left on device")
        assert os.listdir(full_disk) == [".filler"], args


def test_single_file_outputs_replace_only_what_slamobs_wrote(log, earlier, tmp_path):
    """export --force, evaluate --save-results and simulate --force replaced (or deleted) whatever was at the
    path; now only a file of their own kind that slamobs wrote."""
    from mcap.writer import Writer

    user = tmp_path / "user.mcap"  # a log recorded by ROS, not slamobs's
    with open(user, "wb") as f:
        recorder = Writer(f)
        recorder.start(profile="ros2", library="rosbag2_storage_mcap")
        recorder.finish()
    recorded = user.read_bytes()
    code, err = _cli("export", earlier, "--mcap", user, "--force")
    _one_line(code, err, str(user), "not a results MCAP slamobs wrote")
    code, err = _cli("simulate", "circle", "--duration", "1", "-q", "-o", user, "--force")
    _one_line(code, err, str(user), "not a log slamobs simulate wrote")
    assert user.read_bytes() == recorded
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("x")
    code, err = _cli("simulate", "circle", "--duration", "1", "-q", "-o", mine, "--force")
    _one_line(code, err, str(mine), "not a log slamobs simulate wrote")
    assert os.listdir(mine) == ["notes.txt"]
    archive = tmp_path / "ape.zip"
    archive.write_text("mine")
    truth = f"{log}:/mocap/pose"
    code, err = _cli("evaluate", truth, earlier / "poses.parquet", "-q", "--save-results", archive)
    _one_line(code, err, str(archive), "not a result archive slamobs wrote")
    assert archive.read_text() == "mine"
    archive.unlink()
    for _ in range(2):  # its own archive and results MCAP are replaced
        assert _cli("evaluate", truth, earlier / "poses.parquet", "-q", "--save-results", archive)[0] == 0
        assert _cli("export", earlier, "--mcap", tmp_path / "r.mcap", "--force")[0] == 0
    assert sorted(os.listdir(tmp_path)) == ["ape.zip", "mine", "r.mcap", "user.mcap"]


def test_report_replaces_only_its_own_files(earlier, tmp_path):
    """A re-report replaced or removed its file names whoever wrote them; with a manifest, a file the user edited
    (or put there under such a name) is named and kept. An unchanged run is re-reported and its manifest kept
    current, so a later --force still replaces it."""
    run = tmp_path / "run"
    _copy_run(earlier, run)
    assert _cli("report", run, "-q", "--export", "tum")[0] == 0
    doc = json.loads((run / MANIFEST).read_text())
    assert doc["files"]["estimate_tum.txt"] == (run / "estimate_tum.txt").stat().st_size
    assert doc["files"]["run.json"] == (run / "run.json").stat().st_size
    (run / "estimate_tum.txt").write_text("my own edits\n")
    before = _tree(run)
    code, err = _cli("report", run, "-q", "--export", "none")
    _one_line(code, err, str(run / "estimate_tum.txt"), "not written by slamobs")
    assert _tree(run) == before


@pytest.mark.parametrize("renameat2", [True, False], ids=["renameat2", "plain-renames"])
def test_publish_replaces_only_the_checked_entry(tmp_path, monkeypatch, renameat2):
    """The publishing step on its own, with renameat2 and without it (other systems, file systems without the
    flags): nothing is replaced but the entry checked, unchanged; what appeared or changed is put back as it was."""
    from slamobs.pipeline import writers
    from slamobs.pipeline.errors import OutputError
    from slamobs.pipeline.paths import foreign_entry, identity

    if renameat2 and writers.RENAMEAT2 is None:
        pytest.skip("no renameat2 on this system")
    if not renameat2:
        monkeypatch.setattr(writers, "RENAMEAT2", None)

    def new(name: str) -> Path:
        (tmp_path / name).mkdir()
        (tmp_path / name / "run.json").write_text(name)
        return tmp_path / name

    out, aside = tmp_path / "out", tmp_path / "aside"
    import shutil

    for kind in ("directory", "file"):  # appeared where nothing was checked: kept
        users = out / "important.txt" if kind == "directory" else out
        users.parent.mkdir(exist_ok=True)
        users.write_text("user")
        with pytest.raises(OutputError, match="appeared"):
            writers.publish(new(f"n-{kind}"), out, None, aside=aside)
        assert users.read_text() == "user"
        assert (tmp_path / f"n-{kind}" / "run.json").is_file()  # ours stays with the caller
        if kind == "directory":
            shutil.rmtree(out)
        else:
            out.unlink()
    earlier = new("out")
    checked = identity(earlier)
    (out / "thesis.tex").write_text("user")  # added after the check
    with pytest.raises(OutputError, match="thesis.tex is not written by slamobs"):
        writers.publish(new("n1"), out, checked, aside=aside, owned=foreign_entry)
    assert sorted(os.listdir(out)) == ["run.json", "thesis.tex"] and not aside.exists()
    (out / "thesis.tex").unlink()
    os.rename(out, tmp_path / "moved")  # replaced after the check
    new("out")
    with pytest.raises(OutputError, match="was replaced"):
        writers.publish(new("n2"), out, checked, aside=aside, owned=foreign_entry)
    assert identity(out) != checked and not aside.exists()
    shutil.rmtree(out)
    os.rename(tmp_path / "moved", out)
    old = writers.publish(new("n3"), out, checked, aside=aside, owned=foreign_entry)  # the checked run: replaced
    assert (out / "run.json").read_text() == "n3" and identity(old) == checked


def test_a_kill_between_the_swap_and_its_check_deletes_nothing_of_the_users(tmp_path):
    """A SIGKILL right after --force's exchange, before the swapped-out directory was checked: the next run on the
    parent finds the user's directory (put at OUT while the run worked) in the dead run's temporary and swaps it
    back instead of deleting it with the temporary."""
    from slamobs.pipeline import writers

    if writers.RENAMEAT2 is None:
        pytest.skip("no renameat2 on this system")
    out = tmp_path / "out"
    out.mkdir()
    (out / "run.json").write_text('"old"')  # an earlier run (names slamobs writes)
    pid = os.fork()
    if pid == 0:  # the child: a --force run killed by a real SIGKILL just after the exchange
        try:
            exchange = writers.exchange

            def then_killed(a, b):
                done = exchange(a, b)
                os.kill(os.getpid(), signal.SIGKILL)
                return done

            writers.exchange = then_killed
            with writers.atomic_directory(out, force=True) as tmp:
                (tmp / "run.json").write_text('"new"')
                os.rename(out, tmp_path / "earlier")  # meanwhile the user puts a directory of theirs at OUT
                out.mkdir()
                (out / "thesis.tex").write_text("precious")
        finally:
            os._exit(0)
    _, status = os.waitpid(pid, 0)
    assert os.WIFSIGNALED(status) and os.WTERMSIG(status) == signal.SIGKILL
    assert json.loads((out / "run.json").read_text()) == "new"  # swapped, not checked
    assert writers.remove_stale_temporaries(tmp_path)  # what the next run on this parent does first
    assert sorted(os.listdir(out)) == ["thesis.tex"] and (out / "thesis.tex").read_text() == "precious"
    assert sorted(os.listdir(tmp_path)) == ["earlier", "out"]


def test_single_file_outputs_replace_only_their_own_kind(tmp_path):
    """``kept_unless``: without --force nothing is replaced; with it only a file whose head says slamobs wrote it,
    and the user's file stays untouched with the refusal as the one-line error."""
    from slamobs.pipeline.errors import OutputError
    from slamobs.pipeline.writers import atomic_file, kept_unless

    ours, theirs = tmp_path / "a.rrd", tmp_path / "b.rrd"
    ours.write_bytes(b"RRF2 old")
    theirs.write_bytes(b"notes")
    for force in (False, True):  # the user's file: the refusal either way, never "use --force" that would not help
        why = kept_unless(lambda head: head.startswith(b"RRF"), "is not a recording", force=force)
        with pytest.raises(OutputError, match="is not a recording"):
            with atomic_file(theirs, why_kept=why) as tmp:
                tmp.write_bytes(b"RRF2 new")
        assert theirs.read_bytes() == b"notes"
    with pytest.raises(OutputError, match="use --force"):  # slamobs' own file without --force
        with atomic_file(ours, why_kept=kept_unless(lambda head: head.startswith(b"RRF"), "-", force=False)) as tmp:
            tmp.write_bytes(b"RRF2 new")
    assert ours.read_bytes() == b"RRF2 old"
    with atomic_file(ours, why_kept=why) as tmp:
        tmp.write_bytes(b"RRF2 new")
    assert ours.read_bytes() == b"RRF2 new"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.rrd", "b.rrd"]  # no hidden temporary left


def test_kept_unless_judges_a_path_and_may_refuse_links(tmp_path):
    """The one ``why_kept`` of simulate and import too: ``nbytes=None`` hands the path to ``is_ours`` (a rosbag2
    directory has no first bytes), ``links=False`` never replaces a symbolic link, even to a file of ours."""
    from slamobs.pipeline.writers import kept_unless

    ours = tmp_path / "ours.mcap"
    ours.write_bytes(b"RRF2")
    link = tmp_path / "link.mcap"
    link.symlink_to(ours)
    by_head = kept_unless(lambda head: head.startswith(b"RRF"), "not ours")
    assert by_head(ours) is None and by_head(link) is None  # links followed by default (as before)
    assert kept_unless(lambda head: head.startswith(b"RRF"), "not ours", links=False)(link) == "not ours"
    seen = []
    by_path = kept_unless(lambda p: seen.append(p) or p.is_dir(), "not a bag", force=False, nbytes=None)
    assert by_path(tmp_path) == "exists already (use --force to replace it)" and seen == [tmp_path]
    assert by_path(ours) == "not a bag"
