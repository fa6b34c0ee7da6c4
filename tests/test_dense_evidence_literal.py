"""rSHOSM variants: the dense evidence of rshosm-seq (vpr.shosm.dense_evidence) against a literal version."""
import numpy as np
import pytest
import scipy.sparse as sp

from vpr import evaluate, groundtruth, methods, sdr
from vpr.methods import match
from vpr.shosm import EvidenceConf, SequenceMemory, dense_evidence
from vpr.similarity import overlap_similarity
from vpr.types import EncodedTraverse


def _literal_evidence(mem, q, db_codes, decay, stay, skip, direction):
    """Straightforward dense version of the documented rule, over all cells."""
    cpc, nc = mem.cells_per_column, mem.n_columns
    ncell = nc * cpc
    con = mem.connections
    src, dst = con.lateral.nonzero()
    columns = [set(con.feedforward[c].indices.tolist()) for c in range(nc)]
    Z = np.zeros((ncell, q.shape[0]))
    for t in range(q.shape[0]):
        for c in range(nc):
            on = len(columns[c] & set(q[t].indices.tolist()))
            Z[c * cpc:(c + 1) * cpc, t] = on / len(columns[c])

    def run(order, s, d):
        E = np.zeros_like(Z)
        e = None
        for t in order:
            if e is None:
                e = Z[:, t].copy()
            else:
                p1 = np.full(ncell, -np.inf)
                np.maximum.at(p1, d, e[s])
                p = p1.copy()
                if skip is not None:
                    p2 = np.full(ncell, -np.inf)
                    np.maximum.at(p2, d, p1[s])
                    p = np.maximum(p, p2 - skip)
                if stay is not None:
                    p = np.maximum(p, e - stay)
                p[np.isneginf(p)] = 0.0
                e = Z[:, t] + decay * p
            E[:, t] = e
        return E

    T = q.shape[0]
    E = run(range(T), src, dst)
    if direction == "both":
        E = E + run(range(T - 1, -1, -1), dst, src) - Z
    D = sp.csr_matrix(db_codes, dtype=np.float64)
    D.resize((D.shape[0], ncell))
    return (D @ E) / np.asarray(D.sum(axis=1))


def _route(n=40, n_bits=256, k=16, seed=0):
    return sdr.random_sdrs(n, n_bits, k, seed=seed)


@pytest.mark.parametrize("direction", ["forward", "both"])
@pytest.mark.parametrize("stay,skip", [(None, None), (0.05, 0.05), (0.3, None), (None, 0.2)])
def test_evidence_matches_literal_rule(direction, stay, skip):
    places = _route()
    db = sdr.add_noise(places, 0.2, seed=1)
    q = sdr.add_noise(places[::-1][:25], 0.4, seed=2)  # a different order so skips and stays matter
    mem = SequenceMemory(n_inputs=256, cells_per_column=4, new_columns=3, p_extra=0.2, seed=3)
    codes = mem.run(db)
    mem.reset()
    got = dense_evidence(mem, q, codes, EvidenceConf(decay=0.8, stay=stay, skip=skip), direction=direction)
    want = _literal_evidence(mem, q, codes, 0.8, stay, skip, direction)
    assert got.shape == (40, 25) and got.dtype == np.float32
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-5)


def test_evidence_forward_is_causal_and_learns_nothing():
    places = _route()
    mem = SequenceMemory(n_inputs=256, seed=0)
    codes = mem.run(places)
    before = (mem.n_columns, mem.n_connections)
    q = sdr.add_noise(places, 0.3, seed=4)
    a = dense_evidence(mem, q, codes, direction="forward")
    q2 = sp.vstack([q[:20], sdr.random_sdrs(20, 256, 16, seed=9)]).tocsr()
    b = dense_evidence(mem, q2, codes, direction="forward")
    np.testing.assert_array_equal(a[:, :20], b[:, :20])
    assert not np.array_equal(a[:, 20:], b[:, 20:])
    assert (mem.n_columns, mem.n_connections) == before


