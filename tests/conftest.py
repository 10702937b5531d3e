"""The suite's environment: commands print their timed progress lines (`cli.progress`, every 10 s once a
command runs longer) only in the tests that check them (they set their own interval), so what a test reads of a
command's output does not depend on how loaded the machine is.

And the order in which `make test` hands test modules to its workers: the longest first."""

import os
from pathlib import Path

import pytest

os.environ.setdefault("SLAMOBS_PROGRESS_EVERY", "1e9")

#: The modules with the longest wall times, longest first (docs/benchmarks.md, "The suite's balance, session 24"):
#: the first compiles (CPU) and the kill, Dask and tune modules (mostly waits for processes). `make test` gives each
#: worker whole modules in collection order (``--dist loadscope --no-loadscope-reorder``), so these start first
#: and the short modules fill in around them; xdist's own order (most tests first) left the 4-test
#: test_interrupts_compile.py (~190 s) running alone at the end.
LONGEST_FIRST = (
    "test_interrupts_compile.py",
    "test_batch_kills_local.py",
    "test_batch_kills_dask.py",
    "test_batch_kills_local_cluster.py",
    "test_tune.py",
    "test_compile_ahead.py",
    "test_batch_integrity.py",
    "test_smoother.py",
    "test_reference_cli.py",
    "test_batch.py",
    "test_batch_hostile.py",
)


def pytest_collection_modifyitems(items):
    """The modules of :data:`LONGEST_FIRST` first, in its order; the rest after them as collected (a stable sort:
    the tests of a module keep their order). A listed module that is gone (renamed, split) stops the run."""
    gone = [name for name in LONGEST_FIRST if not (Path(__file__).parent / name).is_file()]
    if gone:
        raise pytest.UsageError(f"tests/conftest.py: LONGEST_FIRST names test modules that do not exist: {gone}")
    rank = {name: i for i, name in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))


@pytest.fixture
def drawn_figures(monkeypatch):
    """The matplotlib figures saved while a test runs, in order (each as it was when saved): a test draws a figure
    into a buffer and reads its axes, labels and layout from these."""
    from matplotlib.figure import Figure

    saved = []
    savefig = Figure.savefig
    monkeypatch.setattr(
        Figure, "savefig", lambda fig, *args, **kwargs: saved.append(fig) or savefig(fig, *args, **kwargs)
    )
    return saved
