"""Transitive groups of joined items (connected components), the one grouping used by the GCP checks (coincident
points) and the background detector (blobs of one vehicle)."""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components


def group_pairs(n: int, pairs: np.ndarray) -> list[list[int]]:
    """Groups of ``range(n)`` joined by ``pairs`` (P, 2) of indices, transitively (connected components), each
    ascending, in order of first member; an item in no pair is a group of its own."""
    if n == 0:
        return []
    p = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    graph = coo_matrix((np.ones(len(p)), (p[:, 0], p[:, 1])), shape=(n, n))
    labels = connected_components(graph, directed=False)[1]
    groups: dict[int, list[int]] = {}
    for i, label in enumerate(labels.tolist()):
        groups.setdefault(label, []).append(i)
    return list(groups.values())
