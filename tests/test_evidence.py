"""vpr.shosm evidence: dense, sparse (beam, top-K), streaming and loop-closure rSHOSM-seq evidence."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from vpr import groundtruth, sdr, simulate
from vpr import shosm as ev
from vpr.shosm import BeamConf, EvidenceConf, LoopConf, LoopDecider, SequenceMemory, confirm_closures
from vpr.types import EncodedTraverse


def _zscore(D):
    D = np.asarray(D, np.float64)
    sd = D.std(axis=0)
    return (D - D.mean(axis=0)) / np.where(sd > 0, sd, 1.0)


@pytest.fixture(scope="module")
def aliased():
    db, q, dp, qp = simulate.aliased_traverses(400, 40, seed=3)
    mem = SequenceMemory(threshold=0.75, seed=0)
    codes = mem.run(db)
    mem.reset()
    return mem, codes, q, dp, qp


def test_aliased_traverses_shapes_and_seed():
    db, q, dp, qp = simulate.aliased_traverses(300, 30, k=40, move=0.35, speed=(0.8, 1.2), seed=1)
    assert db.shape == (300, 2048) and db.dtype == bool and np.all(np.diff(db.indptr) == 40)
    assert np.array_equal(dp, np.arange(300))
    assert q.shape[0] == qp.size and 200 < qp.size < 400 and qp.min() == 0 and qp.max() <= 299
    assert np.all(np.diff(qp) >= 0) and np.diff(qp).max() <= 2  # speed 0.8-1.2: repeats and skips
    assert np.any(np.diff(qp) == 0) and np.any(np.diff(qp) == 2)
    # 30 appearances over 300 places: each SDR is shown at about 10 places
    assert np.unique(db.toarray(), axis=0).shape[0] == 30
    # the query keeps 65 % of its place's bits
    kept = np.asarray(db[qp].multiply(q).sum(axis=1)).ravel()
    assert np.all(kept == 26)
    db2, q2, _, qp2 = simulate.aliased_traverses(300, 30, seed=1)
    assert (db2 != db).nnz == 0 and (q2 != q).nnz == 0 and np.array_equal(qp2, qp)
    with pytest.raises(ValueError, match="speed"):
        simulate.aliased_traverses(10, 2, speed=(0, 1))


@pytest.mark.parametrize("direction", ["forward", "both"])
def test_beam_without_floors_equals_dense_clamped(aliased, direction):
    mem, codes, q, _, _ = aliased
    q = q[:120]
    D = ev.dense_evidence(mem, q, codes, direction=direction, clamp=True)
    open_beam = BeamConf(floor=0.0, rel_floor=0.0, z_floor=0.0, max_beam=None, max_enter=None)
    r = ev.sparse_evidence(mem, q, codes, EvidenceConf(normalise="none"), direction=direction, top_k=None,
                           beam=open_beam)
    np.testing.assert_allclose(r.similarity.toarray(), D, atol=1e-5)
    # z-scores from the sparse column's sums equal the dense column's
    rz = ev.sparse_evidence(mem, q, codes, direction=direction, top_k=7, beam=open_beam)
    Z = _zscore(D)
    C = rz.similarity.tocoo()
    np.testing.assert_allclose(C.data, Z[C.row, C.col], atol=1e-4)
    assert np.all(np.diff(rz.similarity.tocsc().indptr) <= 7)
    # the kept entries are the column's 7 largest
    kth = -np.sort(-Z, axis=0)[6]
    assert np.all(C.data >= kth[C.col] - 1e-4)


def test_query_evidence_is_the_dense_or_the_sparse_evidence(aliased):
    mem, codes, q, _, _ = aliased
    conf = EvidenceConf(decay=0.8, stay=None, skip=0.1)
    a = ev.query_evidence(mem, q[:50], codes, conf)
    Z = _zscore(ev.dense_evidence(mem, q[:50], codes, conf))
    np.testing.assert_allclose(a.similarity, Z, atol=1e-5)
    assert np.array_equal(a.best, Z.argmax(axis=0))
    b = ev.query_evidence(mem, q[:50], codes, conf, top_k=5)
    c = ev.sparse_evidence(mem, q[:50], codes, conf, top_k=5)
    assert (b.similarity != c.similarity).nnz == 0 and np.array_equal(b.best, c.best)


def test_default_beam_gives_the_dense_best_matches(aliased):
    mem, codes, q, dp, qp = aliased
    D = ev.dense_evidence(mem, q, codes)  # the method as it was: unclamped, dense
    r = ev.sparse_evidence(mem, q, codes)
    agree = np.mean(r.best == D.argmax(axis=0))
    assert agree >= 0.99, agree
    assert np.mean(np.abs(dp[r.best] - qp) <= 1) >= 0.9
    # kept z-scores are close to the dense ones (the beam drops evidence below its floor)
    C = r.similarity.tocoo()
    Z = _zscore(D)
    best = C.row == r.best[C.col]
    assert np.median(np.abs(C.data[best] - Z[C.row[best], C.col[best]])) < 0.1


@pytest.mark.parametrize("direction", ["forward", "both"])
def test_columns_finished_block_by_block_are_those_of_one_block(aliased, direction, monkeypatch):
    # the forward pass's columns wait for the backward pass, which runs the blocks in reverse; a block
    # boundary anywhere (here every 7 queries, the last block shorter) changes nothing
    from vpr.shosm import evidence as mod

    mem, codes, q, _, _ = aliased
    for beam in (BeamConf(), BeamConf(floor=0.0, rel_floor=0.0, z_floor=0.0, max_beam=None, max_enter=None)):
        for top_k in (None, 5):
            one = ev.sparse_evidence(mem, q[:60], codes, direction=direction, top_k=top_k, beam=beam)
            monkeypatch.setattr(mod, "QUERY_CHUNK", 7)
            blocks = ev.sparse_evidence(mem, q[:60], codes, direction=direction, top_k=top_k, beam=beam)
            graph = mod.Graph.of(mem, codes, backward=direction == "both")  # the passes one after the other
            serial = mod.Engine(graph, None, beam, threads=1).run(q[:60], direction, top_k)
            monkeypatch.undo()
            for other in (blocks, serial):
                assert other.similarity.shape == one.similarity.shape
                assert (other.similarity != one.similarity).nnz == 0
                assert np.array_equal(other.best, one.best) and np.array_equal(other.z, one.z)


def test_cells_with_the_same_targets_share_one_list():
    from vpr.shosm.graph import grouped_lists

    # cells 0 and 2 predict {5, 7} (2 twice over the same connection), cell 1 predicts {7}, cell 3 nothing
    head, nxt, dst, group = grouped_lists([0, 2, 1, 0, 2, 2], [7, 5, 7, 5, 7, 5], 4)
    assert group[0] == group[2] != group[1] and group[3] == -1 and head.size == 2

    def targets(g):
        out, e = [], head[g]
        while e >= 0:
            out.append(int(dst[e]))
            e = nxt[e]
        return sorted(out)

    assert targets(group[0]) == [5, 7] and targets(group[1]) == [7]
    head, nxt, dst, group = grouped_lists([], [], 3)
    assert head.size == 0 and np.all(group == -1)


@pytest.fixture(scope="module")
def rendered_pixel():
    """Pixel SDRs of a rendered scene: neighbouring (and other) places share many bits, so without caps
    the beam takes in most of the memory."""
    import encoders
    from vpr.render import render_scene

    d, n = render_scene("two_seasons", size=(64, 48), n_frames=160).traverses
    enc = encoders.get("pixel", k=200, standardise="fit")
    db, q = enc.fit(d.images).encode(d.images), enc.fit(n.images).encode(n.images)
    mem = SequenceMemory(threshold=0.75, seed=0)
    codes = mem.run(db)
    mem.reset()
    return mem, codes, q


def test_beam_caps_bound_the_cells_carried_and_keep_the_dense_best_matches(rendered_pixel):
    mem, codes, q = rendered_pixel
    free, capped, small = {}, {}, {}
    r_free = ev.sparse_evidence(mem, q, codes, beam=BeamConf().uncapped(), stats=free)
    r_cap = ev.sparse_evidence(mem, q, codes, stats=capped)
    ev.sparse_evidence(mem, q, codes, beam=BeamConf(max_beam=100, max_enter=5), stats=small)
    # on these SDRs the floors alone let most of the memory in; the caps hold whatever the data
    assert free["max_beam"] > 1000, free
    assert small["max_beam"] <= 100 < free["max_beam"]
    assert capped["max_beam"] <= BeamConf().max_beam
    # candidates: at most max_enter minicolumns by feed-forward plus what the beam predicts (stay, one and two
    # connections: each cell here has few lateral connections)
    assert small["max_candidates"] <= 5 * mem.cells_per_column + 100 * 8, small
    # here the floors carry every cell of the database codes (1,600): under the default caps, so the same result
    assert free["max_beam"] <= BeamConf().max_beam
    assert np.array_equal(r_cap.best, r_free.best)
    D = _zscore(ev.dense_evidence(mem, q, codes))
    bd = D.argmax(axis=0)
    assert np.mean(r_cap.best == bd) >= 0.95
    # the capped beam's z-scores come from what it kept: still those of the dense column at the best match
    C = r_cap.similarity.tocoo()
    best = (C.row == r_cap.best[C.col]) & (r_cap.best[C.col] == bd[C.col])
    assert np.median(np.abs(C.data[best] - D[C.row[best], C.col[best]])) < 0.25


def _engine(mem, codes, exact=False):
    return ev.Engine(ev.Graph.of(mem, codes), exact=exact)


def test_forward_stream_equals_batch_and_restarts(aliased, tmp_path):
    mem, codes, q, _, _ = aliased
    n_conn, n_cols = mem.n_connections, mem.n_columns
    batch = ev.sparse_evidence(mem, q, codes, direction="forward", top_k=10)
    S = batch.similarity.tocsc()
    f = _engine(mem, codes)
    for j in range(q.shape[0]):
        if j == 150:  # a robot restarts from its saved state
            header, arrays = f.state()
            np.savez(tmp_path / "state.npz", **arrays)
            with np.load(tmp_path / "state.npz") as z:
                f = _engine(mem, codes).load_state(header, dict(z))
        o = f.step(q.indices[q.indptr[j]:q.indptr[j + 1]].astype(np.int64))
        assert o.best()[0] == batch.best[j]
        assert abs(o.best()[1] - batch.z[j]) <= 1e-6
        rows, z = o.top(10)
        col = S[:, j]
        np.testing.assert_allclose(np.sort(z), np.sort(col.data), atol=1e-6)
        # the same frames, but where the 10th place is a tie of the stored (float32) scores
        assert np.all(np.isin(np.setxor1d(rows, col.indices), np.flatnonzero(o.dense() == z.min())))
    assert f.frames == q.shape[0]
    assert (mem.n_connections, mem.n_columns) == (n_conn, n_cols)  # queries do not change the memory


def test_exact_forward_stream_equals_dense_forward(aliased):
    mem, codes, q, _, _ = aliased
    q = q[:80]
    Z = _zscore(ev.dense_evidence(mem, q, codes, direction="forward"))
    f = _engine(mem, codes, exact=True)
    rows = [q.indices[q.indptr[j]:q.indptr[j + 1]].astype(np.int64) for j in range(q.shape[0])]
    for j, bits in enumerate(rows):
        if j == 40:
            f = _engine(mem, codes, exact=True).load_state(*f.state())
        o = f.step(bits)
        np.testing.assert_allclose(o.dense(), Z[:, j], atol=1e-6)
        assert o.best()[0] == int(np.argmax(Z[:, j]))
    with pytest.raises(ValueError, match="beam"):
        _engine(mem, codes).load_state(*f.state())


def _traverse(**kw):
    return EncodedTraverse(**kw)


def _loop_ap(S, gt, exclude):
    from sklearn.metrics import average_precision_score

    S = S.toarray() if sp.issparse(S) else S
    i, j = np.indices(S.shape)
    m = i <= j - exclude
    return average_precision_score(gt[m], np.where(np.isfinite(S[m]), S[m], -1e9))


NO_TRANSITIONS = EvidenceConf(stay=None, skip=None)


def test_loop_evidence_beats_seqslam_on_the_paper_world():
    from vpr import methods

    obs, traj = simulate.simulate_loops(aliasing=5, noise=0.3, seed=0)
    gt = traj[:, None] == traj[None]
    loop = ev.loop_evidence(obs, exclude=10, conf=NO_TRANSITIONS)
    S, codes = loop
    T = obs.shape[0]
    assert S.shape == (T, T) and codes.shape[0] == T
    i, j = np.indices((T, T))
    assert np.all(np.isneginf(S[i > j - 10])) and np.all(np.isfinite(S[i <= j - 10]))
    f = _traverse(names=list(range(T)), sdr=obs, desc=obs.toarray().astype(np.float32))
    r = methods.loops("seqslam", f, exclude=10, conf={"descriptor": "desc"})
    ap, ap_seqslam = _loop_ap(S, gt, 10), _loop_ap(r.similarity, gt, 10)
    assert ap >= 0.95 and ap > ap_seqslam, (ap, ap_seqslam)
    d = loop.decision  # the default rule: ten laps of one loop, every place revisited
    ok = d.accepted
    assert ok.sum() > 100 and np.all(gt[d.best[ok], np.flatnonzero(ok)])
    # decided on each frame's full column: the same decisions when the matrix is kept top-K
    top = ev.loop_evidence(obs, exclude=10, conf=NO_TRANSITIONS, top_k=50)
    for a in ("best", "score", "accepted"):
        assert np.array_equal(getattr(top.decision, a), getattr(d, a)), a
    # deciding again on the stored dense matrix gives them too, the closures confirmed by the frames after them
    again = confirm_closures(ev.accept_loops(loop, sdr=obs), obs, 10, NO_TRANSITIONS)
    assert np.array_equal(again.accepted, ok) and np.array_equal(again.best, d.best)
    with pytest.raises(ValueError, match="Evidence"):
        ev.accept_loops(top.similarity, exclude=10)
    # top-K: the kept entries are the dense matrix's
    Sk, codes_k = ev.loop_evidence(obs, exclude=10, conf=NO_TRANSITIONS, top_k=5)
    assert (codes_k != codes).nnz == 0
    C = Sk.tocoo()
    np.testing.assert_allclose(C.data, S[C.row, C.col], atol=1e-5)
    assert np.all(np.diff(Sk.tocsc().indptr) <= 5)
    Sa, _ = ev.loop_evidence(obs, exclude=10, conf=NO_TRANSITIONS, dense_max=100)  # beyond the limit: top-50
    assert sp.issparse(Sa) and np.all(np.diff(Sa.tocsc().indptr) <= 50) and Sa.nnz > 50


def test_loop_evidence_forward_only_drive_accepts_no_far_closure():
    import encoders
    from vpr.render import render_scene

    # a street without aliased stretches, driven once with stops
    day = render_scene("speed_change", size=(64, 48), n_frames=150, traverses=["slow"]).traverses[0]
    x = encoders.get("pixel", k=200, standardise="fit").fit(day.images).encode(day.images)
    d = ev.accept_loops(ev.loop_evidence(x), sdr=x)  # defaults: exclude 30
    T = x.shape[0]
    assert np.all(d.best[:30] == -1) and np.all(d.score[:30] == 0)
    assert not np.any(d.accepted & (np.arange(T) - d.best >= 30)), d.score[d.accepted]


def test_bad_arguments(aliased):
    mem, codes, q, _, _ = aliased
    with pytest.raises(ValueError, match="decay"):
        EvidenceConf(decay=1.0)
    with pytest.raises(ValueError, match="normalise"):
        EvidenceConf(normalise="column")
    with pytest.raises(ValueError, match="top_k"):
        ev.sparse_evidence(mem, q, codes, top_k=0)
    with pytest.raises(ValueError, match="rel_floor"):
        BeamConf(rel_floor=1.5)
    with pytest.raises(ValueError, match="direction"):
        ev.sparse_evidence(mem, q, codes, direction="backward")
    with pytest.raises(ValueError, match="max_beam"):
        BeamConf(max_beam=0)
    with pytest.raises(ValueError, match="max_enter"):
        BeamConf(max_enter=2.5)
    with pytest.raises(ValueError, match="shape"):
        ev.Localizer(mem, codes, [str(i) for i in range(codes.shape[0])]).update(np.zeros(100, bool))
    with pytest.raises(ValueError, match="exclude"):
        ev.loop_evidence(sdr.random_sdrs(5, seed=0), exclude=0)
    with pytest.raises(ValueError, match="caps"):
        ev.loop_evidence(sdr.random_sdrs(5, seed=0), exclude=1, caps="auto")
    with pytest.raises(ValueError, match="another memory"):
        ev.Graph.of(mem, sp.csr_matrix((1, mem.n_cells + 10), dtype=bool) + sp.eye(1, mem.n_cells + 10,
                                                                                   mem.n_cells + 5, dtype=bool))


def _rendered_loops(spec, n_frames, traverse=0, radius=5.0, **conf):
    import encoders
    from vpr import methods
    from vpr.render import render_scene

    t = render_scene(spec, size=(64, 48), n_frames=n_frames).traverses[traverse]
    x = encoders.get("pixel", k=200, standardise="fit").fit(t.images).encode(t.images)
    r = methods.get("rshosm-seq", **conf).loops(EncodedTraverse(names=list(range(x.shape[0])), sdr=x),
                                                exclude=30)
    gt = np.linalg.norm(t.xy[:, None] - t.xy[None], axis=-1) <= radius
    return r, gt


def test_rshosm_seq_loops_method_defaults():
    from vpr import evaluate

    # three laps of one loop (a small render, 4.6 m between frames): closures are found, each within 6 m
    r, gt = _rendered_loops("loop_revisits", 200, radius=6.0)
    T = gt.shape[0]
    assert r.similarity.shape == (T, T) and np.all(r.best[:30] == -1)
    ok = r.accepted
    assert ok.sum() >= 15 and np.all(gt[r.best[ok], np.flatnonzero(ok)])
    # the result's score is the decision's (the path score): an accepted frame has reached min_score, or leads up to
    # one that did (on its path, within backfill_frames: accepted with it)
    reached = np.flatnonzero(ok & (r.score >= LoopConf().min_score))
    for j in np.flatnonzero(ok & (r.score < LoopConf().min_score)):
        later = reached[reached > j]
        assert r.score[j] > 0 and later.size and later[0] - j <= LoopConf().backfill_frames
    assert reached.size and np.all(r.score[r.best >= 0] >= 0)
    mask = groundtruth.loop_closure_mask(T, exclude=30)
    assert evaluate.average_precision(r.similarity, gt, None, mask=mask) >= 0.5
    # a forward-only drive (two_seasons by day, before the stretch its world repeats): no closure accepted
    r, gt = _rendered_loops("two_seasons", 150)
    far = r.accepted & (np.arange(gt.shape[0]) - r.best >= 30)
    assert not far.any(), r.score[far]


def _column_stream(T, peaks, exclude=2, base=0.0):
    """A dense T x T loop matrix: every candidate z ``base``, ``peaks`` {frame: [(earlier frame, z), ...]}."""
    S = np.full((T, T), -np.inf)
    i, j = np.indices((T, T))
    S[i <= j - exclude] = base
    for q, entries in peaks.items():
        for b, z in entries:
            S[b, q] = z
    return S


def test_accept_loops_accumulates_margins_along_a_consistent_path():
    # frames 10..19 revisit 0..9 with a margin of 3 over every other place; drift 1, min_score 5: the score grows
    # by 2 a frame, reaches 6 at the third frame, which is accepted
    S = _column_stream(20, {10 + k: [(k, 3.0)] for k in range(10)})
    d = ev.accept_loops(S, LoopConf(drift=1.0, min_score=5.0, stop_ratio=0.0), exclude=2)
    np.testing.assert_allclose(d.margin[10:], 3.0)
    np.testing.assert_allclose(d.score[10:14], [2.0, 4.0, 6.0, 8.0])
    assert np.flatnonzero(d.accepted).tolist() == list(range(12, 20))
    assert np.all(d.best[10:] == np.arange(10))
    # a jump of the best earlier frame breaks the path: the score starts again
    S2 = _column_stream(40, {**{20 + k: [(k, 3.0)] for k in range(20)}, 30: [(0, 3.0)]})
    d2 = ev.accept_loops(S2, LoopConf(drift=1.0, min_score=5.0, stop_ratio=0.0), exclude=2)
    assert d2.score[29] == 20.0 and d2.score[30] == 2.0 and not d2.accepted[30] and d2.score[31] == 2.0
    # a margin below the drift never accumulates: the new-place hypothesis wins
    S3 = _column_stream(20, {10 + k: [(k, 0.9)] for k in range(10)})
    assert not ev.accept_loops(S3, LoopConf(drift=1.0, min_score=1.0, stop_ratio=0.0), exclude=2).accepted.any()
    with pytest.raises(ValueError, match="exclude"):
        ev.accept_loops(S)
    with pytest.raises(ValueError, match="min_score"):
        LoopConf(min_score=0)
    with pytest.raises(ValueError, match="back"):
        LoopConf(back=-1)


def test_accept_loops_margin_is_against_other_places_not_other_visits():
    # frames 20..29 revisit 10..19 (z 3); a look-alike place at 0..9 (z 2.5): the margin is 0.5
    peaks = {20 + k: [(10 + k, 3.0), (k, 2.5)] for k in range(10)}
    d = ev.accept_loops(_column_stream(30, peaks), LoopConf(drift=1.0, min_score=1.0, stop_ratio=0.0), exclude=2)
    np.testing.assert_allclose(d.margin[20:], 0.5)
    assert not d.accepted.any()
    # ... unless 10..19 were themselves closures onto 0..9: then 0..9 is an earlier visit of the same place,
    # not another place, and the margin is against the rest (z 0)
    peaks.update({10 + k: [(k, 3.0)] for k in range(10)})
    d = ev.accept_loops(_column_stream(30, peaks), LoopConf(drift=1.0, min_score=4.0, stop_ratio=0.0), exclude=2)
    assert d.accepted[12:20].all() and d.accepted[21:].all()
    np.testing.assert_allclose(d.margin[21:], 3.0)


def test_accept_loops_a_best_place_just_left_is_no_loop():
    # the candidates nearest to the frame (exclude frames back) stand out: the place the camera is leaving
    T, exclude = 40, 5
    peaks = {j: [(j - exclude - k, 4.0) for k in range(3)] for j in range(10, T)}
    d = ev.accept_loops(_column_stream(T, peaks, exclude), LoopConf(drift=1.0, min_score=2.0, stop_ratio=0.0),
                        exclude=exclude)
    assert not d.accepted.any() and d.score[20] > 2.0  # the score is there, the place is the one just left


@pytest.mark.slow
def test_default_loop_rule_finds_revisits_and_no_closure_on_a_forward_drive():
    # the fast preset's loop encoder (causal standardisation) on the scenes' native frame counts at 160x120
    import encoders
    from vpr import methods, presets
    from vpr.render import render_scene

    s = presets.resolve("fast", loops=True)
    for scene, traverse in (("loop_revisits", "laps"), ("two_seasons", "summer_day")):
        t = render_scene(scene, size=(160, 120), traverses=[traverse]).traverses[0]
        x = encoders.get(s["encoder"], **s["encoder_conf"]).encode(list(t.images))
        r = methods.get("rshosm-seq").loops(EncodedTraverse(names=list(range(x.shape[0])), sdr=x), exclude=30)
        T = x.shape[0]
        ok = r.accepted & (np.arange(T) - r.best >= 30)
        dist = np.linalg.norm(t.xy[r.best[ok]] - t.xy[ok], axis=1)
        if scene == "loop_revisits":  # closures in the second and third lap, all within 5 m
            assert ok.sum() >= 250 and np.all(dist <= 5.0), dist
            assert set(np.flatnonzero(ok) * 3 // T) == {1, 2}
        else:  # driven once: no closure but onto the stretch its world repeats identically 210 m later
            onto_copy = np.abs(t.route_pos[ok] - t.route_pos[r.best[ok]] - 210.0) <= 10.0
            assert onto_copy.all(), (np.flatnonzero(ok), dist)


def test_a_closure_onto_a_place_never_left_is_a_stop():
    rng = np.random.default_rng(0)
    a = rng.choice(256, 20, replace=False)
    others = [rng.choice(256, 20, replace=False) for _ in range(10)]
    # frames 0-5 stand at place A, 6-15 drive elsewhere, 16 is back at A; 17 creeps: A with 5 bits changed
    rows = [a] * 6 + others + [a, np.concatenate([a[:15], others[0][:5]])]
    x = sdr.from_indices(rows, 256)
    T = x.shape[0]
    best = np.full(T, -1)
    best[5], best[16], best[17] = 0, 0, 16
    acc = best >= 0
    stop = ev.stationary_closures(x, best, acc)
    assert np.flatnonzero(stop).tolist() == [5, 17]  # 16 left A in between; 17 never left 16
    S = np.full((T, T), -np.inf)
    S[np.triu_indices(T, 1)] = 0.0
    S[best[acc], np.flatnonzero(acc)] = 9.0
    conf = LoopConf(drift=1.0, min_score=8.0, island=5.0)  # one frame standing out by 9 is accepted
    # 17's best is the frame just before it: the place it is leaving, never a loop
    assert np.flatnonzero(ev.accept_loops(S, conf, exclude=1).accepted).tolist() == [5, 16]
    assert np.flatnonzero(ev.accept_loops(S, conf, sdr=x, exclude=1).accepted).tolist() == [16]
    no_stops = LoopConf(drift=1.0, min_score=8.0, island=5.0, stop_ratio=0)
    assert np.flatnonzero(ev.accept_loops(S, no_stops, sdr=x, exclude=1).accepted).tolist() == [5, 16]
    with pytest.raises(ValueError, match="stop_ratio"):
        LoopConf(stop_ratio=1.5)
    with pytest.raises(ValueError, match="one entry per frame"):
        ev.stationary_closures(x, best[:-1], acc)


def test_a_closure_sharing_little_beyond_chance_is_no_stop():
    # 200 bits of 2,048: two unrelated frames share about 20 by chance. Frame 29 shares 24 with frame 0 (a weak view
    # of it) and chance with every frame between: the camera drove on; counted raw, every frame in between would
    # keep the 0.35 x 24 bits of a stop
    rng = np.random.default_rng(1)
    rows = [np.sort(rng.choice(2048, 200, replace=False)) for _ in range(29)]
    rest = rng.choice(np.setdiff1d(np.arange(2048), rows[0]), 176, replace=False)
    rows.append(np.sort(np.concatenate([rows[0][:24], rest])))
    x = sdr.from_indices(rows, 2048)
    raw = [len(np.intersect1d(r, rows[-1])) for r in rows[1:-1]]
    assert min(raw) >= 0.35 * 24  # what the raw overlap reads as a stop
    best, acc = np.full(30, -1), np.zeros(30, bool)
    best[29], acc[29] = 0, True
    assert not ev.stationary_closures(x, best, acc)[29]
    stood = sdr.from_indices([rows[0]] * 10 + [rows[0][:190]], 2048)  # the same view, then 10 bits fewer
    best, acc = np.full(11, -1), np.zeros(11, bool)
    best[10], acc[10] = 0, True
    assert ev.stationary_closures(stood, best, acc)[10]
    with pytest.raises(ValueError, match="width"):
        LoopDecider(LoopConf())  # the stop check without the SDRs' width


def test_loop_evidence_carries_every_cell_unless_capped():
    # pixel-like SDRs sharing many bits, so that caps of a few cells would bind
    rng = np.random.default_rng(1)
    base = rng.random((60, 256)) < 0.5
    rows = [np.flatnonzero(base[i // 3] ^ (rng.random(256) < 0.05))[:60] for i in range(90)]
    x = sdr.from_indices(rows, 256)
    mem = {"n_inputs": 256}
    default, _ = ev.loop_evidence(x, exclude=5, **mem)
    free, _ = ev.loop_evidence(x, exclude=5, caps=False, **mem)
    tight, _ = ev.loop_evidence(x, exclude=5, conf=BeamConf(max_beam=16, max_enter=2), caps=True, **mem)
    np.testing.assert_array_equal(default, free)
    assert not np.array_equal(tight, free)
    beyond, _ = ev.loop_evidence(x, exclude=5, dense_max=50, **mem)  # top-50 sparse, the same evidence
    assert sp.issparse(beyond)


def test_the_three_directions_at_once_are_each_directions_own_evidence():
    """A batch match and its direction check read the evidence of both directions, the causal and the reversed one:
    three passes (the forward one giving two, with the reversed one beside it, the overlaps counted once) give the
    three evidences that a pass each gives."""
    from vpr import simulate

    db, q = simulate.aliased_traverses(300, 30, k=60, seed=3)[:2]
    mem = ev.SequenceMemory(threshold=0.75)
    codes = mem.run(db)
    mem.reset()
    at_once = ev.directions_evidence(mem, q, codes, top_k=20)
    for d in ("both", "forward", "reversed"):
        alone = ev.query_evidence(mem, q, codes, direction=d, top_k=20)
        assert (at_once[d].similarity != alone.similarity).nnz == 0, d
        np.testing.assert_array_equal(at_once[d].best, alone.best)
        np.testing.assert_array_equal(at_once[d].z, alone.z)
