"""Compiled kernels of the sparse graded evidence (numba): the beam over a learned database."""
from __future__ import annotations

import numpy as np
from numba import njit

from .overlap import count_overlaps

# indices into the int64 state vector of beam_frames; the last two are counters (largest beam and candidate set of any
# frame so far) that tests and benchmarks read to check the caps
B_SIZE, B_OUT_POS, B_NEED, B_FRAMES, B_MAX_BEAM, B_MAX_CAND = range(6)
BEAM_STATE_SIZE = 6
@njit(cache=True, inline="always")
def _join(c, slot, cand, p1, p2, n_c):  # pragma: no cover - compiled
    """Cell ``c`` becomes candidate ``n_c`` (``slot[c] = n_c + 1``) with no offers yet. Returns the count."""
    slot[c] = n_c + 1
    cand[n_c] = c
    p1[n_c] = 0.0
    p2[n_c] = 0.0
    return n_c + 1


@njit(cache=True, inline="always")
def _relax(s, v, a_head, a_dst, a_next, p, q, slot, cand, n_c):  # pragma: no cover - compiled
    """Offer evidence ``v`` of cell ``s`` along its connections: ``p[k] = max(p[k], v)`` for every target (``k`` its
    candidate number; new targets join the candidates, ``q`` is the other offer array). Returns the candidate
    count."""
    e = a_head[s]
    while e >= 0:
        d = a_dst[e]
        k = slot[d] - 1
        if k < 0:
            k = n_c
            n_c = _join(d, slot, cand, p, q, n_c)
        if v > p[k]:
            p[k] = v
        e = a_next[e]
    return n_c


@njit(cache=True, inline="always")
def _offer(s, v, grp, gmax, gmark, gtouch, n_g):  # pragma: no cover - compiled
    """Offer evidence ``v`` of cell ``s`` to its group (the largest offer wins). Returns the touched count."""
    gi = grp[s]
    if gi >= 0:
        if not gmark[gi]:
            gmark[gi] = True
            gmax[gi] = v
            gtouch[n_g] = gi
            n_g += 1
        elif v > gmax[gi]:
            gmax[gi] = v
    return n_g


@njit(cache=True, inline="always")
def _relax_groups(n_g, gtouch, gmax, gmark, a_head, a_dst, a_next, p, q, slot, cand, n_c):  # pragma: no cover
    """Relax each touched group's largest offer along the group's one successor list."""
    for k in range(n_g):
        gi = gtouch[k]
        gmark[gi] = False
        n_c = _relax(gi, gmax[gi], a_head, a_dst, a_next, p, q, slot, cand, n_c)
    return n_c


@njit(cache=True, inline="always")
def _fraction(counts, col_size, col):  # pragma: no cover - compiled
    """Minicolumn ``col``'s overlap fraction: its count over its feed-forward connections (0 without any)."""
    return counts[col] / col_size[col] if col_size[col] > 0 else 0.0


@njit(cache=True, inline="always")
def enter_by_overlap(bits, ff, conf, scratch):  # pragma: no cover - compiled
    """Feed-forward: the overlap count of every minicolumn the frame's ``bits`` touch (kept in ``counts`` until
    the frame ends, so that every candidate gets its feed-forward term, :func:`_fraction`), and the cells of the
    minicolumns above the floor as candidates (:func:`enter_counted`). Returns (minicolumns touched, candidates)."""
    n_tc = count_overlaps(bits, ff[0], ff[1], scratch[0], scratch[1])
    return n_tc, enter_counted(n_tc, ff, conf, scratch)


@njit(cache=True, inline="always")
def enter_counted(n_tc, ff, conf, scratch):  # pragma: no cover - compiled
    """The cells of the touched minicolumns above the floor (at most ``max_enter`` minicolumns, those of largest
    overlap) as candidates, from the counts in ``scratch``. Returns the candidates."""
    col_size, col_ptr = ff[2], ff[3]
    z_floor, max_enter = conf[6], conf[8]
    counts, touched_cols, p1, p2, slot, cand = scratch[0], scratch[1], scratch[2], scratch[3], scratch[5], scratch[6]
    n_above = 0
    for i in range(n_tc):
        if _fraction(counts, col_size, touched_cols[i]) > z_floor:
            n_above += 1
    zf = z_floor
    if max_enter > 0 and n_above > max_enter:
        # SDRs that share many bits between places pass the floor in very many minicolumns: only the max_enter of
        # largest overlap enter (partial selection, O(touched))
        vals = np.empty(n_above, np.float64)
        m = 0
        for i in range(n_tc):
            zz = _fraction(counts, col_size, touched_cols[i])
            if zz > z_floor:
                vals[m] = zz
                m += 1
        zf = max(zf, np.partition(vals, n_above - max_enter - 1)[n_above - max_enter - 1])
    n_c = 0
    for i in range(n_tc):
        col = touched_cols[i]
        if _fraction(counts, col_size, col) > zf:
            for c in range(col_ptr[col], col_ptr[col + 1]):  # the minicolumn's cells that can carry evidence
                if slot[c] == 0:
                    n_c = _join(c, slot, cand, p1, p2, n_c)
    return n_c


