"""Study: several feed-forward segments per minicolumn, taught by the sequence prediction (a prototype).

Negative result (``research/docs/experiments.md``, "Feed-forward segments taught by the
prediction"); run on Nordland by ``python -m research.studies.nordland_variants``.

The paper (section 4.2, item 5) suggests, without implementing it, that a
minicolumn could own several feed-forward segments, one per appearance of a
place, so that the context learned for a place (its lateral connections) is
shared by all its appearances. :class:`SegmentedMemory` is Algorithm 1 written
out as literally as :class:`tests.reference.ReferenceMemory` (the test oracle) (same random draws
in the same order), except that

* a minicolumn owns a list of feed-forward segments (sets of input bits, each
  with its own threshold) and is active when *any* segment reaches its
  threshold;
* a query traverse can be run with the **prediction as teacher**
  (``teach=True``): lateral connections are not learned, but when fewer than
  ``teach_below`` minicolumns reach the threshold while the previous step
  predicted cells, every predicted minicolumn that the input did not activate
  gets a new segment sampled from the current input (as a new minicolumn
  would, Alg. 1 line 3) and is treated as active, so its predicted cells win
  and the sequence continues. ``max_segments`` caps the segments of a
  minicolumn (the database segment included). With ``confirmed_only`` only
  cells predicted by *predicted* winners (a sequence step the input
  confirmed) teach, not the many cells a bursting minicolumn predicts.

With the teacher off and one segment per minicolumn the class is Algorithm 1:
the tests check that its winner cells are those of ``ReferenceMemory``.
Pure Python and slow (the study runs it on Nordland's 358-frame subset only);
``research/docs/experiments.md`` ("Feed-forward segments taught by the prediction")
reports what it does on Nordland summer vs winter.
"""
from __future__ import annotations

from collections import defaultdict

import numpy as np
import scipy.sparse as sp

from tests.reference import activate_cells, learn_lateral

__all__ = ["SegmentedMemory", "segment_codes", "teach_from_labels", "teacher_precision"]


