"""A table cell of a run's decisions, as the studies print them."""
from __future__ import annotations


def decisions_cell(m: dict, digits: int = 3, frames: bool = True) -> str:
    """``frames, accepted, P(acc), R(acc)`` of one method's ``metrics.json`` entry (``-``: nothing accepted)."""
    p = m["precision_accepted"]
    cells = [m["frames"]] if frames else []
    cells += [m["n_accepted"], "-" if p is None else f"{p:.{digits}f}", f"{m['recall_accepted']:.2f}"]
    return ", ".join(str(c) for c in cells)
