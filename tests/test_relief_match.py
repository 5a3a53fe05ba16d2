"""M4 FindMatches (geosynth.completion.matching, kernels/relief.*): the kernel equals the NumPy
oracle bit for bit on every device and rotation, partners that are not samples make a
match invalid, a copied neighbourhood scores 0 where it came from, devices agree bit for
bit, the pruned find_matches() selects what an unpruned score() would, and bad input
gets one-line errors."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import Delaunay

from geosynth.completion import matching as rm
from geosynth.completion.reference import relief_scores_reference


def _plane(n=13, jitter=0.2, seed=0, split=0.5):
    rng = np.random.default_rng(seed)
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    xy = np.stack([i.ravel(), j.ravel()], 1).astype(float) + rng.uniform(-jitter, jitter, (n * n, 2))
    tri = Delaunay(xy).simplices
    h = 0.4 * np.sin(xy[:, 0] * 1.3) * np.cos(xy[:, 1] * 0.9)
    v = len(xy)
    samples = np.nonzero(xy[:, 0] < split * (n - 1))[0]
    tex = np.zeros(v, bool)
    tex[samples] = True
    disp = np.zeros((v, 3))
    disp[samples, 2] = h[samples]
    col = np.clip(np.c_[0.5 + h, 0.5 - h, 0.3 + 0.2 * rng.random(v)], 0, 1)
    return dict(base=np.c_[xy, np.zeros(v)], normals=np.tile([0.0, 0.0, 1.0], (v, 1)), displacements=disp,
                textured=tex, triangles=tri, samples=samples, colours=col)


def _cylinder(nt=24, nz=10, radius=3.0, seed=1):
    """Half a cylinder captured (theta < pi), relief along the normal; a non-axis-aligned
    axis so that every frame case occurs."""
    rng = np.random.default_rng(seed)
    th, z = np.meshgrid(np.linspace(0, 2 * np.pi * (1 - 1 / nt), nt), np.arange(nz) * 0.8, indexing="ij")
    th, z = th.ravel() + rng.uniform(-0.05, 0.05, th.size), z.ravel()
    tri = Delaunay(np.c_[th * radius, z]).simplices
    axis_rot = np.linalg.qr(np.array([[1.0, 0.3, 0.2], [0.1, 1.0, 0.4], [0.3, 0.2, 1.0]]))[0]
    nrm = np.c_[np.cos(th), np.sin(th), 0 * th] @ axis_rot.T
    base = (np.c_[radius * np.cos(th), radius * np.sin(th), z]) @ axis_rot.T
    h = 0.25 * np.sin(3 * th) * np.cos(2.1 * z)
    samples = np.nonzero(th < np.pi)[0]
    tex = np.zeros(len(th), bool)
    tex[samples] = True
    disp = np.zeros_like(base)
    disp[samples] = h[samples, None] * nrm[samples]
    col = np.clip(np.c_[0.5 + h, 0.4 + 0 * h, 0.5 - h], 0, 1)
    return dict(base=base, normals=nrm, displacements=disp, textured=tex, triangles=tri, samples=samples,
                colours=col)


def _rings(tri, v, w):
    nb = [set() for _ in range(v)]
    for a, b, c in tri:
        nb[a] |= {b, c}
        nb[b] |= {a, c}
        nb[c] |= {a, b}

    def ring(t):
        seen, cur = {t}, {t}
        for _ in range(w):
            cur = set().union(*(nb[x] for x in cur)) - seen
            seen |= cur
        return sorted(seen - {t})
    return ring


def _queries(index, kw, targets=None, count=4, w=2, sigma=1.0, rotations=4, mu=0.7):
    ring = _rings(kw["triangles"], index.n_vertices, w)
    tex = index.textured
    if targets is None:
        targets = [t for t in range(index.n_vertices) if not tex[t] and any(tex[x] for x in ring(t))][:count]
    nb = [ring(t) for t in targets]
    start = np.r_[0, np.cumsum([len(x) for x in nb])]
    return rm.neighbourhood_queries(index, targets, start, np.concatenate(nb), sigma, rotations=rotations, mu=mu)


@pytest.mark.parametrize("rotations", [4, 3])
def test_kernel_equals_reference_every_rotation(device, rotations):
    kw = _plane()
    index = rm.ReliefIndex.build(**kw, device=device)
    q = _queries(index, kw, rotations=rotations)
    got = rm.score(index, q)
    ref = relief_scores_reference(index, q)
    assert got.codes.shape == (4, len(kw["samples"]), rotations)
    np.testing.assert_array_equal(got.codes, ref)
    assert got.valid.mean() > 0.3 and (got.codes == rm.INVALID).any()  # both kinds occur
    assert len(np.unique(got.codes[got.valid])) > 100  # real scores, not a constant
    lim = np.percentile(ref[ref < rm.OVER], 20, axis=None).astype(np.int64) * np.ones(4, np.int64)
    cut = rm.score(index, q, lim).codes
    np.testing.assert_array_equal(cut, relief_scores_reference(index, q, lim))
    keep = ref <= lim[:, None, None]
    np.testing.assert_array_equal(cut[keep], ref[keep])  # scores under the limit are exact
    assert np.all((cut[~keep] == rm.OVER) | (cut[~keep] == rm.INVALID))


@pytest.mark.parametrize("rotations", [4, 3])
def test_per_query_candidate_rows_equal_reference(device, rotations):
    """score(slots=(Q, k)): each query against its own candidate row (the kernel's
    cand_stride), -1 padding scored OVER; equal to the oracle and to the shared-list
    scores of the same slots, with and without limits."""
    kw = _plane()
    index = rm.ReliefIndex.build(**kw, device=device)
    q = _queries(index, kw, rotations=rotations)
    n_s = len(index.samples)
    rng = np.random.default_rng(3)
    rows = np.full((4, 30), -1, np.int64)
    for i, k in enumerate([30, 17, 1, 25]):
        rows[i, :k] = rng.choice(n_s, k, replace=False)
    got = rm.score(index, q, slots=rows).codes
    assert got.shape == (4, 30, rotations)
    np.testing.assert_array_equal(got, relief_scores_reference(index, q, slots=rows))
    np.testing.assert_array_equal(got[rows < 0], rm.OVER)
    full = rm.score(index, q).codes
    for i in range(4):
        some = rows[i] >= 0
        np.testing.assert_array_equal(got[i, some], full[i, rows[i, some]])
    assert (got[rows >= 0] < rm.OVER).mean() > 0.3 and (got == rm.INVALID).any()
    lim = np.percentile(full[full < rm.OVER], 20).astype(np.int64) * np.ones(4, np.int64)
    cut = rm.score(index, q, lim, slots=rows).codes
    np.testing.assert_array_equal(cut, relief_scores_reference(index, q, lim, slots=rows))
    keep = (got <= lim[:, None, None]) & (rows >= 0)[..., None]
    np.testing.assert_array_equal(cut[keep], got[keep])
    assert keep.any() and (cut[~keep & (rows >= 0)[..., None]] >= rm.OVER).all()
    shared = rows[0]
    np.testing.assert_array_equal(rm.score(index, q, slots=shared).codes, full[:, shared])


def test_kernel_equals_reference_on_a_curved_surface_after_updates(device):
    kw = _cylinder()
    index = rm.ReliefIndex.build(**kw, partners="textured", device=device)
    q = _queries(index, kw, count=3, rotations=4, mu=0.5)
    np.testing.assert_array_equal(rm.score(index, q).codes, relief_scores_reference(index, q))
    ids = q.targets[:2]
    index.update(ids, index.transfer(index.samples[[3, 9]], [1, 2], ids, 4), [[0.1, 0.2, 0.3], [0.9, 0.8, 0.7]])
    assert index.textured[ids].all() and index.host.usable[ids].all()
    q2 = _queries(index, kw, count=3, rotations=4, mu=0.5)
    np.testing.assert_array_equal(rm.score(index, q2).codes, relief_scores_reference(index, q2))
    # the same state built from scratch scores the same
    kw2 = dict(kw, displacements=index.displacements, textured=index.textured,
               colours=np.where(index.textured[:, None], index.host.colour / 255.0, kw["colours"]))
    kw2["colours"][~index.textured] = kw["colours"][~index.textured]
    fresh = rm.ReliefIndex.build(**kw2, partners="textured", device=device)
    if fresh.quantum == index.quantum:
        np.testing.assert_array_equal(rm.score(fresh, q2).codes, rm.score(index, q2).codes)


def test_partner_outside_the_samples_is_invalid(one_device):
    """Independent of the oracle: on a plane the walk finds the true nearest base, so a
    (sample, rotation) whose moved neighbour lies nearest a non-sample must be INVALID."""
    kw = _plane(jitter=0.15)
    index = rm.ReliefIndex.build(**kw, device=one_device)
    q = _queries(index, kw, count=2, rotations=4, mu=1.0)
    codes = rm.score(index, q).codes
    base = kw["base"]
    is_sample = np.isin(np.arange(index.n_vertices), kw["samples"])
    checked = 0
    for qi in range(2):
        e = slice(q.qstart[qi], q.qstart[qi + 1])
        t = q.targets[qi]
        off = base[q.entries[e]] - base[t]  # plane: frames are all the same
        for slot, s in enumerate(index.samples):
            for r in range(4):
                c, sn = [(1, 0), (0, 1), (-1, 0), (0, -1)][r]
                mv = base[s] + np.c_[c * off[:, 0] - sn * off[:, 1], sn * off[:, 0] + c * off[:, 1], 0 * off[:, 0]]
                d = np.linalg.norm(base[None] - mv[:, None], axis=2)
                two = np.sort(d, axis=1)[:, :2]
                if np.any(two[:, 1] - two[:, 0] < 1e-2):
                    continue  # a near tie: quantization may pick either
                if not is_sample[np.argmin(d, axis=1)].all():
                    assert codes[qi, slot, r] == rm.INVALID
                    checked += 1
    assert checked > 20


def test_fixed_partners_apart_from_the_candidates(device):
    """partners=ids: candidates are a subset of the samples, every sample may still be a
    partner (the completion's default: the capture's own vertices are candidates, the
    oversampling's vertices partners only). The kernel equals the oracle, the usable
    flags are the given ids, and the candidates' colour scores (the shape term's
    normalization comes from the candidates) equal the same slots of an index whose
    candidates are all the samples."""
    kw = _plane()
    every = kw["samples"]
    few = every[::3]
    full = rm.ReliefIndex.build(**kw, device=device)
    index = rm.ReliefIndex.build(**dict(kw, samples=few), partners=every, device=device)
    np.testing.assert_array_equal(index.samples, few)
    np.testing.assert_array_equal(np.flatnonzero(index.host.usable), np.sort(every))
    q = _queries(index, kw, count=3, mu=0.5)
    got = rm.score(index, q).codes
    np.testing.assert_array_equal(got, relief_scores_reference(index, q))
    colour_only = rm.score(index, _queries(index, kw, count=3, mu=0.0)).codes
    np.testing.assert_array_equal(colour_only, rm.score(full, _queries(full, kw, count=3, mu=0.0)).codes[:, ::3])
    assert (got < rm.OVER).any()
    # a partner set without a sample in it makes matches that pair with that sample invalid
    drop = rm.ReliefIndex.build(**dict(kw, samples=few), partners=few, device=device)
    qd = _queries(drop, kw, count=3, mu=0.5)
    gd = rm.score(drop, qd).codes
    np.testing.assert_array_equal(gd, relief_scores_reference(drop, qd))
    assert (gd == rm.INVALID).sum() > (got == rm.INVALID).sum()


def test_copied_neighbourhood_scores_zero_where_it_came_from(device):
    kw = _plane()
    index = rm.ReliefIndex.build(**kw, device=device)
    ring, ring3 = _rings(kw["triangles"], index.n_vertices, 2), _rings(kw["triangles"], index.n_vertices, 3)
    interior = [s for s in kw["samples"] if all(index.textured[x] for x in ring3(s)) and len(ring(s)) > 12]
    s0 = interior[len(interior) // 2]
    q = rm.neighbourhood_queries(index, [s0], [0, len(ring(s0))], ring(s0), 1.0, rotations=4, mu=0.5)
    codes = rm.score(index, q).codes[0]
    slot = int(np.nonzero(index.samples == s0)[0][0])
    assert codes[slot, 0] == 0
    assert codes[slot, 1:].min() > 1000 and np.sort(codes[codes < rm.OVER])[1] > 1000


def test_bit_identical_across_devices(device_pair):
    a, b = device_pair
    kw = _cylinder()
    out = []
    for dev in (a, b):
        index = rm.ReliefIndex.build(**kw, device=dev)
        q = _queries(index, kw, count=6, rotations=4, mu=0.5)
        out.append((rm.score(index, q).codes, [m.code for m in rm.find_matches(index, q, 0.5)]))
    np.testing.assert_array_equal(out[0][0], out[1][0])
    for x, y in zip(out[0][1], out[1][1]):
        np.testing.assert_array_equal(x, y)


@pytest.mark.parametrize("tolerance", [1.1, 1.65])  # 1.65: the completion's balanced pick
def test_find_matches_is_the_unpruned_selection(device, tolerance):
    kw = _plane(n=17)
    index = rm.ReliefIndex.build(**kw, device=device)
    q = _queries(index, kw, count=5, mu=0.6)
    full = rm.score(index, q).codes
    masked = np.where(full < rm.OVER, full, rm.OVER).reshape(5, -1)
    best_slots = np.unravel_index(np.argmin(masked, axis=1), full.shape[1:])[0]  # each query's best slot
    n_s = len(index.samples)
    own = np.full((5, 3), -1, np.int64)
    own[:, 0] = best_slots
    own[1:, 1] = (best_slots[1:] + 7) % n_s
    worst = np.argsort(masked, axis=1)[:, -8:] // full.shape[2]  # slots holding the worst codes
    variants = [dict(probes=(8, 2)), dict(probes=(), hints=[int(best_slots[0])]),  # the best first: the tightest limit
                dict(probes=(4,), hints=np.arange(0, n_s, 5)), dict(probes=(), hints=[]),
                dict(probes=(), hints=own),  # a row per query
                dict(probes=(8,), hints=worst),  # rows of the worst: a loose limit, then the probe
                dict(probes=(), hints=np.full((5, 2), -1))]  # rows without a slot
    for max_err, kw in [(e, v) for e in (0.5, 0.004) for v in variants]:
        got = rm.find_matches(index, q, max_err, tolerance=tolerance, **kw)
        for i, m in enumerate(got):
            real = full[i][full[i] < rm.OVER].astype(np.int64)
            best = real.min()
            if best >= np.ceil(max_err * rm.SCORE_ONE):
                assert len(m.sample) == 0
                continue
            s, r = np.nonzero(full[i] <= np.floor(tolerance * best))
            np.testing.assert_array_equal(m.slot, s)
            np.testing.assert_array_equal(m.rotation, r)
            np.testing.assert_array_equal(m.code, full[i, s, r])
            np.testing.assert_array_equal(m.sample, index.samples[s])
            assert m.best == best / rm.SCORE_ONE and m.accepted[np.argmin(m.code)]
    assert any(len(m.sample) for m in rm.find_matches(index, q, 0.5))


@pytest.mark.parametrize("tolerance", [1.1, 1.65])
def test_find_matches_without_a_full_pass_selects_among_the_scored(device, tolerance):
    """exhaustive=False (the completion's coherent search): the selection is the unpruned
    selection restricted to the hinted and probed slots (each once, in slot order), with
    the same 1.1x rule and MaxErrThreshold."""
    kw = _plane(n=17)
    index = rm.ReliefIndex.build(**kw, device=device)
    q = _queries(index, kw, count=5, mu=0.6)
    full = rm.score(index, q).codes
    n_s = len(index.samples)
    rows = np.full((5, 4), -1, np.int64)
    rows[:, 0] = np.arange(5) * 11 % n_s
    rows[:, 1] = (np.arange(5) * 11 + 3) % n_s
    rows[2, 2] = 0  # also probed (stride 6): scored once
    for max_err, kw2 in [(e, v) for e in (0.5, 0.004) for v in (dict(probes=(6,), hints=rows),
                                                                   dict(probes=(), hints=rows),
                                                                   dict(probes=(5,)))]:
        got = rm.find_matches(index, q, max_err, tolerance=tolerance, exhaustive=False, **kw2)
        for i, m in enumerate(got):
            seen = set(np.arange(0, n_s, kw2["probes"][0]).tolist()) if kw2["probes"] else set()
            if "hints" in kw2:
                seen |= {int(x) for x in kw2["hints"][i] if x >= 0}
            seen = np.array(sorted(seen))
            sub = full[i, seen]
            real = sub[sub < rm.OVER].astype(np.int64)
            if len(real) == 0 or real.min() >= np.ceil(max_err * rm.SCORE_ONE):
                assert len(m.sample) == 0
                continue
            s, r = np.nonzero(sub <= np.floor(tolerance * real.min()))
            np.testing.assert_array_equal(m.slot, seen[s])
            np.testing.assert_array_equal(m.rotation, r)
            np.testing.assert_array_equal(m.code, sub[s, r])
            np.testing.assert_array_equal(m.sample, index.samples[seen[s]])
    assert any(len(m.sample) for m in rm.find_matches(index, q, 0.5, exhaustive=False, probes=(5,)))
    # around: one more pass over the slots next to each query's 2 best found (here: slot +- 1)
    asked = []

    def around(best):
        asked.append(best.copy())
        near = np.concatenate([best - 1, best + 1], axis=1)
        return np.where((best.repeat(2, axis=1) >= 0) & (near >= 0) & (near < n_s), near, -1)

    got = rm.find_matches(index, q, 0.5, tolerance=tolerance, exhaustive=False, probes=(7,), around=around,
                          around_best=2)
    probed = np.arange(0, n_s, 7)
    for i, m in enumerate(got):
        per_slot = np.where(full[i, probed] < rm.OVER, full[i, probed], rm.OVER).min(axis=1)
        best2 = probed[np.argsort(per_slot, kind="stable")[:2]]
        np.testing.assert_array_equal(asked[0][i], best2)
        seen = np.union1d(probed, [x for b in best2 for x in (b - 1, b + 1) if 0 <= x < n_s])
        sub = full[i, seen]
        real = sub[sub < rm.OVER].astype(np.int64)
        s, r = np.nonzero(sub <= np.floor(tolerance * real.min()))
        np.testing.assert_array_equal(m.slot, seen[s])
        np.testing.assert_array_equal(m.code, sub[s, r])
    with pytest.raises(ValueError, match="exhaustive"):
        rm.find_matches(index, q, 0.5, exhaustive=False, probes=())


def test_transfer_inverts_the_query_rotation(one_device):
    kw = _plane()
    kw["displacements"][kw["samples"]] = [0.3, -0.1, 0.2]  # tangential parts too
    index = rm.ReliefIndex.build(**kw, device=one_device)
    s = index.samples[:4]
    for r in range(4):
        d = index.transfer(s, [r] * 4, [100] * 4, 4)
        c, sn = [(1, 0), (0, 1), (-1, 0), (0, -1)][r]
        moved = np.c_[c * d[:, 0] - sn * d[:, 1], sn * d[:, 0] + c * d[:, 1], d[:, 2]]
        np.testing.assert_allclose(moved, kw["displacements"][s], atol=1e-12)


def test_paper_frames_are_orthonormal_and_follow_the_rule():
    n = np.array([[0.1, 0.6, 0.79], [0.7, 0.05, 0.71], [0.6, 0.8, 0.0], [0.0, 0.0, 1.0]])
    f = rm.paper_frames(n)
    np.testing.assert_allclose(np.einsum("vij,vkj->vik", f, f), np.broadcast_to(np.eye(3), (4, 3, 3)), atol=1e-12)
    u0 = np.array([0, -n[0, 2], n[0, 1]])
    np.testing.assert_allclose(f[0, 0], u0 / np.linalg.norm(u0))
    u1 = np.array([n[1, 2], 0, -n[1, 0]])
    np.testing.assert_allclose(f[1, 0], u1 / np.linalg.norm(u1))


def test_bad_input_one_line_errors(one_device):
    kw = _plane(n=8)
    index = rm.ReliefIndex.build(**kw, device=one_device)

    def err(fn, *words):
        with pytest.raises(ValueError) as e:
            fn()
        msg = str(e.value)
        assert "\n" not in msg and all(w in msg for w in words), msg

    bad = dict(kw, base=kw["base"].copy())
    bad["base"][3, 1] = np.nan
    err(lambda: rm.ReliefIndex.build(**bad, device=one_device), "base", "not finite")
    err(lambda: rm.ReliefIndex.build(**dict(kw, normals=kw["normals"][:5]), device=one_device), "normals", "shape")
    err(lambda: rm.ReliefIndex.build(**dict(kw, colours=kw["colours"] * 3), device=one_device), "colours", "[0, 1]")
    err(lambda: rm.ReliefIndex.build(**dict(kw, triangles=kw["triangles"] + 1000), device=one_device), "triangles")
    err(lambda: rm.ReliefIndex.build(**dict(kw, samples=[0, 63]), device=one_device), "samples", "textured")
    err(lambda: rm.ReliefIndex.build(**kw, partners="all", device=one_device), "partners")
    far_t = [t for t in range(index.n_vertices) if t not in kw["samples"]][-1]
    err(lambda: rm.ReliefIndex.build(**kw, partners=[0, far_t], device=one_device), "partners", "textured")
    far = [t for t in range(index.n_vertices) if t not in kw["samples"]][-1]
    err(lambda: rm.neighbourhood_queries(index, [far], [0, 1], [far - 1], 1.0), "targets", "no textured neighbour")
    err(lambda: rm.neighbourhood_queries(index, [far], [0, 1], [0], -1.0), "sigma")
    err(lambda: rm.neighbourhood_queries(index, [far], [0, 2], [0], 1.0), "nbr_start")
    q = rm.neighbourhood_queries(index, [far - 1], [0, 1], [0], 1.0)
    err(lambda: rm.score(index, q, limits=[1, 2]), "limits")
    err(lambda: rm.find_matches(index, q, float("nan")), "max_err")
    err(lambda: rm.find_matches(index, q, 0.5, hints=[len(index.samples)]), "hints")
    err(lambda: rm.find_matches(index, q, 0.5, hints=np.zeros((q.n_queries + 1, 2), np.int64)), "hints")
    err(lambda: rm.find_matches(index, q, 0.5, hints=np.full((q.n_queries, 2), -2)), "hints")
    err(lambda: rm.score(index, q, slots=np.zeros((q.n_queries, 2))), "slots")
    err(lambda: rm.score(index, q, slots=[len(index.samples)]), "slots")
    err(lambda: index.update([1], [[np.nan, 0, 0]]), "displacements", "not finite")


def test_too_many_queries_for_memory_is_refused_up_front(one_device, monkeypatch):
    from geosynth.core import memory

    kw = _plane(n=8)
    index = rm.ReliefIndex.build(**kw, device=one_device)
    q = _queries(index, kw, count=3)
    monkeypatch.setattr(memory, "available_memory", lambda: 2 * 3 * len(index.samples) * 4 * 4)
    with pytest.raises(memory.MemoryBudgetError) as e:
        rm.score(index, q)
    assert e.value.option == "queries" and e.value.largest == 2 and "\n" not in str(e.value)
