"""What the long commands that run many jobs (``batch``, ``tune``) share: exit codes and stopping on a signal
(the number of cores to use: :mod:`pipeline.cores`)."""

from __future__ import annotations

import signal

from slamobs.cli.errors import EXIT_CODES
from slamobs.pipeline.errors import BadInput, InfrastructureFailure, Interruption

#: Exit codes (documented in --help and the README).
EXIT_OK, EXIT_FAILED = 0, 1
EXIT_USAGE, EXIT_INFRA = EXIT_CODES[BadInput], EXIT_CODES[InfrastructureFailure]  # 2, 3
EXIT_SIGNAL = {signal.SIGINT: 130, signal.SIGTERM: 143, signal.SIGHUP: 129}


class Stopped(Interruption):
    """SIGINT, SIGTERM or SIGHUP: the batch stops the same way for each (workers killed, runs so far kept)."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


def on_signal(signum, _frame) -> None:
    """Signal handler of a long command: ignore further signals while it cleans up, stop with :class:`Stopped`."""
    for sig in EXIT_SIGNAL:  # a second signal must not cut the clean-up short (SIGKILL still can)
        signal.signal(sig, _ignored)
    raise Stopped(signum)


def _ignored(_signum, _frame) -> None:
    """A second signal while a stopped command cleans up: nothing. Not ``SIG_IGN``: an ignored signal stays ignored
    across exec, and the worker processes a starting local Dask cluster still spawned after the stop ignored SIGTERM,
    SIGHUP and SIGINT: multiprocessing's exit hook sent them SIGTERM and waited for them to finish importing and
    give up on their nanny (a SIGHUP while the cluster started: exit 11-50 s after the batch's line, load 20)."""
