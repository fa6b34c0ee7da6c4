"""The one compiled overlap count of rSHOSM (numba): an SDR's active bits against every minicolumn."""
from __future__ import annotations

from numba import njit


@njit(cache=True, inline="always")
def count_overlaps(bits, bit_cols, bit_len, counts, touched):  # pragma: no cover - compiled
    """Add 1 to ``counts[c]`` for every connection ``bit -> c`` of the active ``bits``; return how many minicolumns
    were touched, listed first in ``touched`` in the order met (``counts`` must be 0 where not touched; the
    caller resets the touched entries)."""
    n_touch = 0
    for i in range(bits.shape[0]):
        b = bits[i]
        for j in range(bit_len[b]):
            c = bit_cols[b, j]
            if counts[c] == 0:
                touched[n_touch] = c
                n_touch += 1
            counts[c] += 1
    return n_touch
