"""The M1 search tree and its exact best-first search, on every present device:
always the linear search's answer (smallest SSD, lowest block index on ties)."""

from __future__ import annotations

import numpy as np
import pytest

import geosynth
from geosynth.volume import reference
from geosynth.volume import tree as tree_search_mod
from geosynth.volume.blocks import block_offsets, block_origins, box_sums
from geosynth.volume.cascade import CascadeSearch
from geosynth.volume.examples import spheres_field
from geosynth.volume.synthesis import quantize_field
from geosynth.volume.tree import BlockSearch

# (block size, source side): small enough for CI, block sizes 2 to 16.
CASES = [(2, 12), (4, 16), (8, 24), (16, 32)]


def _field(kind: str, side: int, rng) -> np.ndarray:
    if kind == "random":
        return rng.integers(0, 256, (side, side + 1, side - 1), dtype=np.uint8)
    return quantize_field(spheres_field(side, count=max(3, side // 4), radius=(2.0, side / 5), seed=side), 4.0)


def _queries(field, block, rng, count=6):
    """Cuts from the source, cuts with random samples (an octant, or scattered), pure noise."""
    out = []
    for t in range(count):
        o = rng.integers(0, np.array(field.shape) - block + 1)
        q = field[o[0]:o[0] + block, o[1]:o[1] + block, o[2]:o[2] + block].copy()
        h = block // 2
        if t % 3 == 1:
            q[h:, h:, h:] = rng.integers(0, 256, (h, h, h))
        elif t % 3 == 2:
            mask = rng.random(q.shape) < 0.2
            q[mask] = rng.integers(0, 256, int(mask.sum()))
        out.append(q)
    out.append(rng.integers(0, 256, (block,) * 3, dtype=np.uint8))
    return out


@pytest.mark.parametrize("kind", ["random", "real"])
@pytest.mark.parametrize("block, side", CASES)
def test_tree_search_equals_linear(device, rng, kind, block, side):
    field = _field(kind, side, rng)
    s = BlockSearch(field, block, device=device)
    for q in _queries(field, block, rng):
        want = reference.nearest_block_naive(field, q)
        assert s.nearest(q) == want
        assert s.nearest_linear(q) == want


@pytest.mark.parametrize("kind", ["random", "real"])
@pytest.mark.parametrize("block, side", CASES)
def test_cascade_search_equals_linear(device, rng, kind, block, side):
    field = _field(kind, side, rng)
    s = CascadeSearch(field, block, device=device, min_work=0)
    for q in _queries(field, block, rng):
        want = reference.nearest_block_naive(field, q)
        assert s.nearest(q) == want
        # any block's SSD is a valid threshold; so is one too low (the search then drops it)
        o = rng.integers(0, np.array(field.shape) - block + 1)
        other = int(((field[o[0]:o[0] + block, o[1]:o[1] + block, o[2]:o[2] + block].astype(np.int64) - q) ** 2).sum())
        assert s.nearest(q, threshold=other) == want
        assert s.nearest(q, threshold=max(0, want[1] - 1)) == want
        assert s.nearest(q, threshold=max(0, want[1] // 3)) == want  # far too low: searched again without it


def test_cascade_with_three_stages_equals_linear(device, rng):
    """Any chain of bound stages (here cells 16, 8, 4) gives the exact answer."""
    field = _field("real", 36, rng)
    from geosynth.compute.backend import get_backend

    default = CascadeSearch(field, 32, device=device, min_work=0)  # N = 8, 16: fused; 32: staged
    assert not default.fused and default.stages == [32 // n for n in get_backend(device).bound_cells_per_side]
    assert CascadeSearch(field, 16, device=device, min_work=0).fused
    s = CascadeSearch(field, 32, device=device, min_work=0, cells=(16, 8, 4))
    assert s.stages == [16, 8, 4] and not s.fused
    for q in _queries(field, 32, rng):
        want = reference.nearest_block_naive(field, q)
        assert s.nearest(q) == want
        assert len(s.last_info["alive"]) == 4
        assert s.nearest(q, threshold=max(0, want[1] - 1)) == want


def test_cascade_drops_blocks_by_bounds(device, rng):
    """The stages keep fewer and fewer blocks, and the last keeps the answer."""
    field = _field("real", 32, rng)
    s = CascadeSearch(field, 16, device=device, min_work=0, cells=[8, 4])
    assert s.stages == [8, 4]
    q = field[5:21, 3:19, 7:23].copy()
    assert s.nearest(q) == ((5, 3, 7), 0)
    alive = s.last_info["alive"]
    assert alive[0] == s.n_blocks and alive[0] >= alive[1] >= alive[2] >= 1
    direct = CascadeSearch(field, 16, device=device, min_work=float("inf"))  # one launch over every block
    assert direct.stages == [] and direct.nearest(q) == ((5, 3, 7), 0)


@pytest.mark.parametrize("items", [None, 1, 1 << 20])
@pytest.mark.parametrize("shape", [(9, 30, 12), (40, 10, 8), (17, 8, 45)])
def test_fused_cascade_on_thin_and_wide_fields(device, rng, shape, items, monkeypatch):
    """Rows shorter and longer than the kernel's 16 lanes, one-block-thick axes, one
    work-item, the device's default and one per row (sharing the best SSD and ties
    between items): always the linear answer; blocks scored exactly are counted."""
    from geosynth.compute.backend import get_backend

    if items is not None:
        monkeypatch.setattr(get_backend(device), "search_items", items)
    field = _field("real", 48, rng)[:shape[0], :shape[1], :shape[2]].copy()
    s = CascadeSearch(field, 8, device=device, min_work=0)
    assert s.fused
    for q in _queries(field, 8, rng, count=4):
        want = reference.nearest_block_naive(field, q)
        assert s.nearest(q) == want
        alive = s.last_info["alive"]
        assert alive[0] == s.n_blocks and 1 <= alive[1] <= s.n_blocks
        assert s.nearest(q, threshold=want[1]) == want


@pytest.mark.parametrize("items, min_work", [(None, 0), (1, 0), (3, 0), (1 << 20, 0), (None, float("inf"))])
@pytest.mark.parametrize("block", [8, 16])
def test_fused_batch_is_one_launch_and_equals_linear(device, rng, block, items, min_work, monkeypatch):
    """A batch of queries in one fused launch, shared out over any number of work-items per
    query, with thresholds that are good, too low or absent: every answer is the linear one.
    A search small enough to score one query directly still runs a batch fused."""
    from geosynth.compute.backend import get_backend

    be = get_backend(device)
    if items is not None:
        monkeypatch.setattr(be, "search_items", items)
    field = _field("real", 32, rng)
    s = CascadeSearch(field, block, device=device, min_work=min_work)
    assert s.batch_fused and s.fused == (min_work == 0)
    queries = _queries(field, block, rng, count=5)
    want = [reference.nearest_block_naive(field, q) for q in queries]
    # the last query is noise (its best SSD > 0): its threshold is below the best
    thresholds = [None, want[1][1], want[2][1] // 3 if want[2][1] else None, None, 10**9, want[5][1] - 1]
    launches = []
    real = be.cascade_search
    monkeypatch.setattr(be, "cascade_search", lambda *a: (launches.append(a[-5]), real(*a)))
    origins, ssds, alive = s.nearest_batch(np.stack(queries), thresholds)
    assert [(tuple(int(v) for v in o), int(d)) for o, d in zip(origins, ssds)] == want
    # one launch for the batch, a second for the queries whose threshold was below their best
    assert launches[0] == len(queries) and launches[1:] == [
        sum(t is not None and t < w[1] for t, w in zip(thresholds, want))]  # n_queries of each launch
    assert all(a[0] == s.n_blocks and 1 <= a[1] <= 2 * s.n_blocks for a in alive)
    got, got_ssd, _ = s.nearest_batch(np.stack(queries))
    assert np.array_equal(got, origins) and np.array_equal(got_ssd, ssds)


@pytest.mark.parametrize("block", [4, (2, 4, 6)])
def test_dense_batch_is_one_launch_and_equals_linear(device, rng, block, monkeypatch):
    """A small search without stages or fused kernel (cube N = 4, a slab's box) scores a
    batch in one dense launch: the linear answers, lowest index on ties, whatever the
    thresholds; the rows are unpacked once for the search."""
    from geosynth.compute.backend import get_backend

    field = _field("real", 16, rng)
    field[:, :, 8:] = field[:, :, :8]  # repeated blocks: ties, won by the lowest index
    s = CascadeSearch(field, block, device=device, min_work=float("inf"))
    assert s.batch_dense and not s.stages and not s.batch_fused
    shape = s.block_shape
    queries = []
    for t in range(7):
        o = rng.integers(0, np.array(field.shape) - shape + 1)
        q = field[o[0]:o[0] + shape[0], o[1]:o[1] + shape[1], o[2]:o[2] + shape[2]].copy()
        if t % 2:
            q[0] = rng.integers(0, 256, q[0].shape)
        queries.append(q)
    be = get_backend(device)
    launches = []
    real = be.ssd_dense
    monkeypatch.setattr(be, "ssd_dense", lambda *a: (launches.append(a[-2]), real(*a)))
    origins, ssds, alive = s.nearest_batch(np.stack(queries), [0] * len(queries))  # thresholds too low
    for q, o, d in zip(queries, origins, ssds):
        want = reference.nearest_block_naive(field, q)
        assert (tuple(int(v) for v in o), int(d)) == want == s.nearest(q)
    assert launches == [len(queries)] and all(a == [s.n_blocks] for a in alive)
    rows = s._dense_rows
    s.nearest_batch(np.stack(queries[:2]))
    assert s._dense_rows is rows


def test_batch_of_wrong_dtype_is_refused(one_device):
    s = CascadeSearch(np.zeros((20, 20, 20), np.uint8), 8, device=one_device, min_work=0)
    with pytest.raises(TypeError, match="uint8"):
        s.nearest_batch(np.zeros((2, 8, 8, 8), np.int32))


def test_box_sums_match_numpy(rng):
    f = rng.integers(0, 256, (7, 6, 5), dtype=np.uint8)
    got = box_sums(f, 3)
    assert got.shape == (5, 4, 3)
    for z, y, x in [(0, 0, 0), (4, 3, 2), (2, 1, 0)]:
        assert got[z, y, x] == int(f[z:z + 3, y:y + 3, x:x + 3].astype(np.int64).sum())


@pytest.mark.parametrize("block", [2, 4, 8])
def test_cut_query_finds_lowest_identical_block(device, block):
    # a field with many identical blocks (clamped regions): distance 0, lowest index
    field = np.zeros((14, 13, 12), np.uint8)
    field[7:, :, :] = 200
    field[3, 4, 5] = 17
    s = BlockSearch(field, block, device=device)
    cascade = CascadeSearch(field, block, device=device, min_work=0)  # fused for block 8
    assert cascade.fused == (block == 8)
    hi = np.array(field.shape) - block
    for o in [np.minimum((6, 6, 6), hi), (0, 0, 0), (2, 3, 4), hi]:
        q = field[o[0]:o[0] + block, o[1]:o[1] + block, o[2]:o[2] + block]
        got = s.nearest(q)
        assert got[1] == 0
        assert got == reference.nearest_block_naive(field, q)
        assert s.index_of(got[0]) <= s.index_of(o)
        assert cascade.nearest(q) == got
        assert cascade.nearest(q, threshold=0) == got


def _check_tree_holds_every_block_once(s: BlockSearch, field: np.ndarray) -> None:
    b = s.block
    origins = s.block_origins()
    # every leaf is reached exactly once from the root
    visits = np.zeros(s.n_nodes, np.int64)
    stack = [None]
    while stack:
        for c in s.children(stack.pop()):
            visits[c] += 1
            stack.append(int(c))
    assert (visits == 1).all()
    leaves = np.flatnonzero(s._is_leaf)
    # every block sits at exactly one leaf, whose representative is the lowest index of identical blocks
    leaf = s.leaf_of_block
    assert leaf.shape == (s.n_blocks,) and s._is_leaf[leaf].all()
    assert np.array_equal(np.unique(leaf), leaves)
    assert np.bincount(leaf, minlength=s.n_nodes)[leaves].sum() == s.n_blocks
    rep = s._node_rep[leaf]
    assert (rep <= np.arange(s.n_blocks)).all()
    for i in range(0, s.n_blocks, max(1, s.n_blocks // 200)):
        (z, y, x), (rz, ry, rx) = origins[i], origins[rep[i]]
        assert np.array_equal(field[z:z + b, y:y + b, x:x + b], field[rz:rz + b, ry:ry + b, rx:rx + b])
    # distinct blocks sit at distinct leaves
    flat = np.lib.stride_tricks.sliding_window_view(field, (b,) * 3).reshape(s.n_blocks, -1)
    assert np.unique(flat, axis=0).shape[0] == leaves.size
    stats = s.stats()
    assert stats.leaves == leaves.size and stats.blocks == s.n_blocks and stats.nodes == s.n_nodes
    assert "mean branching" in str(stats)


@pytest.mark.parametrize("kind", ["random", "real", "plateaus"])
def test_merged_tree_holds_every_block_once(device, rng, kind):
    if kind == "plateaus":
        field = (rng.integers(0, 3, (16, 16, 16)) * 100).astype(np.uint8)
        field[:8] = 0
    else:
        field = _field(kind, 16, rng)
    _check_tree_holds_every_block_once(BlockSearch(field, 4, device=device), field)


def test_hash_collisions_never_merge(device, rng, monkeypatch):
    # 2-bit hashes: nearly every group is a collision that the exact check must split
    monkeypatch.setattr(tree_search_mod, "HASH_MASK", 0x3)
    field = (rng.integers(0, 4, (12, 12, 12)) * 60).astype(np.uint8)
    s = BlockSearch(field, 4, device=device)
    _check_tree_holds_every_block_once(s, field)
    for q in _queries(field, 4, rng, 3):
        assert s.nearest(q) == reference.nearest_block_naive(field, q)


def test_same_tree_and_answers_on_every_device(device_pair, rng):
    field = _field("real", 24, rng)
    queries = _queries(field, 8, rng)
    runs = []
    for d in device_pair:
        s = BlockSearch(field, 8, device=d)
        runs.append((s.stats().as_dict() | {"build_seconds": 0}, [s.nearest(q) for q in queries]))
    assert runs[1] == runs[0]


def test_block_origins_match_candidate_origins(one_device):
    shape = (10, 9, 11)
    o = block_origins(shape, 4)
    np.testing.assert_array_equal(o, geosynth.candidate_origins(shape, block_offsets(4)))
    s = BlockSearch(np.zeros(shape, np.uint8), 4, device=one_device)
    assert s.n_blocks == len(o)
    for i in (0, 5, len(o) - 1):
        assert s.origin_of(i) == tuple(o[i]) and s.index_of(o[i]) == i


def test_pruned_mode_reports_disagreement(device, rng):
    field = _field("real", 24, rng)
    s = BlockSearch(field, 8, device=device)
    queries = _queries(field, 8, rng)
    exact = s.pruned_disagreement(queries, prune_eps=1e9)  # a huge eps never prunes
    assert exact["disagreement"] == 0 and exact["max_excess"] == 0 and exact["queries"] == len(queries)
    rep = s.pruned_disagreement(queries, prune_eps=0.0)
    assert 0.0 <= rep["disagreement"] <= 1.0 and rep["mean_excess"] >= 0
    for q in queries:  # pruned answers are real blocks with their true SSD
        (z, y, x), ssd = s.nearest(q, prune_eps=0.0)
        assert ssd == int(((field[z:z + 8, y:y + 8, x:x + 8].astype(np.int64) - q) ** 2).sum())


def test_search_invalid_input(monkeypatch, one_device):
    field = np.zeros((8, 8, 8), np.uint8)
    with pytest.raises(ValueError, match="power of two"):
        BlockSearch(field, 3, device=one_device)
    with pytest.raises(ValueError, match="larger than the source"):
        BlockSearch(field, 16, device=one_device)
    with pytest.raises(TypeError, match="uint8"):
        BlockSearch(field.astype(np.int16), 4, device=one_device)
    with pytest.raises(ValueError, match="3-D"):
        BlockSearch(np.zeros((8, 8, 8, 1), np.uint8), 4, device=one_device)
    s = BlockSearch(field, 4, device=one_device)
    with pytest.raises(ValueError, match=r"shape \(4, 4, 4\)"):
        s.nearest(np.zeros((8, 8, 8), np.uint8))
    with pytest.raises(TypeError, match="uint8"):
        s.nearest(np.zeros((4, 4, 4), np.float32))
    with pytest.raises(ValueError, match="prune_eps"):
        s.nearest(np.zeros((4, 4, 4), np.uint8), prune_eps=-1.0)
    for cells in ([3], [8], [1], [2, 4], [2, 2]):
        with pytest.raises(ValueError, match="cells must"):
            CascadeSearch(field, 8, device=one_device, cells=cells)
    import geosynth.volume.pyramid as pyramid

    monkeypatch.setattr(pyramid, "available_memory", lambda: 10_000)
    with pytest.raises(MemoryError, match=r"estimated [0-9.]+ MiB"):
        BlockSearch(np.zeros((32, 32, 32), np.uint8), 8, device=one_device)
