"""Compiled inner loop of :class:`vpr.memory.SequenceMemory` (numba).

A pure NumPy version of one Algorithm 1 step needs a few hundred small array
operations, about 400 us per observation here; the paper's target regime (many
thousands of observations) needs well under 100 us, hence this kernel
(`benchmarks/bench_memory.py` prints the figures).

All state lives in NumPy arrays owned by the Python object. Lists (input bit ->
minicolumns, cell -> outgoing and incoming connections) are singly linked lists
threaded through append-only arrays, so nothing is ever relocated and the
space one step needs is known before the step mutates anything: when an array
is too small the kernel stops *before* the step and reports which one, Python
grows it and calls again from that frame.

Randomness comes from a "tape" of uniform numbers drawn from the memory's
``numpy.random.Generator`` and consumed strictly in order, so results depend
only on the seed (and a slow reference implementation can replay them).
"""
from __future__ import annotations

import numpy as np
from numba import njit

# indices into the int64 state vector
N_COLS, N_ENTRIES, N_EDGES, N_PRED, N_PREV, TAPE_POS, TAPE_LEN, OUT_POS, NEED_KIND, NEED_SIZE, N_ACTIVE = range(11)
STATE_SIZE = 11

# what the kernel needs more of (NEED_KIND)
DONE, NEED_COLS, NEED_ENTRIES, NEED_EDGES, NEED_TAPE, NEED_OUT = range(6)


