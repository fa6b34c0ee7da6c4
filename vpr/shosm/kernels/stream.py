"""Compiled kernel of the graded evidence over one stream's memory, laid out by frame (numba): loop closure.

The beam's evidence (:mod:`vpr.shosm.kernels.beam`) with the same floors, caps and offers, over arrays that a stream
fills in the order it learns: its cells numbered in the order they first won (``r``; those learned by frame ``L`` are
``0 .. r_end[L] - 1``), each frame's winner code (``code_ptr``, ``code_r``) and each frame's new lateral connections
as one block (sources, targets, and the pairs where they are not every source to every target). A frame's evidence
is one pass over these arrays in order, where the beam follows linked lists scattered over the whole memory: the
same evidence up to the order of its sums (``research/docs/benchmarks.md``, "Online at camera rate").
"""
from __future__ import annotations

import numpy as np
from numba import njit

from .overlap import count_overlaps

#: indices into the float64 parameter vector
P_DECAY, P_STAY, P_SKIP, P_ZW, P_FLOOR, P_REL, P_ZFLOOR, P_MAX_BEAM, P_MAX_ENTER = range(9)


@njit(cache=True, inline="always")
def _fraction(counts, col_size, col):  # pragma: no cover - compiled
    return counts[col] / col_size[col] if col_size[col] > 0 else 0.0


@njit(cache=True, inline="always")
def _enter_floor(n_tc, touched, counts, col_size, z_floor, max_enter):  # pragma: no cover - compiled
    """The overlap fraction a minicolumn's cells must exceed to enter: ``z_floor``, or above the ``max_enter``-th
    largest of the touched minicolumns when more pass it (as :func:`vpr.shosm.kernels.beam.enter_by_overlap`)."""
    if max_enter <= 0:
        return z_floor
    n_above = 0
    for i in range(n_tc):
        if _fraction(counts, col_size, touched[i]) > z_floor:
            n_above += 1
    if n_above <= max_enter:
        return z_floor
    vals = np.empty(n_above, np.float64)
    m = 0
    for i in range(n_tc):
        zz = _fraction(counts, col_size, touched[i])
        if zz > z_floor:
            vals[m] = zz
            m += 1
    return max(z_floor, np.partition(vals, n_above - max_enter - 1)[n_above - max_enter - 1])


@njit(cache=True, inline="always")
def _relax_blocks(n_blocks, src_val, dst_p, cand, n_r, blocks, threshold):  # pragma: no cover - compiled
    """Offer ``src_val[s]`` (where above ``threshold``) along every block's connections: ``dst_p[d] = max(dst_p[d],
    value)``, and ``d`` becomes a candidate; sources and targets beyond ``n_r`` (not learned yet) take no part."""
    s_ptr, s_r, d_ptr, d_r, p_ptr, p_s, p_d = blocks
    for b in range(n_blocks):
        if p_ptr[b + 1] > p_ptr[b]:  # the block's pairs, where not every source predicts every target
            for k in range(p_ptr[b], p_ptr[b + 1]):
                s = p_s[k]
                d = p_d[k]
                if s < n_r and d < n_r:
                    v = src_val[s]
                    if v > threshold:
                        cand[d] = 1
                        if v > dst_p[d]:
                            dst_p[d] = v
            continue
        m = threshold
        for k in range(s_ptr[b], s_ptr[b + 1]):
            s = s_r[k]
            if s < n_r and src_val[s] > m:
                m = src_val[s]
        if m > threshold:
            for k in range(d_ptr[b], d_ptr[b + 1]):
                d = d_r[k]
                if d < n_r:
                    cand[d] = 1
                    if m > dst_p[d]:
                        dst_p[d] = m


