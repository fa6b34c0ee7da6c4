"""Compiled inner loop of :class:`vpr.shosm.SequenceMemory` (numba)."""
from __future__ import annotations

import numpy as np
from numba import njit

from .overlap import count_overlaps

# indices into the int64 state vector
N_COLS, N_ENTRIES, N_EDGES, N_PRED, N_PREV, TAPE_POS, TAPE_LEN, OUT_POS, NEED_KIND, NEED_SIZE, N_ACTIVE, N_KEYS = \
    range(12)
# work counters (list nodes visited), machine-independent cost figures for the benchmark
W_MATCH, W_PRED, W_BURST, W_LEARN = range(12, 16)
# KEEP_COUNTS 1: a step leaves its overlap counts for the caller (who resets them), N_TOUCHED minicolumns touched
KEEP_COUNTS, N_TOUCHED = 16, 17
STATE_SIZE = 18

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


@njit(cache=True, inline="always")
def query_tie_key(cell):
    """A fixed pseudo-random number in [0, 1) for ``cell`` (splitmix64).

    Breaks ties between bursting cells when learning is off, so that a query reads no random numbers and leaves the
    memory exactly as it found it.
    """
    z = np.uint64(cell) + np.uint64(0x9E3779B97F4A7C15)
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    z = z ^ (z >> np.uint64(31))
    return np.float64(z >> np.uint64(11)) * (1.0 / 9007199254740992.0)


# The phases are inlined into run_frames (inline="always"): calls between them cost measurably in bench_memory's
# random walk. The phases below share the memory's arrays in four groups (tuples, unpacked by name):
#   ff      feed-forward: (bit_cols, bit_len, col_thr), the inverted index input bit -> minicolumns lat     lateral:
#   (out_head, outdeg, e_src, e_dst, e_onext, col_cell, edge_set) cells   per-cell flags and lists: (is_pred, is_next,
#   pred_list, next_list, prev, cur) scratch per-step work space: (counts, touched, active, keys)
# and the parameters ``params = (cpc, new_columns, k_active, connectivity, threshold, p_extra)``.


@njit(cache=True, inline="always")
def match_columns(bits, learn, k_active, st, ff, scratch):
    """Alg. 1 line 1, M_active = match(I, M): overlaps through the inverted index; return n_active.

    With learning off and no minicolumn at its threshold, our extension takes the ``k_active`` minicolumns with the
    highest non-zero overlap.
    """
    bit_cols, bit_len, col_thr = ff
    counts, touched, active, _ = scratch
    for i in range(bits.shape[0]):
        st[W_MATCH] += bit_len[bits[i]]
    n_touch = count_overlaps(bits, bit_cols, bit_len, counts, touched)
    n_act = 0
    for i in range(n_touch):
        c = touched[i]
        if counts[c] >= col_thr[c]:
            active[n_act] = c
            n_act += 1
    if n_act == 0 and not learn and k_active > 0 and n_touch > 0:
        for _ in range(min(k_active, n_touch)):
            best = -1
            for i in range(n_touch):
                c = touched[i]
                if counts[c] > 0 and (best < 0 or counts[c] > counts[best]
                                      or (counts[c] == counts[best] and c < best)):
                    best = c
            active[n_act] = best
            n_act += 1
            counts[best] = -counts[best]  # taken (all counts are reset below)
    st[N_TOUCHED] = n_touch
    if st[KEEP_COUNTS] == 0:
        for i in range(n_touch):
            counts[touched[i]] = 0
    return n_act


