"""A table cell of a run's decisions, as the studies print them."""
from __future__ import annotations


def decisions_cell(m: dict, digits: int = 3, frames: bool = True) -> str:
    """``frames, accepted, P(acc), R(acc)`` of one method's ``metrics.json`` entry (``-``: nothing accepted, or no
    true match to recall)."""
    p = m["precision_accepted"]
    cells = [m["frames"]] if frames else []
    r = m["recall_accepted"]
    cells += [m["n_accepted"], "-" if p is None else f"{p:.{digits}f}", "-" if r is None else f"{r:.2f}"]
    return ", ".join(str(c) for c in cells)
