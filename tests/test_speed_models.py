"""Speed models of rSHOSM-seq's evidence: one evidence per model of the query's speed, merged by the largest score."""
import numpy as np
import pytest
import scipy.sparse as sp

from vpr import methods, simulate
from vpr.shosm import (
    EvidenceConf,
    Graph,
    Localizer,
    RshosmSeqConf,
    SequenceMemory,
    SpeedEngine,
    make_engine,
    query_evidence,
)
from vpr.shosm.evidence import Evidence, merge_columns, merge_evidence
from vpr.similarity import best_matches
from vpr.types import Column


@pytest.fixture(scope="module")
def learned():
    db, q, _, _ = simulate.aliased_traverses(120, 30, n_bits=512, k=20, speed=(1.8, 2.2), seed=3)
    mem = SequenceMemory(n_inputs=512, seed=0)
    codes = mem.run(db, learn=True)
    return mem, codes, q


def test_speeds_name_the_models_and_each_model_is_its_costs():
    same, faster, slower = EvidenceConf(stay=0.05, skip=0.04, speeds="same+faster+slower").split()
    assert (same.costs, faster.costs, slower.costs) == ((0.05, 0.04), (0.05, 0.0), (0.0, 0.04))
    assert all(c.speeds == "same" for c in (same, faster, slower))
    assert EvidenceConf().split() == (EvidenceConf(),)
    for bad in ("same+same", "quick", "", "same,faster"):
        with pytest.raises(ValueError, match="speeds must join distinct names of same, faster, slower"):
            EvidenceConf(speeds=bad)
    # one spelling on the command line: rshosm-seq.speeds=same+faster
    assert methods.get("rshosm-seq", speeds="same+faster").seq.evidence.speeds == "same+faster"
    with pytest.raises(ValueError, match="rshosm-seq: speeds must"):
        methods.get("rshosm-seq", speeds="fast")


def test_columns_merge_by_the_largest_score_a_missing_candidate_scoring_its_fill():
    a = Column(np.array([1, 3]), np.array([2.0, 0.5], np.float32), -1.0, 5, 7)
    b = Column(np.array([3, 4]), np.array([1.5, -0.5], np.float32), -0.2, 5, 7)
    m = merge_columns([a, b])
    assert m.rows.tolist() == [1, 3, 4] and m.z.tolist() == [2.0, 1.5, -0.5] and m.fill == pytest.approx(-0.2)
    assert (m.n, m.frame) == (5, 7) and merge_columns([a]) is a


def test_traverses_merge_as_their_dense_matrices_with_missing_entries_lowest():
    rng = np.random.default_rng(0)
    parts, dense = [], []
    for _ in range(3):
        D = rng.normal(size=(30, 12)).astype(np.float32)
        keep = np.argsort(-D, axis=0)[:5]  # top-5 per query
        S = sp.csr_matrix((D[keep, np.arange(12)].ravel(), (keep.ravel(), np.tile(np.arange(12), 5))), shape=D.shape)
        parts.append(Evidence(S, *best_matches(S)))
        low = np.min(np.where(S.toarray() != 0, S.toarray(), np.inf), axis=0)
        dense.append(np.where(S.toarray() != 0, S.toarray(), low))
    m = merge_evidence(parts, 4)
    want = np.max(dense, axis=0)
    C = m.similarity.tocsc()
    assert np.diff(C.indptr).tolist() == [4] * 12
    for j in range(12):
        rows = C.indices[C.indptr[j]:C.indptr[j + 1]]
        np.testing.assert_allclose(np.sort(C.data[C.indptr[j]:C.indptr[j + 1]])[::-1], np.sort(want[:, j])[::-1][:4])
        np.testing.assert_allclose(want[rows, j], C.data[C.indptr[j]:C.indptr[j + 1]])
    np.testing.assert_array_equal(m.best, np.argmax(want, axis=0))
    assert merge_evidence(parts[:1], 4) is parts[0]


