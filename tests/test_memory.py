import numpy as np
import pytest

from tests.reference import ReferenceMemory
from vpr import sdr, simulate
from vpr.shosm import MemoryFileError, SequenceMemory, pad_codes


def _small_walk(seed=0, n_places=30, steps=500, noise=0.3):
    world = simulate.make_world(5, n_places // 5, n_bits=256, n_active=12, aliasing=3, seed=seed)
    traj = simulate.random_walk(5, n_places // 5, steps, seed=seed + 1)
    return simulate.observe(world, traj, noise, seed=seed + 2)


def _same_as_reference(mem_kw, obs, learn_split):
    fast = SequenceMemory(**mem_kw)
    ref = ReferenceMemory(**mem_kw)
    codes = fast.run(obs[:learn_split])
    for i in range(learn_split):
        assert codes[i].indices.tolist() == ref.step(obs[i].indices), f"frame {i}"
    fast.reset()
    ref.reset()
    codes = fast.run(obs[learn_split:], learn=False)
    for i in range(obs.shape[0] - learn_split):
        assert codes[i].indices.tolist() == ref.step(obs[learn_split + i].indices, learn=False), f"query {i}"
    assert fast.n_connections == sum(len(v) for v in ref.forward.values())
    assert fast.n_columns == len(ref.columns)


@pytest.mark.parametrize("p_extra", [0.0, 0.05, 0.5])
@pytest.mark.parametrize("k_active", [0, 10])
def test_matches_literal_reference(p_extra, k_active):
    # small cells/columns so the run outgrows every initial array (columns, edges, hash sets, tape)
    kw = dict(n_inputs=256, cells_per_column=4, new_columns=3, p_extra=p_extra, k_active=k_active, seed=7)
    _same_as_reference(kw, _small_walk(), 400)


def test_matches_reference_with_paper_parameters_and_noise():
    obs, _ = simulate.simulate_loops(aliasing=5, noise=0.5, n_loops=4, seed=3)
    _same_as_reference(dict(p_extra=0.05, seed=1), obs, 60)


def test_paper_defaults():
    m = SequenceMemory()
    assert (m.n_inputs, m.cells_per_column, m.new_columns, m.connectivity, m.threshold) == (2048, 32, 10, 0.5, 0.25)


def test_fig2_toy_route():
    """Route A B C D E B C (paper, Fig. 2): the second B gets new winners, the second C the first C's."""
    places = sdr.random_sdrs(5, seed=0)
    m = SequenceMemory(p_extra=0.0, seed=0)
    w = {}
    for t, p in enumerate([0, 1, 2, 3, 4, 1, 2]):
        w[t] = set(m.step(places[p]).tolist())
    assert len(w[1]) == 10 and len(w[5]) == 10
    assert not w[1] & w[5]   # B_A and B_ABCDE: same minicolumns, different cells
    assert w[2] == w[6]      # C_AB and C_ABCDEB: identical thanks to bursting


def test_new_columns_and_threshold():
    m = SequenceMemory(seed=0)
    x = sdr.random_sdrs(1, seed=1)
    m.step(x)
    assert m.n_columns == 10 and m.n_cells == 320
    assert len(m.active_columns) == 10
    # every column samples 20 of the 40 bits; 5 (25%) shared bits activate it, 4 do not
    ff = m.connections.feedforward
    assert ff.shape == (10, 2048) and (ff.sum(axis=1) == 20).all()
    assert set(ff.indices) <= set(x.indices.tolist())  # every column samples only the input's bits
    bits_of_col0 = ff[0].indices.tolist()
    assert len(bits_of_col0) == 20 and set(m.connections.columns_of_bit(bits_of_col0[0])) >= {0}
    m.reset()
    m.step(np.array(bits_of_col0[:5]), learn=False)
    assert 0 in m.active_columns
    m2 = SequenceMemory(seed=0, k_active=0)
    m2.step(x)
    m2.reset()
    m2.step(np.array(bits_of_col0[:4]), learn=False)
    assert 0 not in m2.active_columns


def test_bursting_picks_cell_with_fewest_forward_connections():
    a, b = sdr.random_sdrs(2, seed=4)
    m = SequenceMemory(p_extra=0.0, seed=0)
    wa = m.step(a)
    m.step(b)  # wa -> wb learned: cells of wa now have one forward connection each
    m.reset()
    wa2 = m.step(a)  # no context: burst again, must avoid the cells that already predict
    assert not set(wa) & set(wa2)


def test_learning_off_creates_nothing_and_falls_back_to_k_best_columns():
    obs = sdr.random_sdrs(20, seed=2)
    m = SequenceMemory(seed=0)
    m.run(obs[:10])
    cols, conns = m.n_columns, m.n_connections
    unseen = m.run(obs[10:], learn=False)
    assert (m.n_columns, m.n_connections) == (cols, conns)
    # random unseen inputs rarely reach the threshold; the fallback still gives winners
    # whenever any column overlaps at all
    assert unseen.nnz > 0
    strict = SequenceMemory(seed=0, k_active=0)
    strict.run(obs[:10])
    assert strict.run(obs[10:], learn=False).nnz < unseen.nnz


def test_database_then_query_recognises_the_route():
    world = simulate.make_world(1, 40, seed=5)
    traj = np.arange(40)
    db, q = simulate.observe(world, traj, 0.2, seed=1), simulate.observe(world, traj, 0.2, seed=2)
    m = SequenceMemory(seed=0)
    dbc = m.run(db)
    m.reset()
    qc = m.run(q, learn=False)
    dbc, qc = pad_codes(dbc, qc)
    from vpr.similarity import overlap_similarity

    S = overlap_similarity(dbc, qc)
    assert np.mean(S.argmax(axis=0) == traj) > 0.95


def test_reset_keeps_what_was_learned():
    obs = sdr.random_sdrs(5, seed=3)
    m = SequenceMemory(seed=0)
    m.run(obs)
    m.step(obs[0])  # a known place without context: bursting predicts the learned successor
    before = (m.n_columns, m.n_connections)
    assert m.predictive_cells.size > 0
    m.reset()
    assert m.predictive_cells.size == 0 and m.winner_cells.size == 0
    assert (m.n_columns, m.n_connections) == before


def test_seeded_and_deterministic():
    obs = _small_walk(seed=3, steps=200)
    kw = dict(n_inputs=256, cells_per_column=8, new_columns=4)
    a = SequenceMemory(**kw, seed=1).run(obs)
    b = SequenceMemory(**kw, seed=1).run(obs)
    c = SequenceMemory(**kw, seed=2).run(obs)
    assert a.shape == b.shape and (a != b).nnz == 0
    assert a.shape != c.shape or (a != c).nnz > 0


def test_empty_input_breaks_the_context():
    m = SequenceMemory(seed=0)
    m.step(sdr.random_sdrs(1, seed=0))
    assert m.step(np.array([], dtype=int)).size == 0
    assert m.predictive_cells.size == 0 and m.n_columns == 10


def test_bad_input():
    m = SequenceMemory()
    with pytest.raises(ValueError, match="expected 2048 bits"):
        m.run(sdr.random_sdrs(2, n_bits=1024, seed=0))
    with pytest.raises(ValueError, match="bit index 5000"):
        m.step(np.array([1, 5000]))
    with pytest.raises(ValueError, match="one SDR row"):
        m.step(sdr.random_sdrs(2, seed=0))
    with pytest.raises(ValueError, match="p_extra"):
        SequenceMemory(p_extra=1.5)
    with pytest.raises(ValueError, match="threshold"):
        SequenceMemory(threshold=0)


def test_save_load_continues_identically(tmp_path):
    obs = _small_walk(seed=1, steps=300)
    kw = dict(n_inputs=256, cells_per_column=4, new_columns=3, p_extra=0.2, seed=3)
    a = SequenceMemory(**kw)
    a.run(obs[:150])
    path = a.save(tmp_path / "mem.npz")
    assert [p.name for p in tmp_path.iterdir()] == ["mem.npz"]  # no temp file left behind
    b = SequenceMemory.load(path)
    assert b.get_params() == a.get_params()
    ca, cb = a.run(obs[150:]), b.run(obs[150:])
    assert (ca != cb).nnz == 0
    assert (a.n_columns, a.n_connections) == (b.n_columns, b.n_connections)


def test_load_rejects_bad_files(tmp_path):
    with pytest.raises(MemoryFileError, match="no such SequenceMemory file"):
        SequenceMemory.load(tmp_path / "missing.npz")
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"not a zip file at all")
    with pytest.raises(MemoryFileError, match="junk.npz"):
        SequenceMemory.load(junk)
    foreign = tmp_path / "foreign.npz"
    np.savez(foreign, x=np.arange(3))
    with pytest.raises(MemoryFileError, match="foreign.npz"):
        SequenceMemory.load(foreign)
    m = SequenceMemory(seed=0)
    m.run(sdr.random_sdrs(3, seed=0))
    good = m.save(tmp_path / "good.npz")
    with np.load(good) as z:
        data = {k: z[k] for k in z.files}
    data["e_dst"] = data["e_dst"] + 10**6  # out of range: would crash the kernel
    np.savez(tmp_path / "bad.npz", **data)
    with pytest.raises(MemoryFileError, match="e_dst"):
        SequenceMemory.load(tmp_path / "bad.npz")
    import json

    header = json.loads(str(data["header"]))
    header["version"] = 99
    data["header"] = np.array(json.dumps(header))
    data["e_dst"] = data["e_dst"] - 10**6
    np.savez(tmp_path / "v99.npz", **data)
    with pytest.raises(MemoryFileError, match="version 99"):
        SequenceMemory.load(tmp_path / "v99.npz")


def test_pad_codes():
    a = sdr.from_indices([[1]], 4)
    b = sdr.from_indices([[7]], 8)
    pa, pb = pad_codes(a, b)
    assert pa.shape == pb.shape == (1, 8)


def test_connections_view_matches_what_was_learned():
    obs = _small_walk(seed=4, steps=150)
    kw = dict(n_inputs=256, cells_per_column=4, new_columns=3, p_extra=0.2, seed=2)
    m, ref = SequenceMemory(**kw), ReferenceMemory(**kw)
    m.run(obs)
    for i in range(obs.shape[0]):
        ref.step(obs[i].indices)
    con = m.connections
    assert (con.n_columns, con.n_cells, con.n_connections) == (m.n_columns, m.n_cells, m.n_connections)
    assert con.feedforward.dtype == bool and con.lateral.dtype == bool
    assert [set(con.feedforward[c].indices.tolist()) for c in range(con.n_columns)] == ref.columns
    assert (con.column_sizes() == m.column_sizes()).all() and con.column_sizes().sum() == m.n_feedforward
    lat = con.lateral.tocoo()
    assert set(zip(lat.row.tolist(), lat.col.tolist(), strict=True)) == {
        (s, d) for s, ds in ref.forward.items() for d in ds}
    assert con.thresholds.tolist() == ref.thresholds
    assert m.nbytes >= con.column_sizes().sum() * 4 + m.n_connections * 8 * 3
    with pytest.raises(ValueError):
        con.lateral.data[0] = False  # a read-only copy, not the memory's arrays


def test_query_leaves_the_memory_unchanged():
    obs = _small_walk(seed=5, steps=300)
    kw = dict(n_inputs=256, cells_per_column=8, new_columns=3, p_extra=0.1, seed=4)
    m = SequenceMemory(**kw)
    m.run(obs[:200])
    q1 = m.run(obs[200:], learn=False, reset=True)
    q2 = m.run(obs[200:], learn=False, reset=True)
    assert q1.nnz > 0 and (q1 != q2).nnz == 0  # same memory, same query, same answer
    m.reset()
    stepped = [m.step(obs[200 + i], learn=False).tolist() for i in range(100)]
    assert stepped == [q1[i].indices.tolist() for i in range(100)]
    # learning afterwards continues exactly as if no query had been made
    fresh = SequenceMemory(**kw)
    fresh.run(obs[:200])
    a, b = m.run(obs[:100], reset=True), fresh.run(obs[:100], reset=True)
    assert (a != b).nnz == 0 and m.n_connections == fresh.n_connections


def test_step_reads_a_row_as_run_does():
    kw = dict(n_inputs=64, new_columns=2, cells_per_column=4, seed=0)
    x = sdr.random_sdrs(1, n_bits=64, n_active=6, seed=3)
    dense = x.toarray()[0]
    expected = SequenceMemory(**kw).run(x)[0].indices.tolist()
    rows = {"bool": dense, "uint8 0/1": dense.astype(np.uint8), "int 0/1": dense.astype(np.int64),
            "float 0/1": dense.astype(float), "1 x n bool": dense[None, :], "indices": x.indices,
            "int32 indices": x.indices.astype(np.int32), "sparse row": x}
    for name, row in rows.items():
        m = SequenceMemory(**kw)
        assert m.step(row).tolist() == expected, name
        assert set(m.connections.feedforward.indices.tolist()) <= set(x.indices.tolist()), name
    # run() reads the dense 0/1 form the same way
    assert SequenceMemory(**kw).run(dense[None, :].astype(np.uint8))[0].indices.tolist() == expected
    m = SequenceMemory(**kw)
    with pytest.raises(ValueError, match="ambiguous"):
        m.step(np.arange(64))  # n_inputs values that are not 0/1
    with pytest.raises(ValueError, match="integers"):
        m.step(np.array([1.5, 2.0]))
    with pytest.raises(ValueError, match="one row"):
        m.step(np.zeros((2, 64), bool))


def test_column_sizes_kept_up_to_date_while_learning_equal_a_full_count():
    from vpr import sdr as _sdr
    from vpr.shosm import SequenceMemory as _Mem

    m = _Mem(n_inputs=512, seed=0, threshold=0.75)
    x = _sdr.random_sdrs(120, 512, 60, seed=1)
    for j in range(x.shape[0]):
        m.step(x[j])
        if j % 7 == 0:
            kept = m.column_sizes()
            m._col_sizes = None  # forget what was kept: count the whole inverted index
            np.testing.assert_array_equal(kept, m.column_sizes())
    assert m.column_sizes().sum() == m.n_feedforward
