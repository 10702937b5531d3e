"""One error hierarchy: every exception class of slamobs derives from SlamobsError through one kind, the old
bases still catch what they caught, and the CLI's boundary gives each kind its exit code and one line."""

from __future__ import annotations

import importlib
import inspect
import pkgutil
import signal

import pytest

import slamobs
from slamobs.cli.errors import EXIT_CODES, exit_code, handled
from slamobs.pipeline import errors
from slamobs.pipeline.errors import (
    BadConfig,
    BadInput,
    BadOutput,
    InfrastructureFailure,
    InputError,
    Interruption,
    OutputError,
    ResourceError,
    ResourceFailure,
    SlamobsError,
    kind_of,
)

#: The kind each exception class of the project has (module, class name).
EXPECTED = {
    ("pipeline.errors", "InputError"): BadInput,
    ("pipeline.errors", "OutputError"): BadOutput,
    ("pipeline.errors", "GainError"): BadConfig,
    ("pipeline.errors", "TruthUnusable"): BadInput,
    ("pipeline.errors", "ResourceError"): ResourceFailure,
    ("pipeline.readers.storage", "DamagedError"): BadInput,
    ("pipeline.readers.storage", "TimeRangeError"): BadInput,
    ("pipeline.readers.fastdecode", "DecodeError"): BadInput,
    ("pipeline.vision.detector", "ImageError"): BadInput,
    ("pipeline.observers.base", "ObserverDiverged"): BadInput,
    ("pipeline.tune.study", "TuneFailed"): BadInput,
    ("pipeline.batch.runner", "DaskMissing"): BadConfig,
    ("pipeline.batch.executor", "EnvironmentMismatch"): InfrastructureFailure,
    ("pipeline.batch.executor", "InfrastructureError"): InfrastructureFailure,
    ("pipeline.interrupts", "Interrupted"): Interruption,
    ("cli.jobs", "Stopped"): Interruption,
}


def _project_exceptions() -> dict[tuple[str, str], type]:
    """Every exception class defined in a slamobs module (modules needing an absent extra are skipped)."""
    found = {}
    for info in pkgutil.walk_packages(slamobs.__path__, "slamobs."):
        try:
            module = importlib.import_module(info.name)
        except ImportError:
            continue
        for name, obj in vars(module).items():
            if inspect.isclass(obj) and issubclass(obj, BaseException) and obj.__module__ == info.name:
                found[(info.name.removeprefix("slamobs."), name)] = obj
    return found


def _kind(cls: type) -> type | None:
    return next((c for c in cls.__mro__ if c in errors.KINDS), None)


def test_every_project_exception_derives_from_one_kind_of_slamobs_error():
    found = {
        key: cls for key, cls in _project_exceptions().items() if cls is not SlamobsError and cls not in errors.KINDS
    }
    assert set(EXPECTED) <= set(found), f"not found: {set(EXPECTED) - set(found)}"
    unwinds = {key for key, cls in found.items() if issubclass(cls, errors.Unwind) and cls is not errors.Unwind}
    assert all(n.startswith("_") for _, n in unwinds), f"an Unwind is private to its module: {unwinds}"
    found = {key: cls for key, cls in found.items() if key not in unwinds and cls is not errors.Unwind}
    outside = [f"{m}.{n}" for (m, n), cls in found.items() if not issubclass(cls, SlamobsError)]
    assert not outside, f"exceptions outside the hierarchy: {outside}"
    wrong = {f"{m}.{n}": _kind(cls) for (m, n), cls in found.items() if _kind(cls) is not EXPECTED.get((m, n))}
    assert not wrong, f"exceptions of another kind than expected (add new ones to EXPECTED): {wrong}"


def test_old_bases_catch_what_they_caught():
    """``except InputError`` still catches output and resource errors; the standard bases are kept."""
    assert issubclass(OutputError, InputError) and issubclass(ResourceError, InputError)
    assert not issubclass(errors.GainError, InputError)
    assert issubclass(errors.GainError, ValueError)
    assert issubclass(Interruption, KeyboardInterrupt) and not issubclass(Interruption, Exception)
    for kind in (BadInput, BadConfig, BadOutput, ResourceFailure, InfrastructureFailure):
        assert issubclass(kind, Exception)


def _exit(err: BaseException, capsys) -> tuple[int, str]:
    with pytest.raises(SystemExit) as stop, handled():
        raise err
    return stop.value.code, capsys.readouterr().err.strip()


@pytest.mark.parametrize(
    ("make", "code"),
    [
        (lambda: InputError("log.bag", "not a log", "/imu"), 2),
        (lambda: OutputError("out", "exists already"), 2),
        (lambda: ResourceError("out", "no space left on device"), 2),
        (lambda: errors.GainError("unknown gain 'k_q'"), 2),
        (lambda: importlib.import_module("slamobs.pipeline.readers.fastdecode").DecodeError("message too short"), 2),
        (lambda: importlib.import_module("slamobs.pipeline.batch.runner").DaskMissing("install dask"), 2),
        (lambda: importlib.import_module("slamobs.pipeline.batch.executor").InfrastructureError("workers lost"), 3),
    ],
)
def test_cli_boundary_maps_each_kind_to_its_exit_code_and_one_line(make, code, capsys):
    err = make()
    assert exit_code(err) == EXIT_CODES[kind_of(err)] == code
    got, text = _exit(err, capsys)
    assert got == code
    assert text == f"error: {err}" and "\n" not in text


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_cli_boundary_maps_an_interruption_to_128_plus_the_signal(signum, capsys):
    from slamobs.pipeline.interrupts import Interrupted

    err = Interrupted(signum)
    assert exit_code(err) == 128 + signum
    got, text = _exit(err, capsys)
    assert got == 128 + signum
    assert text.startswith(f"interrupted ({signal.Signals(signum).name})")
