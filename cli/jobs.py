"""What the long commands that run many jobs (``batch``, ``tune``) share: exit codes and stopping on a signal
(the number of cores to use: :mod:`pipeline.cores`)."""

from __future__ import annotations

import os
import signal
import threading
from contextlib import contextmanager
from functools import partial

from slamobs.cli.errors import EXIT_CODES
from slamobs.pipeline.errors import BadInput, InfrastructureFailure, Interruption
from slamobs.pipeline.interrupts import after_critical

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
    """Signal handler of a long command: ignore further signals while it cleans up, stop with :class:`Stopped`, at
    once or, in a block that must not be cut in two (``interrupts.critical()``: a Dask cluster's close), as it ends."""
    for sig in EXIT_SIGNAL:  # a second signal must not cut the clean-up short (SIGKILL still can)
        signal.signal(sig, _ignored)
    if not after_critical(partial(_stop, signum)):
        _stop(signum)


def _stop(signum: int) -> None:
    raise Stopped(signum)


def _ignored(_signum, _frame) -> None:
    """A second signal while a stopped command cleans up: nothing. Not ``SIG_IGN``: an ignored signal stays ignored
    across exec, and the worker processes a starting local Dask cluster still spawned after the stop ignored SIGTERM,
    SIGHUP and SIGINT: multiprocessing's exit hook sent them SIGTERM and waited for them to finish importing and
    give up on their nanny (a SIGHUP while the cluster started: exit 11-50 s after the batch's line, load 20)."""


@contextmanager
def signals_to_the_main_thread():
    """While the block runs, a stop signal the kernel handed to another thread is sent on to the main thread.

    Python runs a handler in the main thread only, and a main thread waiting on a lock (distributed's ``sync()``
    while a local cluster starts) is woken only by a signal delivered to it: one that went to one of Dask's
    threads ran :func:`on_signal` when the wait returned, 2-8 s after a SIGHUP at load 8-20. The wakeup fd names
    every caught signal; a relay thread sends the first stop signal not yet handled to the main thread."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    read, write = os.pipe()
    os.set_blocking(write, False)
    old = signal.set_wakeup_fd(write, warn_on_full_buffer=False)
    main = threading.main_thread().ident

    def relay() -> None:
        while data := os.read(read, 1):
            if data[0] in EXIT_SIGNAL and signal.getsignal(data[0]) is on_signal:  # not yet handled
                signal.pthread_kill(main, data[0])
                return

    thread = threading.Thread(target=relay, name="slamobs signal relay", daemon=True)
    thread.start()
    try:
        yield
    finally:
        signal.set_wakeup_fd(old)
        os.close(write)  # the relay reads the end and returns
        thread.join(1.0)
        if not thread.is_alive():
            os.close(read)