@njit(cache=True, inline="always")
def lacks_space(bits, create, n_act, learn, params, st, ff, lat, tape, out_idx):
    """True (and ``st[NEED_*]`` set) if an array is too small for this step; checked before it mutates anything."""
    cpc, new_columns, _, _, _, p_extra = params
    bit_cols, bit_len, col_thr = ff
    _, _, e_src, _, _, col_cell, edge_set = lat
    nb = bits.shape[0]
    max_win = (new_columns if create else n_act) * cpc
    n_prev = st[N_PREV]
    if learn:
        need_tape = max_win + (new_columns * nb if create else 0) + n_prev * max_win
    else:
        need_tape = 0  # queries draw no random numbers
    new_edges = n_prev * max_win if learn else 0
    need, size = DONE, 0
    if create and st[N_COLS] + new_columns > col_thr.shape[0]:
        need, size = NEED_COLS, st[N_COLS] + new_columns
    elif create and _longest_row(bits, bit_len) + new_columns > bit_cols.shape[1]:
        need, size = NEED_ENTRIES, _longest_row(bits, bit_len) + new_columns
    elif learn and st[N_EDGES] + new_edges > e_src.shape[0]:
        need, size = NEED_EDGES, st[N_EDGES] + new_edges
    elif learn and 2 * (st[N_KEYS] + new_edges) > col_cell.shape[0]:
        # keep the (minicolumn, cell) set at most half full
        need, size = NEED_HASH, 2 * (st[N_KEYS] + new_edges)
    elif learn and p_extra > 0.0 and 2 * (st[N_EDGES] + new_edges) > edge_set.shape[0]:
        need, size = NEED_EDGE_HASH, 2 * (st[N_EDGES] + new_edges)
    elif st[TAPE_POS] + need_tape > st[TAPE_LEN]:
        need, size = NEED_TAPE, need_tape
    elif st[OUT_POS] + max_win > out_idx.shape[0]:
        need, size = NEED_OUT, st[OUT_POS] + max_win
    st[NEED_KIND] = need
    st[NEED_SIZE] = size
    return need != DONE


@njit(cache=True, inline="always")
def _longest_row(bits, bit_len):
    longest = 0
    for i in range(bits.shape[0]):
        longest = max(longest, bit_len[bits[i]])
    return longest


@njit(cache=True, inline="always")
def create_columns(bits, params, st, ff, scratch, tape, tp):
    """Alg. 1 lines 2-4: ``new_columns`` minicolumns, each on a random ``connectivity`` of the 1-bits.

    They become the active minicolumns; return the tape position after the draws.
    """
    _, new_columns, _, connectivity, threshold, _ = params
    bit_cols, bit_len, col_thr = ff
    _, _, active, keys = scratch
    nb = bits.shape[0]
    n_conn = max(1, int(np.round(connectivity * nb)))
    thr = int(np.ceil(threshold * n_conn - 1e-9))
    n_cols = st[N_COLS]
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
    st[N_COLS] = n_cols + new_columns
    return tp


@njit(cache=True, inline="always")
def _predict_from(cell, w_slot, st, lat, cells, n_next):
    """Mark the targets of ``cell``'s lateral connections as predicted next; return the new n_next."""
    out_head, _, _, e_dst, e_onext, _, _ = lat
    _, is_next, _, next_list, _, _ = cells
    e = out_head[cell]
    while e >= 0:
        st[w_slot] += 1
        t = e_dst[e]
        if not is_next[t]:
            is_next[t] = True
            next_list[n_next] = t
            n_next += 1
        e = e_onext[e]
    return n_next


@njit(cache=True, inline="always")
def activate_cells(act, learn, cpc, st, lat, cells, tape, tp):
    """Alg. 1 lines 5-11 for the sorted active minicolumns ``act``; return (n_winners, n_predicted_next, tp).

    Predicted cells of an active minicolumn win and predict their targets (lines 6-8); a minicolumn without one bursts
    (lines 9-11): all its cells predict and the winner is the cell with the fewest outgoing connections, ties broken
    by the tape (learning) or :func:`query_tie_key` (learning off).
    """
    _, outdeg, _, _, _, _, _ = lat
    is_pred, _, _, _, _, cur = cells
    n_cur = 0
    n_next = 0
    for j in range(act.shape[0]):
        base = act[j] * cpc
        n_p = 0
        for i in range(cpc):
            if is_pred[base + i]:
                n_p += 1
        if n_p > 0:
            for i in range(cpc):
                cell = base + i
                if is_pred[cell]:
                    cur[n_cur] = cell
                    n_cur += 1
                    n_next = _predict_from(cell, W_PRED, st, lat, cells, n_next)
        else:
            best = -1
            best_key = 0.0
            for i in range(cpc):
                cell = base + i
                u = tape[tp + i] if learn else query_tie_key(cell)
                key = outdeg[cell] + 0.5 * u
                if best < 0 or key < best_key:
                    best = cell
                    best_key = key
                n_next = _predict_from(cell, W_BURST, st, lat, cells, n_next)
            if learn:
                tp += cpc
            cur[n_cur] = best
            n_cur += 1
    return n_cur, n_next, tp


