"""``trafficgeo.groups.group_pairs`` (connected components of joined blobs) against the union-find it
replaced, on random pair lists: the same groups, in the same order (of first member), members ascending."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from trafficgeo.groups import group_pairs


def union_find_groups(n: int, pairs: np.ndarray) -> list[list[int]]:
    """The former implementation of ``group_pairs`` (path-halving union-find, the smaller root wins), kept as the
    reference its replacement must match exactly."""
    parent = list(range(n))

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for i, j in np.asarray(pairs, dtype=np.int64).reshape(-1, 2):
        ri, rj = find(int(i)), find(int(j))
        if ri != rj:
            parent[max(ri, rj)] = min(ri, rj)
    groups: dict[int, list[int]] = {}
    for i in range(n):
        groups.setdefault(find(i), []).append(i)
    return list(groups.values())


@st.composite
def graphs(draw: st.DrawFn) -> tuple[int, np.ndarray]:
    """``n`` nodes and pairs among them: any order within a pair, repeats and self-pairs included."""
    n = draw(st.integers(0, 40))
    if n == 0:
        return 0, np.zeros((0, 2), dtype=np.int64)
    pairs = draw(st.lists(st.tuples(st.integers(0, n - 1), st.integers(0, n - 1)), max_size=3 * n))
    return n, np.array(pairs, dtype=np.int64).reshape(-1, 2)


@pytest.mark.slow
@settings(max_examples=300, deadline=None)
@given(graphs())
def test_group_pairs_equals_the_union_find(graph: tuple[int, np.ndarray]) -> None:
    n, pairs = graph
    assert group_pairs(n, pairs) == union_find_groups(n, pairs)


@pytest.mark.parametrize("seed", range(20))
def test_group_pairs_on_merge_candidate_like_pairs(seed: int) -> None:
    """Pairs ``i < j`` as :func:`~trafficgeo.video.detectors.blobs.merge_candidates` gives them, dense and sparse."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 200))
    i, j = np.triu_indices(n, k=1)
    keep = rng.random(i.size) < rng.choice([0.001, 0.01, 0.05])
    pairs = np.column_stack([i[keep], j[keep]])
    groups = group_pairs(n, pairs)
    assert groups == union_find_groups(n, pairs)
    assert sorted(k for g in groups for k in g) == list(range(n))


def test_group_pairs_known_groups() -> None:
    """0-3 joined through 3 (listed last), 4 alone, 2-5 via a reversed pair, 6 with itself."""
    pairs = np.array([[1, 3], [0, 3], [5, 2], [6, 6]])
    assert group_pairs(7, pairs) == [[0, 1, 3], [2, 5], [4], [6]]
    assert group_pairs(3, np.zeros((0, 2), dtype=np.int64)) == [[0], [1], [2]]
    assert group_pairs(0, np.zeros((0, 2), dtype=np.int64)) == []