@njit(cache=True, inline="always")
def feed_forward(bits, counted, n_r, ff, cells, params, e_beam, scratch):  # pragma: no cover - compiled
    """The frame's overlap count through the inverted index (``counted`` >= 0: counted already, that many minicolumns
    touched, as the memory counted them learning the frame: :meth:`vpr.shosm.SequenceMemory.overlaps`); every cell's
    overlap fraction ``z``; as candidates the cells of the minicolumns above the floor and the beam cells above
    ``stay``. Sets the counts back to 0; returns the minicolumns touched."""
    bit_cols, bit_len, col_size = ff
    r_col = cells[0]
    counts, touched, p1, p2, z, _, cand = scratch
    stay = params[P_STAY]
    n_tc = count_overlaps(bits, bit_cols, bit_len, counts, touched) if counted < 0 else counted
    zf = _enter_floor(n_tc, touched, counts, col_size, params[P_ZFLOOR], int(params[P_MAX_ENTER]))
    for r in range(n_r):
        zz = _fraction(counts, col_size, r_col[r])
        z[r] = zz
        p1[r] = 0.0
        p2[r] = 0.0
        cand[r] = 1 if zz > zf else 0
        if stay >= 0.0 and e_beam[r] > stay:
            cand[r] = 1  # a beam cell stays a candidate at a cost
    for i in range(n_tc):
        counts[touched[i]] = 0
    return n_tc


@njit(cache=True, inline="always")
def predict(n_r, n_blocks, blocks, params, e_beam, scratch):  # pragma: no cover - compiled
    """Offers along the blocks: one connection from a beam cell (``p1``); two, a skipped frame (``p2``), from a
    candidate whose ``p1`` is above ``skip``."""
    p1, p2, cand = scratch[2], scratch[3], scratch[6]
    _relax_blocks(n_blocks, e_beam, p1, cand, n_r, blocks, 0.0)
    if params[P_SKIP] >= 0.0:
        _relax_blocks(n_blocks, p1, p2, cand, n_r, blocks, params[P_SKIP])


@njit(cache=True, inline="always")
def new_beam(n_r, params, e_beam, scratch):  # pragma: no cover - compiled
    """Each candidate's evidence (``e_new``), the floor it must exceed to count (returned), and the next beam (the
    cells above the carry floor: ``thr``, or the ``max_beam``-th largest above it) in ``e_beam``."""
    p1, p2, z, e_new, cand = scratch[2], scratch[3], scratch[4], scratch[5], scratch[6]
    decay, stay, skip = params[P_DECAY], params[P_STAY], params[P_SKIP]
    max_beam = int(params[P_MAX_BEAM])
    emax = 0.0
    for r in range(n_r):
        if cand[r]:
            p = p1[r]
            if skip >= 0.0 and p2[r] - skip > p:
                p = p2[r] - skip
            if stay >= 0.0 and e_beam[r] > 0.0 and e_beam[r] - stay > p:
                p = e_beam[r] - stay
            if p < 0.0:
                p = 0.0
            en = z[r] + decay * p
            e_new[r] = en
            if en > emax:
                emax = en
        else:
            e_new[r] = 0.0
    thr = max(params[P_FLOOR], params[P_REL] * emax)
    keep = thr
    if max_beam > 0:  # the carry floor: above the (max_beam + 1)-th largest when more cells are above thr
        n_above = 0
        for r in range(n_r):
            if cand[r] and e_new[r] > thr:
                n_above += 1
        if n_above > max_beam:
            vals = np.empty(n_above, np.float64)
            m = 0
            for r in range(n_r):
                if cand[r] and e_new[r] > thr:
                    vals[m] = e_new[r]
                    m += 1
            keep = max(thr, np.partition(vals, n_above - max_beam - 1)[n_above - max_beam - 1])
    for r in range(n_r):
        en = e_new[r]
        e_beam[r] = en if cand[r] and en > keep else 0.0
    for r in range(n_r, e_beam.shape[0]):
        if e_beam[r] != 0.0:
            e_beam[r] = 0.0
    return thr