@njit(cache=True, inline="always")
def learn_lateral(n_cur, cpc, p_extra, st, lat, cells, tape, tp):
    """Alg. 1 lines 12-13: connect every previous winner to every winner; return the tape position.

    A connection is made unless a cell of the source's minicolumn already connects to the target; rSHOSM (section 4.3)
    bypasses that with probability ``p_extra``, unless this very cell already connects.
    """
    out_head, outdeg, e_src, e_dst, e_onext, col_cell, edge_set = lat
    _, _, _, _, prev, cur = cells
    ne = st[N_EDGES]
    for a in range(st[N_PREV]):
        s = prev[a]
        col_s = s // cpc
        for w in range(n_cur):
            d = cur[w]
            ckey = col_s << 32 | d
            has_col = hash_contains(col_cell, ckey)
            make = not has_col
            if has_col and p_extra > 0.0:
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
    return tp


@njit(cache=True, inline="always")
def forget_context(st, cells):
    """No active minicolumn and nothing learned: the sequence context is broken."""
    is_pred, _, pred_list, _, _, _ = cells
    for i in range(st[N_PRED]):
        is_pred[pred_list[i]] = False
    st[N_PRED] = 0
    st[N_PREV] = 0
    st[N_ACTIVE] = 0


@njit(cache=True, inline="always")
def commit_step(n_cur, n_next, n_act, st, cells, out_idx):
    """The predictions become the current ones, the winners the previous ones and the step's output."""
    is_pred, is_next, pred_list, next_list, prev, cur = cells
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


@njit(cache=True, nogil=True)  # another thread may score the stream meanwhile (vpr.shosm.LoopStream)
def run_frames(frames, f_start, f_stop, learn, params, st, ff, lat, cells, scratch, tape, out):
    """Run Algorithm 1 on frames ``f_start..f_stop-1``; return the first frame not processed.

    ``frames = (indptr, indices)`` of the input batch, ``out = (out_idx, out_ptr)`` the winners; the other groups are
    described above. A frame for which an array is too small is not started (see ``st[NEED_KIND]``).
    """
    ind_ptr, ind = frames
    out_idx, out_ptr = out
    cpc, new_columns, k_active, _, _, p_extra = params
    active = scratch[2]
    f = f_start
    while f < f_stop:
        bits = ind[ind_ptr[f]:ind_ptr[f + 1]]
        n_act = match_columns(bits, learn, k_active, st, ff, scratch)
        create = n_act == 0 and learn and bits.shape[0] > 0
        if lacks_space(bits, create, n_act, learn, params, st, ff, lat, tape, out_idx):
            if st[KEEP_COUNTS]:  # the frame is run again once there is room: its counts start from 0
                counts, touched = scratch[0], scratch[1]
                for i in range(st[N_TOUCHED]):
                    counts[touched[i]] = 0
            return f
        tp = st[TAPE_POS]
        if create:
            tp = create_columns(bits, params, st, ff, scratch, tape, tp)
            n_act = new_columns
        if n_act == 0:
            forget_context(st, cells)
        else:
            act = np.sort(active[:n_act])
            active[:n_act] = act
            n_cur, n_next, tp = activate_cells(act, learn, cpc, st, lat, cells, tape, tp)
            if learn:
                tp = learn_lateral(n_cur, cpc, p_extra, st, lat, cells, tape, tp)
            commit_step(n_cur, n_next, n_act, st, cells, out_idx)
        st[TAPE_POS] = tp
        out_ptr[f + 1] = st[OUT_POS]
        f += 1
    st[NEED_KIND] = DONE
    return f
