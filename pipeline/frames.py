"""Transforms between frames, as tf2 would give them, without ROS: a buffer of static and time-stamped edges.

Static edges come from ``/tf_static``, time-stamped ones from ``/tf``. A lookup walks the frame graph in
either direction (an edge used child -> parent is inverted) and composes the edges; a time-stamped edge is
interpolated at the query times (linear translation, slerp rotation). A chain made of static edges only is
preferred over any chain through ``/tf``, and a pair published both ways keeps its static value, because a
static extrinsic that is also re-published on ``/tf`` is the same transform. Outside a time-stamped edge's
span nothing is extrapolated: the lookup says which samples are outside, and the caller either drops them or
holds the nearest value (``hold=True``).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from slamobs.pipeline.kernel_cache import njit

from slamobs.pipeline.errors import InputError
from slamobs.pipeline.lie import mat3_mul, quats_to_rots, rots_to_quats, so3_exp, so3_log
from slamobs.pipeline.streams import PoseStream, Transform, TransformSeries

if TYPE_CHECKING:
    from collections.abc import Iterable


def _strip(frame: str) -> str:
    """TF frame ids are compared without a leading slash (ROS1 logs often carry one)."""
    return frame.lstrip("/")


@dataclass(frozen=True)
class _Edge:
    """``x_parent = rot[k] x_child + trans[k]``; static edges hold one sample and no times."""

    parent: str
    child: str
    rot: np.ndarray  # (K, 3, 3)
    trans: np.ndarray  # (K, 3)
    t_ns: np.ndarray | None = None  # (K,) strictly increasing; None = static
    rec_ns: np.ndarray | None = None
    topic: str = "/tf_static"

    @property
    def static(self) -> bool:
        return self.t_ns is None


@dataclass(frozen=True)
class Lookup:
    """Transforms ``x_target = rot[k] x_source + trans[k]`` at each query time.

    ``valid[k]`` is False where a time-stamped edge of the chain had no sample around the query time (the
    values there hold the nearest sample). ``dynamic`` names the ``/tf`` edges the chain used.
    """

    rot: np.ndarray  # (N, 3, 3)
    trans: np.ndarray  # (N, 3)
    valid: np.ndarray  # (N,) bool
    dynamic: tuple[str, ...] = ()


@njit(cache=True)
def _interpolate(t_edge, rots, trans, t_query, out_r, out_t, valid):  # noqa: ANN001, ANN202
    """Edge samples at ``t_query``: lerp translation, slerp rotation ``R0 exp(a log(R0^T R1))``; hold outside."""
    n = t_edge.shape[0]
    for k in range(t_query.shape[0]):
        tq = t_query[k]
        i = np.searchsorted(t_edge, tq)
        if i < n and t_edge[i] == tq:
            out_r[k] = rots[i]
            out_t[k] = trans[i]
            valid[k] = True
        elif i == 0 or i == n:
            j = 0 if i == 0 else n - 1
            out_r[k] = rots[j]
            out_t[k] = trans[j]
            valid[k] = False
        else:
            a = (tq - t_edge[i - 1]) / (t_edge[i] - t_edge[i - 1])
            r0 = rots[i - 1]
            delta = so3_log(mat3_mul(r0.T.copy(), rots[i]))
            out_r[k] = mat3_mul(r0, so3_exp(a * delta))
            out_t[k] = (1.0 - a) * trans[i - 1] + a * trans[i]
            valid[k] = True


class TfBuffer:
    """Static and time-stamped transforms of one log, looked up through chains of frames.

    ``time_source="record"`` interpolates ``/tf`` edges on their record times instead of their header stamps,
    to match streams aligned on record time.
    """

    def __init__(
        self,
        static: Iterable[Transform] = (),
        dynamic: Iterable[TransformSeries] = (),
        *,
        path: str = "",
        time_source: str = "header",
    ) -> None:
        self.path = path
        self.notes: list[str] = []
        self._edges: dict[tuple[str, str], _Edge] = {}
        for tf in static:
            rot = quats_to_rots(np.asarray(tf.quat_xyzw, dtype=np.float64)[None])[0]
            trans = np.asarray(tf.translation, dtype=np.float64)
            key = (_strip(tf.parent), _strip(tf.child))
            self._edges[key] = _Edge(*key, rot[None], trans[None])
        shadowed = []
        for series in dynamic:
            key = (_strip(series.parent), _strip(series.child))
            if len(series) == 0:
                continue
            if key in self._edges:
                shadowed.append(f"{key[0]}->{key[1]}")
                continue
            self._edges[key] = self._dynamic_edge(series, key, time_source)
        if shadowed:
            self.notes.append(f"/tf edges also in /tf_static, using the static value: {', '.join(sorted(shadowed))}")
        self._adjacent: dict[str, list[tuple[str, _Edge, bool]]] = {}
        for (parent, child), edge in self._edges.items():
            self._adjacent.setdefault(child, []).append((parent, edge, False))  # child -> parent: as stored
            self._adjacent.setdefault(parent, []).append((child, edge, True))  # parent -> child: inverted

    @staticmethod
    def _dynamic_edge(series: TransformSeries, key: tuple[str, str], time_source: str) -> _Edge:
        t = np.asarray(series.rec_ns if time_source == "record" else series.t_ns, dtype=np.int64)
        order = np.argsort(t, kind="stable")
        keep = order[np.concatenate(([True], t[order][1:] != t[order][:-1]))] if t.size else order
        rot = quats_to_rots(np.ascontiguousarray(series.quat_xyzw[keep], dtype=np.float64))
        trans = np.ascontiguousarray(series.translation[keep], dtype=np.float64)
        return _Edge(*key, rot, trans, t[keep], np.asarray(series.rec_ns)[keep], series.topic)

    @property
    def frames(self) -> set[str]:
        """Every frame named by an edge."""
        return set(self._adjacent)

    def _path(self, target: str, source: str, *, static_only: bool) -> list[tuple[_Edge, bool]] | None:
        """Edges from ``source`` to ``target`` (breadth first: fewest edges), each with its 'inverted' flag."""
        if target == source:
            return []
        back: dict[str, tuple[str, _Edge, bool]] = {}
        queue = deque([source])
        seen = {source}
        while queue:
            node = queue.popleft()
            for nxt, edge, inverted in self._adjacent.get(node, ()):
                if nxt in seen or (static_only and not edge.static):
                    continue
                seen.add(nxt)
                back[nxt] = (node, edge, inverted)
                if nxt == target:
                    chain = []
                    while nxt != source:
                        nxt, edge, inverted = back[nxt]
                        chain.append((edge, inverted))
                    return chain[::-1]
                queue.append(nxt)
        return None

    def chain(self, target: str, source: str) -> list[tuple[_Edge, bool]] | None:
        """The chain a lookup uses: static edges only if they connect the frames, else any; None if apart."""
        target, source = _strip(target), _strip(source)
        found = self._path(target, source, static_only=True)
        return found if found is not None else self._path(target, source, static_only=False)

    def _require_chain(self, target: str, source: str, topic: str | None) -> list[tuple[_Edge, bool]]:
        found = self.chain(target, source)
        if found is None:
            raise InputError(
                self.path,
                f"no transform chain from frame '{_strip(source)}' to '{_strip(target)}' "
                f"({self.explain(target, source)})",
                topic,
            )
        return found

    def is_static(self, target: str, source: str) -> bool:
        """Whether ``target`` and ``source`` are connected through static edges only."""
        return self._path(_strip(target), _strip(source), static_only=True) is not None

    def static_lookup(self, target: str, source: str) -> tuple[np.ndarray, np.ndarray] | None:
        """``(R, t)`` with ``x_target = R x_source + t`` through static edges, or None."""
        found = self._path(_strip(target), _strip(source), static_only=True)
        if found is None:
            return None
        rot, trans = np.eye(3), np.zeros(3)
        for edge, inverted in found:
            r, t = edge.rot[0], edge.trans[0]
            if inverted:
                r, t = r.T, -r.T @ t
            rot, trans = r @ rot, r @ trans + t
        return rot, trans

    def explain(self, target: str, source: str) -> str:
        """Why two frames are not connected, for error messages: the frames each one reaches."""
        target, source = _strip(target), _strip(source)
        if not self._edges:
            return "the log has no /tf_static or /tf transforms"

        def reach(frame: str) -> str:
            if frame not in self._adjacent:
                return f"'{frame}' is in no transform"
            seen, queue = {frame}, deque([frame])
            while queue:
                for nxt, _, _ in self._adjacent[queue.popleft()]:
                    if nxt not in seen:
                        seen.add(nxt)
                        queue.append(nxt)
            names = sorted(seen - {frame})
            shown = ", ".join(names[:6]) + (f", ... ({len(names)} frames)" if len(names) > 6 else "")
            return f"'{frame}' connects to {shown}"

        return f"{reach(source)}; {reach(target)}"

    def lookup(self, target: str, source: str, t_ns: np.ndarray, topic: str | None = None) -> Lookup:
        """Transform ``source`` -> ``target`` at each of ``t_ns`` (int64 ns).

        Raises:
            InputError: The frames are not connected (the message says what each one connects to).

        """
        found = self._require_chain(target, source, topic)
        t_ns = np.asarray(t_ns, dtype=np.int64).reshape(-1)
        n = t_ns.shape[0]
        rot = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
        trans = np.zeros((n, 3))
        valid = np.ones(n, bool)
        dynamic = []
        for edge, inverted in found:
            if edge.static:
                r, t = np.broadcast_to(edge.rot[0], (n, 3, 3)), np.broadcast_to(edge.trans[0], (n, 3))
            else:
                r, t = np.empty((n, 3, 3)), np.empty((n, 3))
                inside = np.empty(n, bool)
                _interpolate(edge.t_ns, edge.rot, edge.trans, t_ns, r, t, inside)
                valid &= inside
                dynamic.append(f"{edge.parent}->{edge.child}")
            if inverted:
                r = np.swapaxes(r, 1, 2)
                t = -np.einsum("nij,nj->ni", r, t)
            rot = np.einsum("nij,njk->nik", r, rot)
            trans = np.einsum("nij,nj->ni", r, trans) + t
        return Lookup(rot, trans, valid, tuple(dynamic))

    def pose_stream(self, parent: str, child: str, topic: str) -> PoseStream:
        """Poses of ``child`` in ``parent`` (ground truth from TF) at the stamps of the densest ``/tf`` edge of
        the chain, where every ``/tf`` edge of the chain has samples around them.

        Raises:
            InputError: The frames are not connected, or only through static transforms.

        """
        stamped = [edge for edge, _ in self._require_chain(parent, child, topic) if not edge.static]
        if not stamped:
            raise InputError(self.path, f"TF edge {_strip(parent)}->{_strip(child)} is static: not a trajectory", topic)
        densest = max(stamped, key=lambda e: (e.t_ns.shape[0], e.parent, e.child))
        res = self.lookup(parent, child, densest.t_ns, topic)
        keep = res.valid
        return PoseStream(
            topic,
            _strip(parent),
            _strip(child),
            densest.t_ns[keep],
            densest.rec_ns[keep],
            np.ascontiguousarray(res.trans[keep]),
            rots_to_quats(np.ascontiguousarray(res.rot[keep])),
        )


def static_transform(tfs: list[Transform], target: str, source: str) -> tuple[np.ndarray, np.ndarray] | None:
    """``(R, t)`` with ``x_target = R x_source + t``, composed through any chain of static transforms.

    Returns ``None`` when the frames are not connected. Equal frames give the identity.
    """
    return TfBuffer(tfs).static_lookup(target, source)