def test_evidence_argument_errors():
    places = _route(5)
    mem = SequenceMemory(n_inputs=256, seed=0)
    codes = mem.run(places)
    for kw, msg in [({"decay": 1.0}, "decay"), ({"stay": -0.1}, "stay"), ({"skip": float("nan")}, "skip")]:
        with pytest.raises(ValueError, match=msg):
            EvidenceConf(**kw)
    with pytest.raises(ValueError, match="direction"):
        dense_evidence(mem, places, codes, direction="backward")
    with pytest.raises(ValueError, match="sparse winner-code"):
        dense_evidence(mem, places, codes.toarray())
    with pytest.raises(ValueError, match="n_bits|bits"):
        dense_evidence(mem, sdr.random_sdrs(3, 128, 8, seed=0), codes)


def _aliased_traverses(seed=0, n=120):
    """Database and query of one route: heavy query noise, and 30 places that look like others."""
    rng = np.random.default_rng(seed)
    places = sdr.random_sdrs(n, 2048, 40, seed=seed)
    alias = rng.choice(n, size=(min(30, n // 4), 2), replace=False)
    rows = sdr.to_indices(places)
    for a, b in alias:
        rows[b] = rows[a]
    places = sdr.from_indices(rows, 2048)
    return sdr.add_noise(places, 0.2, seed=seed + 1), sdr.add_noise(places, 0.6, seed=seed + 2)


def test_rshosm_seq_beats_pairwise_and_paper_memory_under_aliasing_and_noise():
    db, q = _aliased_traverses()
    n = db.shape[0]
    # the benchmark's tolerances: |i - j| <= 1 true, <= 3 ignored
    gh, gs = groundtruth.gt_from_tolerance(n, n, 1), groundtruth.gt_from_tolerance(n, n, 3)
    names = list(range(n))
    a, b = EncodedTraverse(names, sdr=db), EncodedTraverse(names, sdr=q)

    def run(method):
        return evaluate.evaluate(match(method, a, b).similarity, gh, gs)

    seq, paper = run("rshosm-seq"), run("rshosm")
    pw = evaluate.evaluate(overlap_similarity(db, q), gh, gs)
    assert seq["recall_at_1"] > 0.95 and seq["auc_pr"] > 0.95
    assert seq["auc_pr"] > pw["auc_pr"] + 0.3
    assert seq["auc_pr"] > paper["auc_pr"] + 0.2


def test_method_registry_and_defaults():
    assert "rshosm-seq" in methods.available() and "rshosm" in methods.available()
    c = methods.get("rshosm-seq", decay="0.5").conf
    assert c["decay"] == 0.5 and c["threshold"] == 0.75 and c["normalise"] == "query"
    # the paper's memory keeps the paper's defaults
    paper = methods.get_class("rshosm").default_conf
    assert paper["threshold"] == 0.25 and paper["p_extra"] == 0.05
    with pytest.raises(ValueError, match="unknown rshosm-seq option"):
        methods.get("rshosm-seq", nope=1)


def test_rshosm_seq_normalise_and_disabled_transitions():
    db, q = _aliased_traverses(n=40)
    names = list(range(40))
    r = match("rshosm-seq", EncodedTraverse(names, sdr=db), EncodedTraverse(names, sdr=q))
    S = r.similarity
    np.testing.assert_allclose(S.mean(axis=0), 0, atol=1e-4)
    np.testing.assert_allclose(S.std(axis=0), 1, atol=1e-3)
    raw = match("rshosm-seq", EncodedTraverse(names, sdr=db), EncodedTraverse(names, sdr=q),
                {"normalise": "none", "stay": None, "skip": "none"}).similarity
    mem = SequenceMemory(threshold=0.75, seed=0)
    codes = mem.run(db)
    np.testing.assert_allclose(raw, dense_evidence(mem, q, codes, EvidenceConf(stay=None, skip=None)), rtol=1e-6)
    with pytest.raises(ValueError, match="normalise"):
        match("rshosm-seq", EncodedTraverse(names, sdr=db), EncodedTraverse(names, sdr=q), {"normalise": "global"})
    # a negative cost is an error, not a second way of saying "disabled"
    with pytest.raises(ValueError, match="stay must be >= 0 or None"):
        match("rshosm-seq", EncodedTraverse(names, sdr=db), EncodedTraverse(names, sdr=q), {"stay": -1})