@njit(cache=True, inline="always")
def enter_by_prediction(n_c, lateral, conf, state, scratch):  # pragma: no cover - compiled
    """Prediction: the offers of one connection from a beam cell (and of the beam cell itself: ``stay``) into
    ``p1``, and of two connections (a skipped database frame) into ``p2``; their targets join the candidates.
    Returns the candidates."""
    a_head, a_next, a_dst, grp = lateral
    stay, skip = conf[1], conf[2]
    st, beam, beam_e = state[0], state[1], state[2]
    p1, p2, slot, cand = scratch[2], scratch[3], scratch[5], scratch[6]
    gmax, gmark, gtouch = scratch[8], scratch[9], scratch[10]
    grouped = grp.shape[0] > 0
    n_g = 0
    for i in range(st[B_SIZE]):
        s = beam[i]
        v = beam_e[i]
        if stay >= 0.0 and v > stay and slot[s] == 0:
            n_c = _join(s, slot, cand, p1, p2, n_c)
        if grouped:
            n_g = _offer(s, v, grp, gmax, gmark, gtouch, n_g)
        else:
            n_c = _relax(s, v, a_head, a_dst, a_next, p1, p2, slot, cand, n_c)
    if grouped:
        n_c = _relax_groups(n_g, gtouch, gmax, gmark, a_head, a_dst, a_next, p1, p2, slot, cand, n_c)
    if skip >= 0.0:  # only p1 > skip can win
        n1 = n_c
        n_g = 0
        for i in range(n1):
            s = cand[i]
            v = p1[i]
            if v > skip:
                if grouped:
                    n_g = _offer(s, v, grp, gmax, gmark, gtouch, n_g)
                else:
                    n_c = _relax(s, v, a_head, a_dst, a_next, p2, p1, slot, cand, n_c)
        if grouped:
            n_c = _relax_groups(n_g, gtouch, gmax, gmark, a_head, a_dst, a_next, p2, p1, slot, cand, n_c)
    return n_c


@njit(cache=True, inline="always")
def new_evidence(n_c, ff, cells, conf, state, scratch):  # pragma: no cover - compiled
    """Each candidate's evidence (its feed-forward term plus ``decay`` times the best prediction, never below 0)
    into ``e_new``; returns the floor a cell must exceed to count this frame."""
    decay, stay, skip, _, floor, rel_floor = conf[0], conf[1], conf[2], conf[3], conf[4], conf[5]
    col_size, r_col = ff[2], cells[3]
    beam_e, in_beam = state[2], state[3]
    counts, p1, p2, z, cand, e_new = scratch[0], scratch[2], scratch[3], scratch[4], scratch[6], scratch[7]
    emax = 0.0
    for i in range(n_c):
        c = cand[i]
        z[i] = _fraction(counts, col_size, r_col[c])
        p = p1[i]
        if skip >= 0.0 and p2[i] - skip > p:
            p = p2[i] - skip
        if stay >= 0.0 and in_beam[c] > 0 and beam_e[in_beam[c] - 1] - stay > p:
            p = beam_e[in_beam[c] - 1] - stay
        if p < 0.0:
            p = 0.0
        en = z[i] + decay * p
        e_new[i] = en
        if en > emax:
            emax = en
    return max(floor, rel_floor * emax)


@njit(cache=True, inline="always")
def carry_floor(n_c, thr, max_beam, scratch):  # pragma: no cover - compiled
    """The evidence a cell must exceed to be carried to the next frame: ``thr``, or above the ``max_beam + 1``-th
    largest when more cells than ``max_beam`` are above it (all above ``thr`` still go to this frame's column,
    so that the z-score's sums hold every cell with evidence this frame, as without the cap)."""
    e_new = scratch[7]
    keep = thr
    if max_beam > 0 and n_c > max_beam:
        n_above = 0
        for i in range(n_c):
            if e_new[i] > thr:
                n_above += 1
        if n_above > max_beam:
            vals = np.empty(n_above, np.float64)
            m = 0
            for i in range(n_c):
                if e_new[i] > thr:
                    vals[m] = e_new[i]
                    m += 1
            keep = max(thr, np.partition(vals, n_above - max_beam - 1)[n_above - max_beam - 1])
    return keep