def test_a_speed_engine_steps_as_its_models_apart_and_continues_from_its_state(learned):
    mem, codes, q = learned
    g = Graph.of(mem, codes)
    conf = EvidenceConf(speeds="same+faster")
    assert isinstance(make_engine(g, conf), SpeedEngine) and not isinstance(make_engine(g, EvidenceConf()),
                                                                            SpeedEngine)
    both, apart = make_engine(g, conf), [make_engine(g, c) for c in conf.split()]
    rows = [q.indices[q.indptr[j]:q.indptr[j + 1]].astype(np.int64) for j in range(q.shape[0])]
    for j in range(20):
        got, want = both.step(rows[j], frame=j), merge_columns([e.step(rows[j], frame=j) for e in apart])
        np.testing.assert_array_equal(got.rows, want.rows)
        np.testing.assert_array_equal(got.z, want.z)
    header, arrays = both.state()
    again = make_engine(g, conf).load_state(header, arrays)
    assert again.frames == both.frames == 20
    for j in range(20, 30):
        a, b = both.step(rows[j], frame=j), again.step(rows[j], frame=j)
        np.testing.assert_array_equal(a.rows, b.rows)
        np.testing.assert_array_equal(a.z, b.z)
    with pytest.raises(ValueError, match="speed models"):
        make_engine(g, EvidenceConf()).load_state(header, arrays)
    with pytest.raises(ValueError, match="speed models"):
        make_engine(g, conf).load_state(*make_engine(g, EvidenceConf()).state())


def test_a_traverse_merges_its_models_dense_and_top_k(learned):
    mem, codes, q = learned
    conf = EvidenceConf(speeds="same+faster")
    dense = query_evidence(mem, q, codes, conf)
    lanes = [query_evidence(mem, q, codes, c).similarity for c in conf.split()]
    np.testing.assert_array_equal(dense.similarity, np.maximum(*lanes))
    top = query_evidence(mem, q, codes, conf, top_k=5)
    parts = [query_evidence(mem, q, codes, c, top_k=5) for c in conf.split()]
    assert (top.similarity != merge_evidence(parts, 5).similarity).nnz == 0
    assert query_evidence(mem, q, codes, EvidenceConf(speeds="same"), top_k=5).similarity.nnz > 0


def test_a_map_localises_with_other_speed_models_afresh(learned):
    mem, codes, q = learned
    loc = Localizer(mem, codes, [str(i) for i in range(codes.shape[0])])
    for j in range(5):
        loc.update(q[j])
    faster = loc.reconfigure(speeds="same+faster")
    assert isinstance(faster.engine, SpeedEngine) and faster.frames == 0
    assert faster.update(q[5]).frame == 0
    assert isinstance(Localizer(mem, codes, list("x" * codes.shape[0]), RshosmSeqConf.of(speeds="faster")).engine,
                      type(loc.engine))


def test_a_loop_detector_of_two_speed_models_continues_from_its_file(tmp_path):
    from vpr.shosm import LoopDetector

    db, q, _, _ = simulate.aliased_traverses(150, 30, n_bits=512, k=20, seed=2)
    stream = sp.vstack([db, q]).tocsr()
    d = LoopDetector(n_inputs=512, speeds="same+faster")
    for j in range(100):
        d.update(stream[j])
    d.take_late()  # answers handed out before the save
    d.save(tmp_path / "s.npz")
    e = LoopDetector.load(tmp_path / "s.npz")
    assert isinstance(e.stream.engine, SpeedEngine)
    for j in range(100, stream.shape[0]):
        got = [[r, *det.take_late()] for r, det in ((d.update(stream[j]), d), (e.update(stream[j]), e))]
        a, b = ([(x.frame, x.best, x.accepted, x.score) for x in g if x is not None] for g in got)
        assert a == b  # this frame's answer, or the frames' that waited for it