class SegmentedMemory:
    """Algorithm 1 (rSHOSM) with a list of feed-forward segments per minicolumn.

    Parameters
    ----------
    n_inputs, cells_per_column, new_columns, connectivity, threshold, p_extra, k_active, seed
        As in :class:`vpr.shosm.SequenceMemory` (paper defaults; ``k_active``
        is our fallback for a query frame that activates no minicolumn).
    teach_below : int
        With ``teach=True``: teach when fewer than this many minicolumns reach
        the threshold (1: only when none does). 0 switches the teacher off.
    max_segments : int or None
        At most this many segments per minicolumn (the database one included);
        a predicted minicolumn at the cap is not taught and not activated.
        None: no cap.
    confirmed_only : bool
        Teach only minicolumns predicted by predicted winner cells, not by bursting ones.

    Attributes
    ----------
    taught_log : list of (int, list of int)
        (query step, minicolumns taught) of every teaching event since creation;
        the step counts :meth:`step` calls with ``teach=True``.
    """

    def __init__(self, n_inputs=2048, cells_per_column=32, new_columns=10, connectivity=0.5, threshold=0.25,
                 p_extra=0.05, k_active=10, teach_below=0, max_segments=None, confirmed_only=False, seed=0):
        if max_segments is not None and int(max_segments) < 1:
            raise ValueError(f"max_segments must be >= 1 or None, got {max_segments}")
        if int(teach_below) < 0:
            raise ValueError(f"teach_below must be >= 0, got {teach_below}")
        self.n_inputs, self.cpc, self.new_columns = n_inputs, cells_per_column, new_columns
        self.connectivity, self.threshold, self.p_extra, self.k_active = connectivity, threshold, p_extra, k_active
        self.teach_below, self.max_segments = int(teach_below), max_segments
        self.confirmed_only = bool(confirmed_only)
        self.rng = np.random.default_rng(seed)
        self.segments: list[list[tuple[set[int], int]]] = []   # per minicolumn: (input bits, threshold)
        self.forward = defaultdict(set)          # cell -> cells it predicts
        self.backward = defaultdict(set)         # cell -> cells that predict it
        self.predicted: set[int] = set()
        self.confirmed: set[int] = set()         # cells predicted by predicted (non-bursting) winners
        self.prev_winners: list[int] = []
        self.taught_log: list[tuple[int, list[int]]] = []
        self._teach_steps = 0

    @property
    def n_columns(self) -> int:
        """Number of minicolumns."""
        return len(self.segments)

    def reset(self):
        """Forget the sequence context (predictions and previous winners), keep what was learned."""
        self.predicted, self.confirmed, self.prev_winners = set(), set(), []

    # ------------------------------------------------------------ feed-forward
    def sample_segment(self, bits: list[int]) -> tuple[set[int], int]:
        """A segment on ``connectivity`` of the 1-bits, drawn exactly as ReferenceMemory draws a minicolumn."""
        n_conn = max(1, int(np.round(self.connectivity * len(bits))))
        thr = int(np.ceil(self.threshold * n_conn - 1e-9))
        keys = [self.rng.random() for _ in bits]
        order = sorted(range(len(bits)), key=lambda i: (keys[i], i))
        return {bits[i] for i in order[:n_conn]}, thr

    def _overlaps(self, bitset: set[int]) -> tuple[list[int], list[int]]:
        """Active minicolumns (any segment at its threshold) and each minicolumn's best segment overlap."""
        best, active = [], []
        for m, segs in enumerate(self.segments):
            counts = [(len(s & bitset), thr) for s, thr in segs]
            best.append(max(c for c, _ in counts))
            if any(c >= thr for c, thr in counts):
                active.append(m)
        return active, best

    def _fallback(self, best: list[int]) -> list[int]:
        """Our k_active extension (learning off): the minicolumns with the highest non-zero overlap."""
        cand = sorted((-o, m) for m, o in enumerate(best) if o > 0)
        return [m for _, m in cand[: self.k_active]]

    def _create_columns(self, bits: list[int]) -> list[int]:
        """Alg. 1 lines 2-4: ``new_columns`` minicolumns, one segment each."""
        new = []
        for _ in range(self.new_columns):
            self.segments.append([self.sample_segment(bits)])
            new.append(len(self.segments) - 1)
        return new

    def _teach(self, bits: list[int], active: list[int]) -> list[int]:
        """Give every predicted, inactive minicolumn below the cap a segment of ``bits``; return them."""
        teachers = self.confirmed if self.confirmed_only else self.predicted
        predicted_cols = sorted({c // self.cpc for c in teachers} - set(active))
        cap = self.max_segments
        taught = [m for m in predicted_cols if cap is None or len(self.segments[m]) < cap]
        for m in taught:
            self.segments[m].append(self.sample_segment(bits))
        if taught:
            self.taught_log.append((self._teach_steps, taught))
        return taught

    # ----------------------------------------------------------------- lateral
    def _winners(self, active: list[int], learn: bool) -> tuple[list[int], set[int], set[int]]:
        """Alg. 1 lines 5-11 (the oracle's): winner cells, cells predicted for the next step, and those
        of them predicted by predicted winners (the ``confirmed`` ones)."""
        return activate_cells(active, self.predicted, self.forward, self.cpc, self.rng, learn)

    def _learn_lateral(self, winners: list[int]) -> None:
        """Alg. 1 lines 12-13 with rSHOSM's random extra connections (as ReferenceMemory)."""
        learn_lateral(self.forward, self.backward, self.prev_winners, winners, self.cpc, self.p_extra, self.rng)

    # -------------------------------------------------------------------- step
    def step(self, bits, learn: bool = True, teach: bool = False) -> list[int]:
        """One step of Algorithm 1; return the winner cells.

        ``learn``: create minicolumns and lateral connections (the database
        traverse). ``teach`` (only with ``learn=False``): the prediction may
        add feed-forward segments, see the class docstring.
        """
        if learn and teach:
            raise ValueError("teach is a query mode: use learn=False with teach=True")
        bits = sorted(int(b) for b in bits)
        active, best = self._overlaps(set(bits))
        if teach:
            if self.teach_below and len(active) < self.teach_below and self.predicted:
                active = active + self._teach(bits, active)
            self._teach_steps += 1
        if not active and not learn and self.k_active > 0:
            active = self._fallback(best)
        if not active and learn and bits:
            active = self._create_columns(bits)
        if not active:
            self.reset()
            return []
        winners, self.predicted, self.confirmed = self._winners(active, learn)
        if learn:
            self._learn_lateral(winners)
        self.prev_winners = winners
        return winners

    def run(self, sdr_batch, learn: bool = False, teach: bool = False) -> sp.csr_matrix:
        """Step through an SDR batch (frames x bits, csr); winner codes as csr bool (frames x cells)."""
        batch = sp.csr_matrix(sdr_batch)
        codes = [sorted(set(self.step(batch.indices[batch.indptr[t]:batch.indptr[t + 1]], learn, teach)))
                 for t in range(batch.shape[0])]
        ptr = np.cumsum([0] + [len(w) for w in codes])
        idx = np.asarray([c for w in codes for c in w], dtype=np.int64)
        return sp.csr_matrix((np.ones(idx.size, bool), idx, ptr),
                             shape=(batch.shape[0], max(self.n_columns * self.cpc, 1)))


def teacher_precision(mem: SegmentedMemory, db_codes: sp.csr_matrix, tolerance: int = 1) -> float:
    """Fraction of taught segments that went to a minicolumn of the right place.

    Assumes the taught traverse is frame-aligned with the database (Nordland):
    a segment taught at query step ``t`` is right when its minicolumn was active
    at a database frame ``i`` with ``|i - t| <= tolerance``. None if nothing was taught.
    """
    db_codes = sp.csr_matrix(db_codes)
    columns = [set((db_codes.indices[db_codes.indptr[i]:db_codes.indptr[i + 1]] // mem.cpc).tolist())
               for i in range(db_codes.shape[0])]
    right = total = 0
    for t, taught in mem.taught_log:
        near = set().union(*columns[max(t - tolerance, 0): t + tolerance + 1])
        right += sum(m in near for m in taught)
        total += len(taught)
    return right / total if total else None


def teach_from_labels(mem: SegmentedMemory, teach_sdr, db_codes: sp.csr_matrix) -> None:
    """Upper bound, not a method: frame ``t`` of ``teach_sdr`` teaches the minicolumns of database frame ``t``.

    Uses the ground truth (the traverses are frame-aligned), so it measures
    what a perfect teacher would give, the best the segments themselves can do.
    """
    batch, db_codes = sp.csr_matrix(teach_sdr), sp.csr_matrix(db_codes)
    for t in range(min(batch.shape[0], db_codes.shape[0])):
        bits = sorted(batch.indices[batch.indptr[t]:batch.indptr[t + 1]].tolist())
        columns = sorted(set((db_codes.indices[db_codes.indptr[t]:db_codes.indptr[t + 1]] // mem.cpc).tolist()))
        cap = mem.max_segments
        taught = [m for m in columns if cap is None or len(mem.segments[m]) < cap]
        for m in taught:
            mem.segments[m].append(mem.sample_segment(bits))
        if taught and bits:
            mem.taught_log.append((t, taught))


def segment_codes(db_sdr, q_sdr, read: str = "online", teach_sdr=None, teach_below: int = 1,
                  max_segments=None, confirmed_only: bool = False, teacher: str = "prediction",
                  seed: int = 0) -> tuple[sp.csr_matrix, sp.csr_matrix, dict]:
    """Database and query winner codes (same width) of one segment experiment, and counts.

    The database is learned as in Algorithm 1. Then, by ``read``:

    * ``"online"``: the query traverse is run once with the teacher on and its
      own winner codes are returned (each frame's code uses only that frame and
      earlier ones; no labels, but the query frames are learned from);
    * ``"after"``: a teaching pass over ``teach_sdr`` (the query itself when
      None: transductive), then the query with learning and teacher off: do
      the learned segments make the memory recognise the query's appearance?

    ``teach_below=0`` gives the paper's rSHOSM (learning off on the query).
    ``teacher="labels"`` (only with ``"after"``) replaces the prediction by
    :func:`teach_from_labels`, an upper bound that uses the ground truth.
    The counts: database minicolumns, frames on which the teacher fired,
    segments it added, and :func:`teacher_precision` (only when the taught
    traverse is the query, which is frame-aligned with the database).
    """
    if read not in ("online", "after"):
        raise ValueError(f"read must be 'online' or 'after', got {read!r}")
    if teacher not in ("prediction", "labels") or (teacher == "labels" and read != "after"):
        raise ValueError(f"teacher must be 'prediction' or, with read='after', 'labels'; got {teacher!r}")
    mem = SegmentedMemory(teach_below=teach_below, max_segments=max_segments, confirmed_only=confirmed_only,
                          seed=seed)
    db_codes = mem.run(db_sdr, learn=True)
    n_db_columns = mem.n_columns
    mem.reset()
    if read == "online":
        q_codes = mem.run(q_sdr, teach=True)
    else:
        taught = q_sdr if teach_sdr is None else teach_sdr
        if teacher == "labels":
            teach_from_labels(mem, taught, db_codes)
        else:
            mem.run(taught, teach=True)
        mem.reset()
        q_codes = mem.run(q_sdr)
    width = max(db_codes.shape[1], q_codes.shape[1])
    db_codes.resize((db_codes.shape[0], width))
    q_codes.resize((q_codes.shape[0], width))
    stats = {"columns": n_db_columns, "taught_frames": len(mem.taught_log),
             "taught_segments": sum(len(m) for _, m in mem.taught_log),
             "teacher_precision": teacher_precision(mem, db_codes) if teach_sdr is None else None}
    return db_codes, q_codes, stats
