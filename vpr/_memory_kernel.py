"""Compiled inner loop of :class:`vpr.memory.SequenceMemory` (numba).

A pure NumPy version of one Algorithm 1 step needs a few hundred small array
operations, about 400 us per observation here; the paper's target regime (many
thousands of observations) needs well under 100 us, hence this kernel
(`benchmarks/bench_memory.py` prints the figures).

All state lives in NumPy arrays owned by the Python object. The inverted index
input bit -> minicolumns is a 2-D array with one contiguous row per bit (the
matching loop reads it sequentially: a linked list here was 10x slower once it
outgrew the cache); cell -> outgoing connections are singly linked lists threaded
through append-only arrays; line 13's tests use two open-addressing hash sets,
(source minicolumn, cell) and (source cell, cell). The space one step needs is known
before the step mutates anything: when an array is too small the kernel stops
*before* the step and reports which one, Python grows it and calls again from
that frame.

Randomness comes from a "tape" of uniform numbers drawn from the memory's
``numpy.random.Generator`` and consumed strictly in order, so results depend
only on the seed (and a slow reference implementation can replay them).
"""
from __future__ import annotations

import numpy as np
from numba import njit

# indices into the int64 state vector
N_COLS, N_ENTRIES, N_EDGES, N_PRED, N_PREV, TAPE_POS, TAPE_LEN, OUT_POS, NEED_KIND, NEED_SIZE, N_ACTIVE, N_KEYS = \
    range(12)
# work counters (list nodes visited), machine-independent cost figures for the benchmark
W_MATCH, W_PRED, W_BURST, W_LEARN = range(12, 16)
STATE_SIZE = 16

# what the kernel needs more of (NEED_KIND)
DONE, NEED_COLS, NEED_ENTRIES, NEED_EDGES, NEED_TAPE, NEED_OUT, NEED_HASH, NEED_EDGE_HASH = range(8)

_EMPTY = -1
_MULT = np.uint64(0x9E3779B97F4A7C15)


@njit(cache=True, inline="always")
def _slot(key, mask):
    # Fibonacci hashing; the table size is a power of two
    return np.int64((np.uint64(key) * _MULT) >> np.uint64(20)) & mask


@njit(cache=True)
def hash_insert(table, key):
    """Insert ``key`` into an open-addressing set; return True if it was new."""
    mask = table.shape[0] - 1
    i = _slot(key, mask)
    while True:
        k = table[i]
        if k == key:
            return False
        if k == _EMPTY:
            table[i] = key
            return True
        i = (i + 1) & mask


@njit(cache=True)
def hash_contains(table, key):
    mask = table.shape[0] - 1
    i = _slot(key, mask)
    while True:
        k = table[i]
        if k == key:
            return True
        if k == _EMPTY:
            return False
        i = (i + 1) & mask


@njit(cache=True)
def rebuild_sets(table, e_src, e_dst, n_edges, cpc):
    """Fill a key set from the first ``n_edges`` connections; return the number of keys.

    ``cpc`` > 0: keys are (source minicolumn, target cell); ``cpc`` == 0: (source cell, target cell).
    """
    n = 0
    for e in range(n_edges):
        src = e_src[e] // cpc if cpc > 0 else e_src[e]
        if hash_insert(table, src << 32 | e_dst[e]):
            n += 1
    return n


@njit(cache=True)
def run_frames(ind_ptr, ind, f_start, f_stop, learn, cpc, new_columns, k_active, connectivity, threshold,
               p_extra, st, bit_cols, bit_len, col_thr, counts, touched, active,
               out_head, outdeg, e_src, e_dst, e_onext, is_pred, is_next,
               pred_list, next_list, prev, cur, tape, out_idx, out_ptr, keys, col_cell, edge_set):
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
            b = bits[i]
            row = bit_cols[b]
            n_b = bit_len[b]
            st[W_MATCH] += n_b
            for j in range(n_b):
                c = row[j]
                if counts[c] == 0:
                    touched[n_touch] = c
                    n_touch += 1
                counts[c] += 1
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
        if create:
            longest = 0
            for i in range(nb):
                longest = max(longest, bit_len[bits[i]])
            if longest + new_columns > bit_cols.shape[1]:
                st[NEED_KIND] = NEED_ENTRIES
                st[NEED_SIZE] = longest + new_columns
                return f
        if learn and st[N_EDGES] + n_prev * max_win > e_src.shape[0]:
            st[NEED_KIND] = NEED_EDGES
            st[NEED_SIZE] = st[N_EDGES] + n_prev * max_win
            return f
        if learn and 2 * (st[N_KEYS] + n_prev * max_win) > col_cell.shape[0]:
            # keep the (minicolumn, cell) set at most half full
            st[NEED_KIND] = NEED_HASH
            st[NEED_SIZE] = 2 * (st[N_KEYS] + n_prev * max_win)
            return f
        if learn and p_extra > 0.0 and 2 * (st[N_EDGES] + n_prev * max_win) > edge_set.shape[0]:
            st[NEED_KIND] = NEED_EDGE_HASH
            st[NEED_SIZE] = 2 * (st[N_EDGES] + n_prev * max_win)
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
                for i in range(n_conn):
                    b = bits[order[i]]
                    bit_cols[b, bit_len[b]] = c
                    bit_len[b] += 1
                st[N_ENTRIES] += n_conn
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
                            st[W_PRED] += 1
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
                        st[W_BURST] += 1
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
                    ckey = col_s << 32 | d
                    has_col = hash_contains(col_cell, ckey)
                    make = not has_col
                    if has_col and p_extra > 0.0:
                        # rSHOSM (section 4.3): bypass the restriction with probability p_extra,
                        # unless this very cell already connects
                        u = tape[tp]
                        tp += 1
                        if u < p_extra:
                            st[W_LEARN] += 1
                            make = not hash_contains(edge_set, s << 32 | d)
                    if make:
                        if not has_col:
                            hash_insert(col_cell, ckey)
                            st[N_KEYS] += 1
                        e_src[ne] = s
                        e_dst[ne] = d
                        e_onext[ne] = out_head[s]
                        out_head[s] = ne
                        outdeg[s] += 1
                        if p_extra > 0.0:
                            hash_insert(edge_set, s << 32 | d)
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
