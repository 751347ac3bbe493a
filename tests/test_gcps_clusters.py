"""Coincident-GCP grouping (calibration.gcp_checks._clusters, scipy connected components) against a plain search."""

from __future__ import annotations

import numpy as np

from trafficgeo.calibration.gcp_checks import _clusters


def _groups_by_search(points: np.ndarray, tol: float) -> list[list[int]]:
    """Single-linkage groups by depth-first search over all pairs within ``tol``, in order of first row."""
    close = np.hypot(*(points[:, None] - points[None]).transpose(2, 0, 1)) <= tol
    group = -np.ones(len(points), dtype=int)
    groups: list[list[int]] = []
    for i in range(len(points)):
        if group[i] >= 0:
            continue
        group[i], stack, members = len(groups), [i], []
        while stack:
            k = stack.pop()
            members.append(k)
            for j in np.flatnonzero(close[k] & (group < 0)):
                group[j] = len(groups)
                stack.append(int(j))
        groups.append(sorted(members))
    return groups


def test_clusters_equal_a_plain_search() -> None:
    rng = np.random.default_rng(7)
    sizes = set()
    for _ in range(200):
        n = int(rng.integers(1, 40))
        points, tol = rng.uniform(0, 10, (n, 2)), float(rng.uniform(0.1, 3.0))
        got = _clusters(points, tol)
        assert got == _groups_by_search(points, tol)
        sizes.update(len(g) for g in got)
    assert {1, 2, 3} <= sizes and max(sizes) > 10  # singletons, pairs, chains and big groups all occurred


def test_chain_is_one_group() -> None:
    """Single linkage: 0-1 and 1-2 close, 0-2 not: one group; a far point stays alone."""
    pts = np.array([[0.0, 0.0], [100.0, 0.0], [0.9, 0.0], [1.8, 0.0]])
    assert _clusters(pts, 1.0) == [[0, 2, 3], [1]]
