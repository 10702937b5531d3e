"""Static transforms between frames (``/tf_static``): chains through the frame graph, no ROS needed."""

from __future__ import annotations

from collections import deque

import numpy as np

from pipeline.lie import quat_to_rot
from pipeline.streams import Transform


def _strip(frame: str) -> str:
    """TF frame ids are compared without a leading slash (ROS1 logs often carry one)."""
    return frame.lstrip("/")


def static_transform(tfs: list[Transform], target: str, source: str) -> tuple[np.ndarray, np.ndarray] | None:
    """``(R, t)`` with ``x_target = R x_source + t``, composed through any chain of static transforms.

    Returns ``None`` when the frames are not connected. Equal frames give the identity.
    """
    target, source = _strip(target), _strip(source)
    if target == source:
        return np.eye(3), np.zeros(3)
    # Graph edges in both directions: parent<-child is the stored transform, child<-parent its inverse.
    edges: dict[str, list[tuple[str, np.ndarray, np.ndarray]]] = {}
    for tf in tfs:
        r = quat_to_rot(np.asarray(tf.quat_xyzw, dtype=float))
        t = np.asarray(tf.translation, dtype=float)
        p, c = _strip(tf.parent), _strip(tf.child)
        edges.setdefault(c, []).append((p, r, t))  # x_p = r x_c + t
        edges.setdefault(p, []).append((c, r.T, -r.T @ t))
    # Breadth-first search from the source, accumulating x_node = R x_source + t.
    seen = {source: (np.eye(3), np.zeros(3))}
    queue = deque([source])
    while queue:
        node = queue.popleft()
        r_acc, t_acc = seen[node]
        for nxt, r, t in edges.get(node, []):
            if nxt in seen:
                continue
            seen[nxt] = (r @ r_acc, r @ t_acc + t)
            if nxt == target:
                return seen[nxt]
            queue.append(nxt)
    return None
