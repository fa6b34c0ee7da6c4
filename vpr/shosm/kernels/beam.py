"""Compiled kernels of the sparse graded evidence (numba): the beam, and lists that grow online.

* :func:`beam_frames`: per frame only the cells whose evidence is above a floor
  (the "beam") are carried; a cell enters through the inverted index input bit
  -> minicolumns (feed-forward) or through a learned connection from a beam
  cell (prediction). Evidence is never negative here: a cell outside the beam
  has evidence 0, which is what makes the beam exact when its floors are 0
  (tests compare it with ``evidence_frames(clamp=True)``). Output per frame is
  the sparse column of database frames that a beam cell belongs to.
* :func:`append_lists`, :func:`count_new_entries`: follow a memory that learns
  while it is read (loop closure in one stream).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from .overlap import count_overlaps

# indices into the int64 state vector of beam_frames; the last two are counters (largest beam and
# candidate set of any frame so far) that tests and benchmarks read to check the caps
B_SIZE, B_OUT_POS, B_NEED, B_FRAMES, B_MAX_BEAM, B_MAX_CAND = range(6)
BEAM_STATE_SIZE = 6


@njit(cache=True, inline="always")
def _relax(s, v, a_head, a_dst, a_next, birth, limit, p, mark, cand, n_c):  # pragma: no cover - compiled
    """Offer evidence ``v`` of cell ``s`` along its connections: ``p[d] = max(p[d], v)`` for every
    target ``d`` learned by ``limit``; new targets join the candidates. Returns the candidate count."""
    e = a_head[s]
    while e >= 0:
        d = a_dst[e]
        if birth[d] <= limit:
            if v > p[d]:
                p[d] = v
            if not mark[d]:
                mark[d] = True
                cand[n_c] = d
                n_c += 1
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
def _relax_groups(n_g, gtouch, gmax, gmark, a_head, a_dst, a_next, birth, limit, p, mark, cand,
                  n_c):  # pragma: no cover - compiled
    """Relax each touched group's largest offer along the group's one successor list."""
    for k in range(n_g):
        gi = gtouch[k]
        gmark[gi] = False
        n_c = _relax(gi, gmax[gi], a_head, a_dst, a_next, birth, limit, p, mark, cand, n_c)
    return n_c


@njit(cache=True, nogil=True)  # the forward and backward passes run on two threads at once
def beam_frames(q_ptr, q_ind, order, limits, bit_cols, bit_len, col_size, cpc,
                a_head, a_next, a_dst, grp, c_head, c_next, c_frame, relevant, birth, db_norm,
                decay, stay, skip, z_weight, floor, rel_floor, z_floor, max_beam, max_enter,
                st, beam, beam_e, e_cur, counts, touched_cols, p1, p2, z, mark, cand, e_new,
                gmax, gmark, gtouch, acc, db_mark, db_touch, out_ptr, out_idx, out_val):
    """Sparse graded evidence for the query frames ``order`` (one direction).

    Parameters (all arrays owned by the caller; cells are the memory's cell indices)
    ----------
    q_ptr, q_ind : CSR of the query SDR batch; ``order``: frames to run, in order.
    limits : int64 per frame of ``order``: only cells born at a database frame
        ``<= limit`` take part and only database frames ``<= limit`` are output
        (loop closure over the past; a large value for database matching).
    bit_cols, bit_len : the memory's inverted index input bit -> minicolumns.
    col_size : feed-forward connections per minicolumn (float64).
    a_head, a_next, a_dst : the lateral connections used for prediction, as
        linked lists per source cell (reversed connections for a backward pass),
        or per group of source cells with the same targets (``grp``).
    grp : int64 per cell, its group (-1: no connection), or empty: the lists are per
        cell. A frame's winner cells all predict the next frame's, so the cells that
        relay evidence come in groups with one successor list; a group relaxes the
        largest evidence of its beam cells once (the same maxima as cell by cell).
    c_head, c_next, c_frame : cell -> database frames whose code holds the cell.
    relevant : bool per cell, may carry evidence; birth : first database frame of a cell.
    db_norm : code size per database frame (the mean over its cells).
    decay, stay, skip, z_weight : as :func:`evidence_frames` (stay/skip < 0: off).
    floor, rel_floor : a cell stays in the beam when its evidence is above
        ``max(floor, rel_floor * (largest evidence this frame))``.
    z_floor : a minicolumn's cells enter by feed-forward alone when its overlap fraction is
        above it (a cell that enters by prediction gets its feed-forward term whatever it is).
    max_beam : at most this many cells are carried to the next frame (those of largest
        evidence: above the ``max_beam + 1``-th largest; ties at it drop out together);
        every cell above the floors still counts in this frame's column; <= 0: no cap.
    max_enter : at most this many minicolumns enter by feed-forward per frame (those of
        largest overlap, the same way); <= 0: no cap. Together the two caps bound the
        candidates per frame by ``max_enter * cpc + max_beam * (out-degree)`` whatever
        the SDRs share.
    st : int64 state: beam size, output position, need-flag, frames done, largest beam
        and largest candidate set so far.
    gmax, gmark, gtouch : scratch per group (unused without groups).
    beam, beam_e : the beam (cells, evidence), carried from call to call.
    out_ptr, out_idx, out_val : per processed frame the sparse column
        (database frame, evidence); ``out_ptr[t + 1]`` ends frame ``order[t]``.

    Returns the number of frames of ``order`` processed; fewer than all when
    ``out_idx`` is too small for the next frame (``st[B_NEED]`` = size needed),
    the caller grows it and calls again from there.
    """
    n = order.shape[0]
    for t in range(st[B_FRAMES], n):
        q = order[t]
        limit = limits[t]
        # ---- feed-forward: overlap of every touched minicolumn via the inverted index
        n_tc = count_overlaps(q_ind[q_ptr[q]:q_ptr[q + 1]], bit_cols, bit_len, counts, touched_cols)
        # counts become overlap fractions; they stay until the end of the frame so that every
        # candidate (also one that enters by prediction) gets its feed-forward term
        n_above = 0
        for i in range(n_tc):
            col = touched_cols[i]
            zz = counts[col] / col_size[col] if col_size[col] > 0 else 0.0
            counts[col] = zz
            if zz > z_floor:
                n_above += 1
        zf = z_floor
        if max_enter > 0 and n_above > max_enter:
            # SDRs that share many bits between places pass the floor in very many minicolumns:
            # only the max_enter of largest overlap enter (partial selection, O(touched))
            vals = np.empty(n_above, np.float64)
            m = 0
            for i in range(n_tc):
                zz = counts[touched_cols[i]]
                if zz > z_floor:
                    vals[m] = zz
                    m += 1
            zf = max(zf, np.partition(vals, n_above - max_enter - 1)[n_above - max_enter - 1])
        n_c = 0
        for i in range(n_tc):
            col = touched_cols[i]
            zz = counts[col]
            if zz > zf:
                for k in range(cpc):
                    c = col * cpc + k
                    if relevant[c] and birth[c] <= limit:
                        if not mark[c]:
                            mark[c] = True
                            cand[n_c] = c
                            n_c += 1
        # ---- prediction: one connection from a beam cell (and the beam cell itself: stay)
        grouped = grp.shape[0] > 0
        nb = st[B_SIZE]
        n_g = 0
        for i in range(nb):
            s = beam[i]
            v = beam_e[i]
            if birth[s] > limit:
                continue
            if stay >= 0.0 and v > stay and not mark[s]:
                mark[s] = True
                cand[n_c] = s
                n_c += 1
            if grouped:
                n_g = _offer(s, v, grp, gmax, gmark, gtouch, n_g)
            else:
                n_c = _relax(s, v, a_head, a_dst, a_next, birth, limit, p1, mark, cand, n_c)
        if grouped:
            n_c = _relax_groups(n_g, gtouch, gmax, gmark, a_head, a_dst, a_next, birth, limit, p1, mark, cand, n_c)
        # ---- two connections (a skipped database frame); only p1 > skip can win
        if skip >= 0.0:
            n1 = n_c
            n_g = 0
            for i in range(n1):
                s = cand[i]
                v = p1[s]
                if v > skip:
                    if grouped:
                        n_g = _offer(s, v, grp, gmax, gmark, gtouch, n_g)
                    else:
                        n_c = _relax(s, v, a_head, a_dst, a_next, birth, limit, p2, mark, cand, n_c)
            if grouped:
                n_c = _relax_groups(n_g, gtouch, gmax, gmark, a_head, a_dst, a_next, birth, limit, p2, mark, cand,
                                    n_c)
        # ---- new evidence of the candidates
        emax = 0.0
        for i in range(n_c):
            c = cand[i]
            z[c] = counts[c // cpc]
            p = p1[c]
            if skip >= 0.0 and p2[c] - skip > p:
                p = p2[c] - skip
            if stay >= 0.0 and e_cur[c] - stay > p:
                p = e_cur[c] - stay
            if p < 0.0:
                p = 0.0
            en = z[c] + decay * p
            e_new[i] = en
            if en > emax:
                emax = en
        thr = max(floor, rel_floor * emax)
        if n_c > st[B_MAX_CAND]:
            st[B_MAX_CAND] = n_c
        # ---- capacity of the output for this frame (cells x their database frames)
        need = st[B_OUT_POS]
        for i in range(n_c):
            if e_new[i] > thr:
                node = c_head[cand[i]]
                while node >= 0:
                    need += 1
                    node = c_next[node]
        if need > out_idx.shape[0]:
            for i in range(n_c):
                c = cand[i]
                mark[c] = False
                p1[c] = 0.0
                p2[c] = 0.0
                z[c] = 0.0
            for i in range(n_tc):
                counts[touched_cols[i]] = 0.0
            st[B_NEED] = need
            st[B_FRAMES] = t
            return t
        keep = thr
        if max_beam > 0 and n_c > max_beam:
            n_above = 0
            for i in range(n_c):
                if e_new[i] > thr:
                    n_above += 1
            if n_above > max_beam:
                # only the max_beam cells of largest evidence are carried to the next frame; all
                # above the floor still go to this frame's column, so the z-score's sums hold
                # every cell that has evidence this frame, as without the cap
                vals = np.empty(n_above, np.float64)
                m = 0
                for i in range(n_c):
                    if e_new[i] > thr:
                        vals[m] = e_new[i]
                        m += 1
                keep = max(thr, np.partition(vals, n_above - max_beam - 1)[n_above - max_beam - 1])
        # ---- new beam and the output column
        for i in range(nb):
            e_cur[beam[i]] = 0.0
        nb2 = 0
        n_touch = 0
        for i in range(n_c):
            c = cand[i]
            zc = z[c]
            mark[c] = False
            p1[c] = 0.0
            p2[c] = 0.0
            z[c] = 0.0
            en = e_new[i]
            if en > thr:
                if en > keep:
                    beam[nb2] = c
                    beam_e[nb2] = en
                    e_cur[c] = en
                    nb2 += 1
                node = c_head[c]
                while node >= 0:
                    j = c_frame[node]
                    if j <= limit:
                        if not db_mark[j]:
                            db_mark[j] = True
                            db_touch[n_touch] = j
                            n_touch += 1
                        acc[j] += (en - z_weight * zc) / db_norm[j]
                    node = c_next[node]
        st[B_SIZE] = nb2
        if nb2 > st[B_MAX_BEAM]:
            st[B_MAX_BEAM] = nb2
        for i in range(n_tc):
            counts[touched_cols[i]] = 0.0
        pos = st[B_OUT_POS]
        for i in range(n_touch):
            j = db_touch[i]
            out_idx[pos] = j
            out_val[pos] = acc[j]
            pos += 1
            acc[j] = 0.0
            db_mark[j] = False
        st[B_OUT_POS] = pos
        out_ptr[t + 1] = pos
    st[B_FRAMES] = n
    st[B_NEED] = 0
    return n


@njit(cache=True)
def append_lists(head, nxt, val, base, keys, vals):
    """Append entries ``keys[i] -> vals[i]`` at positions ``base + i`` of linked lists (newest first)."""
    for i in range(keys.shape[0]):
        e = base + i
        k = keys[i]
        nxt[e] = head[k]
        head[k] = e
        val[e] = vals[i]


@njit(cache=True)
def count_new_entries(col_size, bits, old_len, bit_len, bit_cols):
    """Add the feed-forward connections made since ``old_len`` (new minicolumns) to ``col_size``."""
    for i in range(bits.shape[0]):
        b = bits[i]
        for j in range(old_len[b], bit_len[b]):
            col_size[bit_cols[b, j]] += 1.0
