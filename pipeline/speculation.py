"""The observer over the settled prefix of a log while the rest of it is read (issue 27): speculation with a check.

The readers hand over the rows decoded so far after each decoding group (``read_log(prefix=...)``); where they
cover the next stretch of ``STRETCH_SAMPLES`` velocity samples, a thread builds their streams as the readers
build the whole log's (:func:`.readers.prefix_streams`), aligns them as the run aligns the whole log, and runs the
observer's stretches whose samples and frames lie a margin before the prefix's end (:data:`SETTLE_NS`, plus
``max_meas_age``: what a segment start looks ahead). A later prefix takes over the run where it stands, and at the
end so does the whole log's stream, each only when it agrees with the stream the run has been on over everything
the run read so far and its next stretch reads (:func:`agrees`): samples, stamps, frames, landmark ids and
indices, segment starts, the most detections in a frame, the time origin, the observer's options. Where a prefix
differs from the one before (a landmark first seen later, a frame with more detections: a short log's first
prefixes), the run ahead starts again on it; where the whole log's stream differs (a message stamped earlier
than one read before it, a clock step, a duplicate, anything the whole log decides), the run starts from the
beginning as without speculation. So
the stretches are those of the staged run bit for bit, and every check the readers and the alignment make over
the whole log still runs on the whole log (the run's notes and warnings are the whole log's). Only for observers
whose stepper reads nothing else (``ObserverSpec.reads_prefix_only``), two cores or more, and runs whose options
do not depend on the whole log (no known map, time window or output rate).
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator, Mapping
from dataclasses import replace

import numpy as np

from slamobs.pipeline.alignment import AlignedStream
from slamobs.pipeline.observers.base import ObserverResult, joined, max_per_frame

#: Pieces of a stretch the run on a prefix advances by (joined into the stretch when it is complete): the first
#: prefix need not hold a whole stretch, and the run takes what each prefix settles.
PIECES = 4
#: No prefix is built past this many angular-velocity rows (~87 min at 200 Hz), and the run ahead stops at this
#: many samples (four stretches): on longer logs the read's end is far off, and a prefix built from its start and
#: the stretches held for the writer only cost CPU and memory there (the 4 h log gained no wall time either way).
MAX_PREFIX_ROWS, MAX_AHEAD = 1 << 20, 1 << 19
#: A stretch is run on a prefix when its last sample, plus ``max_meas_age``, lies this far before the prefix's end:
#: header stamps may come out of record order by less (a message stamped earlier arriving later is caught by the
#: check either way, and costs the speculation).
SETTLE_NS = 2_000_000_000


def agrees(ran: AlignedStream, other: AlignedStream, stop: int, ahead_ns: int) -> bool:
    """Whether ``other`` holds what a run on ``ran`` has read up to velocity sample ``stop`` and what a stretch
    from there reads ``ahead_ns`` past it (a segment start's look at the frames after it): the same arrays bit for
    bit over that range, the same landmarks, the same buffer sizes, the same time origin."""
    if ran.t0_ns != other.t0_ns or ran.body_frame != other.body_frame:
        return False
    if not np.array_equal(ran.landmark_ids, other.landmark_ids):
        return False
    if max_per_frame(ran.det_offsets) != max_per_frame(other.det_offsets):
        return False
    if stop + 1 >= ran.vel_t_ns.shape[0]:
        return False
    horizon = int(ran.vel_t_ns[stop]) + ahead_ns
    nv = min(int(np.searchsorted(ran.vel_t_ns, horizon, side="right")) + 1, ran.vel_t_ns.shape[0])
    nf = min(int(np.searchsorted(ran.det_t_ns, horizon, side="right")) + 1, ran.det_t_ns.shape[0])
    if nv > other.vel_t_ns.shape[0] or nf > other.det_t_ns.shape[0]:
        return False
    m = int(ran.det_offsets[nf])
    same = (
        np.array_equal(ran.vel_t_ns[:nv], other.vel_t_ns[:nv])
        and np.array_equal(ran.omega[:nv], other.omega[:nv])
        and np.array_equal(ran.velocity[:nv], other.velocity[:nv])
        and np.array_equal(ran.det_t_ns[:nf], other.det_t_ns[:nf])
        and np.array_equal(ran.det_offsets[: nf + 1], other.det_offsets[: nf + 1])
        and np.array_equal(ran.det_idx[:m], other.det_idx[:m])
        and np.array_equal(ran.det_y[:m], other.det_y[:m])
    )
    starts, others = ran.segment_starts, other.segment_starts
    return same and np.array_equal(starts[starts < nv], others[others < nv])


def settled_stop(aligned: AlignedStream, stop: int, ahead_ns: int) -> bool:
    """Whether a stretch ending at velocity sample ``stop`` lies settled in the prefix ``aligned``."""
    n = aligned.vel_t_ns.shape[0]
    if stop + 1 >= n or aligned.det_t_ns.shape[0] == 0:
        return False
    end = min(int(aligned.vel_t_ns[-1]), int(aligned.det_t_ns[-1]))
    return int(aligned.vel_t_ns[stop]) + ahead_ns + SETTLE_NS <= end


class Speculation:
    """The observer run on the log's prefixes on a thread while the log is read (:class:`.readers.PrefixConsumer`);
    :meth:`parts` then gives the run's stretches on the whole log's stream, the checked ones first."""

    def __init__(
        self,
        spec,
        gains: dict,
        align: Callable[[object], AlignedStream],
        options_for: Callable[[AlignedStream], object],
        samples: int,
        roles: tuple[str, ...],
    ) -> None:
        self.spec, self.gains, self.samples, self.roles = spec, gains, samples, roles
        self._piece = max(1, samples // PIECES)
        self._pieces: list[ObserverResult] = []  # of the stretch in hand
        self._align, self._options_for = align, options_for
        self._stepper = None
        self.options = None
        self._held: list[ObserverResult] = []
        self._stop = threading.Event()
        self._busy = False
        self._failed = False
        self._thread: threading.Thread | None = None
        #: how the speculation went: prefixes built, runs started again, whole stretches run ahead, whether the
        #: log's own stream took the run over and at which velocity sample
        self.summary: dict = {"prefixes": 0, "restarts": 0, "stretches": 0, "taken_over": False, "samples": 0}

    def wants(self, rows: Mapping[str, int]) -> bool:
        """A prefix is worth building when the thread is idle and the rows so far hold two pieces more than the run
        ahead has done (each prefix is built from its start: fewer, longer ones cost less), up to
        :data:`MAX_PREFIX_ROWS` and :data:`MAX_AHEAD`."""
        if self._busy or self._failed or self._stop.is_set() or rows.get("angular_velocity", 0) > MAX_PREFIX_ROWS:
            return False
        done = self._stepper.iv if self._stepper is not None else 0
        if done >= MAX_AHEAD:
            return False
        return rows.get("angular_velocity", 0) > done + 2 * self._piece

    def offer(self, build: Callable[[], object]) -> None:
        """Build, align and run the prefix on the thread (joined before the next one is offered)."""
        if self._thread is not None:
            self._thread.join()
        self._busy = True
        self._thread = threading.Thread(target=self._run, args=(build,), name="slamobs-speculate", daemon=True)
        self._thread.start()

    def _run(self, build: Callable[[], object]) -> None:
        try:
            streams = build()
            if streams is None:
                self._failed = True
                return
            aligned = self._align(streams)
            del streams
            self.summary["prefixes"] += 1
            self._take(aligned)
            self._ahead(aligned)
        except Exception:  # noqa: BLE001 - a prefix that fails says nothing: the whole log decides, as staged
            self._failed = True
        finally:
            self._busy = False

    def _take(self, aligned: AlignedStream) -> None:
        """The run onto the prefix ``aligned``: moved from the prefix before where they agree, else started again
        there (a landmark first seen in the new part, a frame with more detections: a short log's first prefixes)."""
        if self._stepper is not None and agrees(self._stepper.stream, aligned, self._stepper.iv, self._ahead_ns()):
            self._stepper.continue_on(aligned)
            return
        self.summary["restarts"] += self._stepper is not None
        self._held, self._pieces = [], []
        self.options = self._options_for(aligned)
        self._stepper = self.spec.start(aligned, self.gains, self.options)

    def _ahead_ns(self) -> int:
        return int(round(self.options.max_meas_age * 1e9))

    def _ahead(self, aligned: AlignedStream) -> None:
        """The pieces of stretches settled in ``aligned``; each stretch once complete held with the map as it was
        then."""
        stepper = self._stepper
        while not self._stop.is_set():
            end = (stepper.iv // self.samples + 1) * self.samples  # of the stretch in hand
            stop = min(stepper.iv + self._piece, end)
            if stop > MAX_AHEAD or not settled_stop(aligned, stop, self._ahead_ns()):
                return
            self._pieces.append(stepper.advance(stop))
            if stop == end:
                part = joined(self._pieces)
                self._pieces = []
                self._held.append(replace(part, landmark_xyz=np.array(part.landmark_xyz)))
                self.summary["stretches"] += 1

    def close(self) -> None:
        """Stop the thread after the piece in hand (before the whole log's stream takes over; a failed or interrupted
        run)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join()

    def parts(self, aligned: AlignedStream, gains: dict, options) -> Iterator[ObserverResult]:
        """The run's stretches on the whole log's ``aligned`` (``spec.chunks``' stretches): those run ahead when
        the stream agrees with the prefix they ran on, and the run goes on from there; else all run here."""
        self.close()
        stepper = self._stepper
        taken = (
            stepper is not None
            and not self._failed
            and gains == self.gains
            and options == self.options
            and agrees(stepper.stream, aligned, stepper.iv, self._ahead_ns())
        )
        if not taken:
            self._held, self._pieces = [], []
            yield from self.spec.chunks(aligned, gains, options, self.samples)
            return
        self.summary["taken_over"], self.summary["samples"] = True, stepper.iv
        held, self._held = self._held, []
        while held:
            yield held.pop(0)
        stepper.continue_on(aligned)
        pieces, self._pieces = self._pieces, []
        for stop in range(-(-stepper.iv // self.samples) * self.samples, stepper.n_vel + self.samples, self.samples):
            if stop > stepper.iv:  # the stretch in hand completed, then whole ones
                yield joined([*pieces, stepper.advance(stop)])
                pieces = []