@njit(cache=True, inline="always")
def output(n_r, n_frames, thr, codes, params, scratch, out_idx, out_val):  # pragma: no cover - compiled
    """Each frame's evidence: the mean over its code's cells above ``thr`` of ``evidence - z_weight * z`` (a frame
    none of whose cells is above: absent). Returns the entries written."""
    code_ptr, code_r, norm = codes
    z, e_new, cand = scratch[4], scratch[5], scratch[6]
    z_weight = params[P_ZW]
    n_out = 0
    for j in range(n_frames):
        s = 0.0
        hit = False
        for k in range(code_ptr[j], code_ptr[j + 1]):
            r = code_r[k]
            if r < n_r and cand[r] and e_new[r] > thr:
                s += (e_new[r] - z_weight * z[r]) / norm[j]
                hit = True
        if hit:
            out_idx[n_out] = j
            out_val[n_out] = s
            n_out += 1
    return n_out


@njit(cache=True, nogil=True)
def stream_step(bits, counted, n_r, n_frames, n_blocks, ff, cells, blocks, codes, params, e_beam, scratch,
                out_idx, out_val):  # pragma: no cover - compiled
    """One frame's evidence over the cells ``0 .. n_r - 1`` and the frames ``0 .. n_frames - 1`` learned so far, in
    phases: :func:`feed_forward`, :func:`predict`, :func:`new_beam`, :func:`output`.

    Parameters
    ----------
    bits : the frame's active input bits.
    counted : -1, or the minicolumns touched by the frame's overlap count already in ``scratch``'s counts and
        touched (only without ``max_enter``: the count then need not hold the minicolumns the frame created).
    ff : (bit_cols, bit_len, col_size): input bit -> minicolumns, connections per minicolumn.
    cells : (r_col,): each cell's minicolumn.
    blocks : (s_ptr, s_r, d_ptr, d_r, p_ptr, p_s, p_d): per block its sources, its targets and, where not every
        source connects to every target, its pairs.
    codes : (code_ptr, code_r, norm): each frame's winner cells and their count.
    params : float64 (decay, stay, skip, z_weight, floor, rel_floor, z_floor, max_beam, max_enter), as the beam's
        (caps <= 0: none).
    e_beam : float64 per cell, carried between frames: the evidence of the cells in the beam, 0 elsewhere.
    scratch : (counts int32 per minicolumn, touched int32 per minicolumn, p1, p2, z, e_new float64 per cell, cand uint8
        per cell).
    out_idx, out_val : room for ``n_frames`` entries: the frames with evidence and their mean evidence.

    Returns the number of output entries.
    """
    feed_forward(bits, counted, n_r, ff, cells, params, e_beam, scratch)
    predict(n_r, n_blocks, blocks, params, e_beam, scratch)
    thr = new_beam(n_r, params, e_beam, scratch)
    return output(n_r, n_frames, thr, codes, params, scratch, out_idx, out_val)


@njit(cache=True)
def add_block(s_ptr, s_r, d_ptr, d_r, p_ptr, p_s, p_d, b, src, dst):
    """Block ``b``: the connections ``src[i] -> dst[i]`` (cell numbers), as every source to every target where they
    are, else as pairs. The arrays must have room (the caller grows them)."""
    # the distinct sources and targets, in order met
    ns = 0
    nd = 0
    s0, d0 = s_ptr[b], d_ptr[b]
    for i in range(src.shape[0]):
        seen = False
        for k in range(s0, s0 + ns):
            if s_r[k] == src[i]:
                seen = True
                break
        if not seen:
            s_r[s0 + ns] = src[i]
            ns += 1
        seen = False
        for k in range(d0, d0 + nd):
            if d_r[k] == dst[i]:
                seen = True
                break
        if not seen:
            d_r[d0 + nd] = dst[i]
            nd += 1
    s_ptr[b + 1] = s0 + ns
    d_ptr[b + 1] = d0 + nd
    p0 = p_ptr[b]
    if ns * nd == src.shape[0]:  # distinct pairs, as many as sources x targets: every source predicts every target
        p_ptr[b + 1] = p0
        return
    for i in range(src.shape[0]):
        p_s[p0 + i] = src[i]
        p_d[p0 + i] = dst[i]
    p_ptr[b + 1] = p0 + src.shape[0]