@njit(cache=True, inline="always")
def carry_and_output(t, n_c, thr, keep, z_weight, cells, state, scratch, out):  # pragma: no cover
    """The new beam (cells above ``keep``) and frame ``t``'s output column (database frames of the cells above
    ``thr``, each the mean of its cells' ``evidence - z_weight * z``; where ``out`` has a second value array of
    room, also the mean of ``evidence - z_weight2 * z`` there, ``out = (ptr, idx, val, val2, z_weight2)``); clears
    the frame's scratch but the overlap counts."""
    c_head, c_next, c_frame, db_norm = cells[0], cells[1], cells[2], cells[4]
    st, beam, beam_e, in_beam = state
    z, slot, cand, e_new = scratch[4], scratch[5], scratch[6], scratch[7]
    acc, db_mark, db_touch, acc2 = scratch[11], scratch[12], scratch[13], scratch[14]
    out_ptr, out_idx, out_val, out_val2, z_weight2 = out
    two = out_val2.shape[0] > 0
    for i in range(st[B_SIZE]):
        in_beam[beam[i]] = 0
    nb2 = 0
    n_touch = 0
    for i in range(n_c):
        c = cand[i]
        zc = z[i]
        slot[c] = 0
        en = e_new[i]
        if en > thr:
            if en > keep:
                beam[nb2] = c
                beam_e[nb2] = en
                nb2 += 1
                in_beam[c] = nb2
            node = c_head[c]
            while node >= 0:
                j = c_frame[node]
                if not db_mark[j]:
                    db_mark[j] = True
                    db_touch[n_touch] = j
                    n_touch += 1
                acc[j] += (en - z_weight * zc) / db_norm[j]
                if two:
                    acc2[j] += (en - z_weight2 * zc) / db_norm[j]
                node = c_next[node]
    st[B_SIZE] = nb2
    if nb2 > st[B_MAX_BEAM]:
        st[B_MAX_BEAM] = nb2
    pos = st[B_OUT_POS]
    for i in range(n_touch):
        j = db_touch[i]
        out_idx[pos] = j
        out_val[pos] = acc[j]
        if two:
            out_val2[pos] = acc2[j]
            acc2[j] = 0.0
        pos += 1
        acc[j] = 0.0
        db_mark[j] = False
    st[B_OUT_POS] = pos
    out_ptr[t + 1] = pos


@njit(cache=True, nogil=True)  # the forward and backward passes run on two threads at once
def beam_frames(query, ff, lateral, cells, conf, state, scratch, out):  # pragma: no cover - compiled
    """Sparse graded evidence for the query frames ``order`` (one direction), frame by frame in phases:
    enter by overlap, enter by prediction, new evidence, the carry floor, the new beam and the output column.

    Parameters (tuples of arrays owned by the caller; cells are the database's cells that can carry evidence,
    numbered ``0 .. n - 1`` in the order of the memory's cells: :class:`vpr.shosm.graph.Graph`)
    ----------
    query : (q_ptr, q_ind, order)
        CSR of the query SDR batch; ``order``: frames to run.
    ff : (bit_cols, bit_len, col_size, col_ptr)
        Inverted index input bit -> minicolumns, connections per minicolumn (float64), each minicolumn's cells
        ``col_ptr[m] .. col_ptr[m + 1] - 1``.
    lateral : (a_head, a_next, a_dst, grp)
        Prediction lists per source cell (reversed for a backward pass), or per group of cells with the same targets
        (``grp``: int32 group per cell, -1: none; empty: per cell); a group relaxes its largest evidence once.
    cells : (c_head, c_next, c_frame, r_col, db_norm)
        cell -> database frames whose code holds it; its minicolumn; the code size per database frame.
    conf : (decay, stay, skip, z_weight, floor, rel_floor, z_floor, max_beam, max_enter)
        As :class:`vpr.shosm.EvidenceConf` and :class:`vpr.shosm.BeamConf` (stay/skip < 0: off; caps <= 0: none); ties
        at a cap drop out together.
    state : (st, beam, beam_e, in_beam)
        ``st`` (int64, indices ``B_*``), the beam's cells and evidence, per cell its place in the beam plus one;
        carried from call to call.
    scratch : (counts, touched_cols, p1, p2, z, slot, cand, e_new, gmax, gmark, gtouch, acc, db_mark, db_touch, acc2)
        Work space: per minicolumn, per cell (``slot``: candidate number plus one, zero between frames), per
        candidate, per group and per database frame.
    out : (out_ptr, out_idx, out_val, out_val2, z_weight2)
        Per processed frame the sparse column (database frame, evidence; with room in ``out_val2``, also the
        evidence with ``z_weight2``); ``out_ptr[t + 1]`` ends frame ``order[t]``.

    Returns the number of frames processed; fewer than all when ``out_idx`` lacks room for the next frame
    (``st[B_NEED]``: the size needed), and the caller grows it and calls again.
    """
    q_ptr, q_ind, order = query
    st = state[0]
    n = order.shape[0]
    for t in range(st[B_FRAMES], n):
        q = order[t]
        need = st[B_OUT_POS] + cells[4].shape[0]  # a column holds each database frame once at most
        if need > out[1].shape[0]:
            st[B_NEED] = need
            st[B_FRAMES] = t
            return t
        n_tc, n_c = enter_by_overlap(q_ind[q_ptr[q]:q_ptr[q + 1]], ff, conf, scratch)
        _beam_step(t, n_c, ff, lateral, cells, conf, state, scratch, out)
        _clear_counts(n_tc, scratch)
    st[B_FRAMES] = n
    st[B_NEED] = 0
    return n