@njit(cache=True)
def run_frames(ind_ptr, ind, f_start, f_stop, learn, cpc, new_columns, k_active, connectivity, threshold,
               p_extra, st, bit_head, ent_col, ent_next, ent_bit, col_thr, counts, touched, active,
               out_head, in_head, outdeg, e_src, e_dst, e_onext, e_inext, is_pred, is_next,
               pred_list, next_list, prev, cur, tape, out_idx, out_ptr, keys):
    """Run Algorithm 1 on frames ``f_start..f_stop-1``; return the first frame not processed."""
    cols_cap = col_thr.shape[0]
    f = f_start
    while f < f_stop:
        bits = ind[ind_ptr[f]:ind_ptr[f + 1]]
        nb = bits.shape[0]
        n_cols = st[N_COLS]
        # ---- line 1: M_active = match(I, M): overlap through the inverted index
        n_touch = 0
        for i in range(nb):
            e = bit_head[bits[i]]
            while e >= 0:
                c = ent_col[e]
                if counts[c] == 0:
                    touched[n_touch] = c
                    n_touch += 1
                counts[c] += 1
                e = ent_next[e]
        n_act = 0
        for i in range(n_touch):
            c = touched[i]
            if counts[c] >= col_thr[c]:
                active[n_act] = c
                n_act += 1
        if n_act == 0 and not learn and k_active > 0 and n_touch > 0:
            # our extension: with learning off take the k best-overlapping minicolumns
            k = min(k_active, n_touch)
            for j in range(k):
                best = -1
                for i in range(n_touch):
                    c = touched[i]
                    if counts[c] > 0 and (best < 0 or counts[c] > counts[best]
                                          or (counts[c] == counts[best] and c < best)):
                        best = c
                active[n_act] = best
                n_act += 1
                counts[best] = -counts[best]  # taken (all counts are reset below)
        for i in range(n_touch):
            counts[touched[i]] = 0
        create = n_act == 0 and learn and nb > 0
        n_conn = max(1, int(np.round(connectivity * nb)))
        # ---- capacity checks: nothing below may run out of space
        n_act_b = new_columns if create else n_act
        max_win = n_act_b * cpc
        n_prev = st[N_PREV]
        need_tape = max_win + (new_columns * nb if create else 0) + (n_prev * max_win if learn else 0)
        if create and n_cols + new_columns > cols_cap:
            st[NEED_KIND] = NEED_COLS
            st[NEED_SIZE] = n_cols + new_columns
            return f
        if create and st[N_ENTRIES] + new_columns * n_conn > ent_col.shape[0]:
            st[NEED_KIND] = NEED_ENTRIES
            st[NEED_SIZE] = st[N_ENTRIES] + new_columns * n_conn
            return f
        if learn and st[N_EDGES] + n_prev * max_win > e_src.shape[0]:
            st[NEED_KIND] = NEED_EDGES
            st[NEED_SIZE] = st[N_EDGES] + n_prev * max_win
            return f
        if st[TAPE_POS] + need_tape > st[TAPE_LEN]:
            st[NEED_KIND] = NEED_TAPE
            st[NEED_SIZE] = need_tape
            return f
        if st[OUT_POS] + max_win > out_idx.shape[0]:
            st[NEED_KIND] = NEED_OUT
            st[NEED_SIZE] = st[OUT_POS] + max_win
            return f
        tp = st[TAPE_POS]
        # ---- lines 2-4: no active minicolumn -> create new ones sampling the input's 1-bits
        if create:
            thr = int(np.ceil(threshold * n_conn - 1e-9))
            for j in range(new_columns):
                c = n_cols + j
                for i in range(nb):
                    keys[i] = tape[tp + i]
                tp += nb
                order = np.argsort(keys[:nb], kind="mergesort")
                ne = st[N_ENTRIES]
                for i in range(n_conn):
                    b = bits[order[i]]
                    ent_col[ne] = c
                    ent_bit[ne] = b
                    ent_next[ne] = bit_head[b]
                    bit_head[b] = ne
                    ne += 1
                st[N_ENTRIES] = ne
                col_thr[c] = thr
                active[j] = c
            n_act = new_columns
            st[N_COLS] = n_cols + new_columns
        if n_act == 0:
            # nothing recognised and nothing learned: the sequence context is broken
            for i in range(st[N_PRED]):
                is_pred[pred_list[i]] = False
            st[N_PRED] = 0
            st[N_PREV] = 0
            st[N_ACTIVE] = 0
            st[TAPE_POS] = tp
            out_ptr[f + 1] = st[OUT_POS]
            f += 1
            continue
        act = np.sort(active[:n_act])
        active[:n_act] = act
        # ---- lines 5-11: winners and predictions for the next step
        n_cur = 0
        n_next = 0
        for j in range(n_act):
            base = act[j] * cpc
            n_p = 0
            for i in range(cpc):
                if is_pred[base + i]:
                    n_p += 1
            if n_p > 0:
                # lines 6-8: predicted cells win and predict (their targets)
                for i in range(cpc):
                    cell = base + i
                    if is_pred[cell]:
                        cur[n_cur] = cell
                        n_cur += 1
                        e = out_head[cell]
                        while e >= 0:
                            t = e_dst[e]
                            if not is_next[t]:
                                is_next[t] = True
                                next_list[n_next] = t
                                n_next += 1
                            e = e_onext[e]
            else:
                # lines 9-11: burst: every cell predicts; the winner is the cell with the
                # fewest forward connections, ties broken by the tape
                best = -1
                best_key = 0.0
                for i in range(cpc):
                    cell = base + i
                    key = outdeg[cell] + 0.5 * tape[tp + i]
                    if best < 0 or key < best_key:
                        best = cell
                        best_key = key
                    e = out_head[cell]
                    while e >= 0:
                        t = e_dst[e]
                        if not is_next[t]:
                            is_next[t] = True
                            next_list[n_next] = t
                            n_next += 1
                        e = e_onext[e]
                tp += cpc
                cur[n_cur] = best
                n_cur += 1
        # ---- lines 12-13: one-shot learning prev winner -> current winner
        if learn:
            ne = st[N_EDGES]
            for a in range(n_prev):
                s = prev[a]
                col_s = s // cpc
                for w in range(n_cur):
                    d = cur[w]
                    has_col = False
                    exact = False
                    e = in_head[d]
                    while e >= 0:
                        src = e_src[e]
                        if src // cpc == col_s:
                            has_col = True
                            if src == s:
                                exact = True
                                break
                        e = e_inext[e]
                    make = not has_col
                    if has_col and p_extra > 0.0:
                        # rSHOSM (section 4.3): bypass the restriction with probability p_extra
                        u = tape[tp]
                        tp += 1
                        make = u < p_extra and not exact
                    if make:
                        e_src[ne] = s
                        e_dst[ne] = d
                        e_onext[ne] = out_head[s]
                        out_head[s] = ne
                        e_inext[ne] = in_head[d]
                        in_head[d] = ne
                        outdeg[s] += 1
                        ne += 1
            st[N_EDGES] = ne
        # ---- commit predictions and winners
        for i in range(st[N_PRED]):
            is_pred[pred_list[i]] = False
        for i in range(n_next):
            t = next_list[i]
            is_next[t] = False
            is_pred[t] = True
            pred_list[i] = t
        st[N_PRED] = n_next
        op = st[OUT_POS]
        for w in range(n_cur):
            prev[w] = cur[w]
            out_idx[op + w] = cur[w]
        st[N_PREV] = n_cur
        st[N_ACTIVE] = n_act
        st[OUT_POS] = op + n_cur
        out_ptr[f + 1] = st[OUT_POS]
        st[TAPE_POS] = tp
        f += 1
    st[NEED_KIND] = DONE
    return f
