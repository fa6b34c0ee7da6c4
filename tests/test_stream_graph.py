"""The evidence over one stream laid out by frame is the beam's, read literally (tests/reference.py)."""
import numpy as np
import pytest

from tests.reference import stream_beam_reference
from vpr import sdr
from vpr.shosm import EvidenceConf, SequenceMemory, StreamEngine, StreamGraph
from vpr.shosm.conf import BeamConf
from vpr.similarity import n_candidates


def _stream(seed=0, n=60, bits=128, k=12):
    """A route driven twice (the second time with a tenth of every frame's bits moved), so that loops close."""
    rng = np.random.default_rng(seed)
    places = [np.sort(rng.choice(bits, k, replace=False)) for _ in range(n // 2)]
    again = []
    for p in places:
        moved = p.copy()
        moved[rng.random(k) < 0.1] = rng.choice(bits, 1)
        again.append(np.unique(moved))
    return places + again


@pytest.mark.parametrize("seed,sessions,shared", [(0, (), False), (1, (25,), False), (2, (30,), True),
                                                  (0, (), True)])
def test_the_stream_engine_gives_the_beams_evidence(seed, sessions, shared):
    """Counting each frame's overlaps itself or reading the memory's count of them (``shared``)."""
    rows = _stream(seed)
    exclude = 4
    evidence, beam = EvidenceConf(), BeamConf(max_beam=None, max_enter=None)
    stay, skip = evidence.costs
    ref = stream_beam_reference(rows, exclude, evidence.decay, stay, skip, beam.floor, beam.rel_floor, beam.z_floor,
                                sessions=sessions)
    mem = SequenceMemory(n_inputs=128, seed=0)
    g = StreamGraph(mem)
    eng = StreamEngine(g, evidence, beam)
    start = 0
    for j, bits in enumerate(rows):
        if j in sessions:
            mem.reset()
            eng.reset()
            start = j
        old_len, ne_old = mem.view().bit_len.copy(), mem.n_connections
        winners = mem.step(np.asarray(bits, np.int64), keep_overlaps=shared)
        g.attach(np.asarray(bits, np.int64), winners, old_len, ne_old)
        eng.grow()
        got_rows, got_val, _ = eng.step_raw(np.asarray(bits, np.int64), n_candidates(j, exclude, start),
                                            overlaps=mem.overlaps() if shared else None)
        want = ref[j]
        assert got_rows.tolist() == sorted(want), j
        np.testing.assert_allclose(got_val, [want[f] for f in sorted(want)], rtol=1e-12, atol=0)


def test_a_frames_connections_are_one_block_of_every_source_to_every_target_or_its_pairs():
    mem = SequenceMemory(n_inputs=64, seed=0)
    g = StreamGraph(mem)
    x = sdr.random_sdrs(12, 64, 6, seed=3)
    for j in range(12):
        bits = x.indices[x.indptr[j]:x.indptr[j + 1]].astype(np.int64)
        old_len, ne_old = mem.view().bit_len.copy(), mem.n_connections
        g.attach(bits, mem.step(bits), old_len, ne_old)
    v = mem.view()
    pairs = set()
    for b in range(g.n_blocks):
        if g.p_ptr[b + 1] > g.p_ptr[b]:
            pairs |= set(zip(g.p_s[g.p_ptr[b]:g.p_ptr[b + 1]].tolist(), g.p_d[g.p_ptr[b]:g.p_ptr[b + 1]].tolist(),
                             strict=True))
        else:
            pairs |= {(s, d) for s in g.s_r[g.s_ptr[b]:g.s_ptr[b + 1]].tolist()
                      for d in g.d_r[g.d_ptr[b]:g.d_ptr[b + 1]].tolist()}
    assert pairs == set(zip(g.numbers(v.e_src).tolist(), g.numbers(v.e_dst).tolist(), strict=True))
    # cells numbered in the order they first won: each frame's new cells after the earlier frames'
    assert np.all(np.diff(g.r_end[: g.n_frames]) >= 0) and g.r_end[g.n_frames - 1] == g.n_r


def test_an_answers_column_kept_to_its_best_candidates_scores_the_rest_as_the_fill():
    from vpr.types import Column

    c = Column(np.array([1, 4, 6, 9]), np.array([0.5, 2.0, -1.0, 1.5], np.float32), -3.0, 12, 7)
    k = c.kept(2)
    assert k.rows.tolist() == [4, 9] and k.z.tolist() == [2.0, 1.5] and k.fill == -3.0 and k.n == 12
    assert k.best() == c.best() and c.kept(None) is c and c.kept(10) is c
