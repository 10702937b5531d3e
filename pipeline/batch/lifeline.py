"""The loop of a local batch worker; binding it to its batch is :mod:`slamobs.pipeline.lifetime`'s job."""

from __future__ import annotations

import signal


def worker_main(_bound, conn, run) -> None:
    """A local worker (see :mod:`local`): ignores SIGINT, runs the tasks it is sent until told to stop.

    Sends ``("started", None)`` when it takes a task, then ``("row", row)``, or ``("mismatch", text)`` when
    it runs other slamobs code than its batch.
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    import gc

    from slamobs.pipeline.lifetime import collected_after_imports

    gc.enable()  # off since the worker's arrival (lifetime.arrived): its start-up arguments' imports are done
    # every log's run imports the pipeline: here at the start (the start-up has its own timeout), with the collector
    # off, the modules frozen out of the collections of every run that follows (lifetime.collected_after_imports)
    with collected_after_imports() as imported:
        from slamobs.pipeline.batch.executor import EnvironmentMismatch, failed_row, failure_text
        from slamobs.pipeline.batch.dataset import stage_tables  # noqa: F401 - each run's tables into the dataset
        from slamobs.pipeline.run import run_log  # noqa: F401

        imported()
        while True:
            try:
                task = conn.recv()
            except (EOFError, OSError):
                return
            if task is None:
                return
            conn.send(("started", None))  # the timeout counts from here, not from the worker's start-up
            try:
                result = ("row", run(task))
            except EnvironmentMismatch as err:
                result = ("mismatch", str(err))
            except Exception as err:  # noqa: BLE001 - run_task does not raise; a test's run function might
                result = ("row", failed_row(task, failure_text(err, task.log)))
            conn.send(result)