@njit(cache=True, inline="always")
def _beam_step(t, n_c, ff, lateral, cells, conf, state, scratch, out):  # pragma: no cover - compiled
    """A frame's phases after entering by overlap: prediction, new evidence, the carry floor, carry and output."""
    st = state[0]
    n_c = enter_by_prediction(n_c, lateral, conf, state, scratch)
    thr = new_evidence(n_c, ff, cells, conf, state, scratch)
    if n_c > st[B_MAX_CAND]:
        st[B_MAX_CAND] = n_c
    keep = carry_floor(n_c, thr, conf[7], scratch)
    carry_and_output(t, n_c, thr, keep, conf[3], cells, state, scratch, out)


@njit(cache=True, inline="always")
def _clear_counts(n_tc, scratch):  # pragma: no cover - compiled
    counts, touched_cols = scratch[0], scratch[1]
    for i in range(n_tc):
        counts[touched_cols[i]] = 0


@njit(cache=True, nogil=True)
def beam_frames_pair(query, ff, lat_a, lat_b, cells, conf_a, conf_b, state_a, state_b, scratch_a, scratch_b,
                     out_a, out_b):  # pragma: no cover - compiled
    """Two passes over the same query frames in the same order at once (:func:`beam_frames`' arguments, one of each
    per pass): each frame's overlaps are counted once for both (``scratch_b`` must hold ``scratch_a``'s counts and
    touched minicolumns). The forward evidence and the evidence of the query running the map backwards go so."""
    q_ptr, q_ind, order = query
    st_a, st_b = state_a[0], state_b[0]
    n = order.shape[0]
    for t in range(st_a[B_FRAMES], n):
        q = order[t]
        need = cells[4].shape[0]
        if st_a[B_OUT_POS] + need > out_a[1].shape[0] or st_b[B_OUT_POS] + need > out_b[1].shape[0]:
            st_a[B_NEED] = st_a[B_OUT_POS] + need
            st_b[B_NEED] = st_b[B_OUT_POS] + need
            st_a[B_FRAMES] = t
            return t
        n_tc, n_c = enter_by_overlap(q_ind[q_ptr[q]:q_ptr[q + 1]], ff, conf_a, scratch_a)
        _beam_step(t, n_c, ff, lat_a, cells, conf_a, state_a, scratch_a, out_a)
        _beam_step(t, enter_counted(n_tc, ff, conf_b, scratch_b), ff, lat_b, cells, conf_b, state_b, scratch_b, out_b)
        _clear_counts(n_tc, scratch_a)
    st_a[B_FRAMES] = n
    st_a[B_NEED] = 0
    return n


@njit(cache=True)
def count_new_entries(col_size, bits, old_len, bit_len, bit_cols):
    """Add the feed-forward connections made since ``old_len`` (new minicolumns) to ``col_size``."""
    for i in range(bits.shape[0]):
        b = bits[i]
        for j in range(old_len[b], bit_len[b]):
            col_size[bit_cols[b, j]] += 1.0
