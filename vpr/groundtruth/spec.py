"""Where a run's ground truth comes from (the command line's options), and building it for the frames read."""
from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from vpr.similarity import fits_dense

from .files import (
    csv_columns,
    is_loop_pairs_file,
    load_loop_pairs,
    load_pairs_csv,
    load_tolerance_csv,
    load_traverse_positions,
    parse_float,
    positions_for,
    positions_for_frames,
    positions_of_frames,
    read_rows,
)
from .formats import db_query_matrix, is_matrix_file, loop_matrix, split_variable
from .matrices import gt_from_frames, gt_from_positions

__all__ = ["NAMES_RADIUS", "GroundTruthSpec", "build_gt", "build_loop_gt", "check_loop_gt_files", "warn_if_mostly_true",
           "sampling_step", "tolerance_text", "check_tolerance", "check_radius", "aligned_frames"]


#: Metres within which positions read from file names (``--gt names``: UTM as ``@east@north@``) are one place when no
#: ``--radius`` is given: the field's (VPR-methods-evaluation's and its datasets' 25 m).
NAMES_RADIUS = 25.0


@dataclass(frozen=True)
class GroundTruthSpec:
    """Where the ground truth of a database/query pair comes from (the ``vpr match`` options).

    Attributes
    ----------
    tolerance : int, optional
        Frame-aligned traverses: ``|i - j| <= tolerance`` in frames kept (:func:`sampling_step`).
    files : tuple of str
        A CSV of ``query,db`` pairs (``frame,earlier`` for loops); one or two matrix files, hard then soft
        (:mod:`vpr.groundtruth.formats`); or, with ``radius``, positions CSVs (``frame,x,y`` per traverse, or one of
        ``traverse,frame,x,y``), trajectories (:mod:`vpr.groundtruth.trajectories`), ``names`` (UTM in file names) or
        ``exif``.
    radius : float, optional
        Match radius for positions.
    soft : float, optional
        Larger radius (or tolerance) within which pairs are ignored.
    topic : str or tuple of str, optional
        Positions from this topic of each bag (or one per input), with ``radius``.
    file_unit : int, optional
        OpenSeqSLAM's ``query,db,tolerance`` CSV (``files``): the frames its tolerance counts per frame of the file
        (:func:`~vpr.groundtruth.files.load_tolerance_csv`); such a file is refused without it.
    """

    tolerance: int | None = None
    files: tuple[str, ...] = ()
    radius: float | None = None
    soft: float | None = None
    topic: str | tuple[str, ...] | None = None
    file_unit: int | None = None

    #: ``--gt`` words that name where positions are, not a file.
    KEYWORDS = ("names", "exif")

    def describe(self, step: float | None = None) -> dict:
        """The spec under the command line's names (for ``metrics.json``); ``step``: the database's input frames per
        frame kept (:func:`sampling_step`), which puts a tolerance in both units."""
        out = {"tolerance": self.tolerance, "gt": list(self.files) or None, "radius": self.radius,
               "gt_soft": self.soft}
        if self.tolerance is not None and step is not None:
            out.update(tolerance_unit="frames kept", frame_step=step,
                       tolerance_input_frames=self.tolerance * step,
                       tolerance_text=tolerance_text("--tolerance", self.tolerance, step))
            if self.soft is not None:
                out.update(gt_soft_input_frames=self.soft * step,
                           gt_soft_text=tolerance_text("--gt-soft", self.soft, step))
        if self.file_unit is not None:
            out["gt_tolerance_unit"] = self.file_unit
        topic = list(self.topic) if isinstance(self.topic, tuple) else self.topic
        return {**out, "gt_topic": topic} if self.topic is not None else out

    @property
    def topic_text(self) -> str:
        """``--gt-topic`` as written on the command line."""
        return " ".join(self.topic) if isinstance(self.topic, tuple) else str(self.topic)

    @property
    def keyword(self) -> str | None:
        """The ``--gt`` keyword given (``names``, ``exif``), if any."""
        return self.files[0] if len(self.files) == 1 and self.files[0] in self.KEYWORDS else None

    @property
    def given(self) -> bool:
        """Whether any ground truth is given (``--tolerance``, ``--gt`` or ``--gt-topic``)."""
        return self.tolerance is not None or bool(self.files) or self.topic is not None

    @property
    def positional(self) -> bool:
        """Ground truth from positions of the frames (``--radius``): every source's frames get a position."""
        return self.radius is not None

    def check(self, loops: bool = False, files: bool = True, sessions: int = 1) -> None:
        """Refuse contradictory, ignored or out-of-range options and missing files, before any work.

        ``loops``: ``vpr loops``'s ground truth; ``files=False``: the options only; ``sessions``: a multi-session
        stream's sources. Raises ValueError naming the options, FileNotFoundError for a missing ``--gt`` file.
        """
        check_files = files
        tol, files, radius, soft = self.tolerance, list(self.files), self.radius, self.soft
        if self.topic is not None:
            if files or tol is not None:
                raise ValueError(f"--gt-topic {self.topic_text}: positions come from the bags' topic; give it "
                                 "instead of --gt or --tolerance, not with them")
            if radius is None:
                raise ValueError(f"--gt-topic {self.topic_text} needs --radius (metres)")
        if self.keyword is not None:
            if radius is None:
                raise ValueError(f"--gt {self.keyword} needs --radius (metres)")
            check_files = False
        elif any(f in self.KEYWORDS for f in files):
            raise ValueError(f"--gt {' '.join(files)}: {', '.join(self.KEYWORDS)} name where positions are and "
                             "stand alone")
        if tol is not None and (isinstance(tol, bool) or not isinstance(tol, (int, np.integer)) or tol < 0):
            raise ValueError(f"--tolerance must be an integer >= 0 (frames), got {tol!r}")
        for name, v in (("--radius", radius), ("--gt-soft", soft)):
            if v is not None and (isinstance(v, bool) or parse_float(str(v)) is None or not math.isfinite(v)
                                  or v < 0):
                raise ValueError(f"{name} must be a finite number >= 0, got {v!r}")
        if tol is not None and files:
            raise ValueError("give either --tolerance or --gt, not both")
        if tol is not None and radius is not None:
            raise ValueError("--radius applies to position ground truth (--gt FILE), not to --tolerance")
        if loops and tol is not None:
            raise ValueError("loops: ground truth is --gt FILE (positions with --radius, frame,earlier pairs, or a "
                             "matrix), not --tolerance")
        matrices = [f for f in files if is_matrix_file(f)]
        if matrices and len(matrices) != len(files):
            raise ValueError("--gt: matrix files (.npy, .png, .bmp, .mat) cannot be mixed with CSV files")
        if len(files) > 2:
            raise ValueError(f"--gt takes one or two files, got {len(files)}")
        if radius is not None and not files and self.topic is None:
            raise ValueError("--radius needs --gt FILE (positions), --gt names / exif, or --gt-topic")
        if matrices and radius is not None:
            raise ValueError("--radius applies to positions CSV files, not to matrix ground truth "
                             f"({', '.join(matrices)})")
        if soft is not None:
            if tol is None and not files and self.topic is None:
                raise ValueError("--gt-soft needs ground truth: --tolerance K, or --gt FILE with --radius R")
            if (files or self.topic) and radius is None:
                raise ValueError("--gt-soft needs position ground truth (--radius) or --tolerance; with matrix "
                                 "files give the soft matrix as the second --gt file")
            hard, name = (tol, "--tolerance") if tol is not None else (radius, "--radius")
            if soft < hard:
                raise ValueError(f"--gt-soft {soft:g} is smaller than {name} {hard:g}: the soft ground truth "
                                 f"(pairs ignored) must reach at least as far as the true matches")
        if loops and not matrices and len(files) > 1 and not (radius is not None and len(files) == sessions):
            raise ValueError(f"loops: --gt takes one CSV file (positions with --radius, or frame,earlier pairs; "
                             f"with several sessions one positions file each), got {len(files)}")
        if not matrices and len(files) >= 2 and radius is None:
            raise ValueError(f"{len(files)} --gt CSV files are positions files and need --radius")
        for f in files if check_files else ():
            fp, _ = split_variable(f)
            if not fp.exists():
                raise FileNotFoundError(f"no such ground-truth file: {fp}")
            if not fp.is_file():
                raise ValueError(f"{fp}: is a folder, expected a ground-truth file")
        self._check_file_unit(loops, check_files and not matrices and radius is None and len(files) == 1)

    def _check_file_unit(self, loops: bool, pairs_file: bool) -> None:
        """A ``query,db,tolerance`` file needs ``file_unit``, and ``file_unit`` needs one."""
        unit, what = self.file_unit, "--gt-tolerance-unit"
        if unit is not None:
            if isinstance(unit, bool) or not isinstance(unit, (int, np.integer)) or unit < 1:
                raise ValueError(f"{what} must be an integer >= 1 (frames), got {unit!r}")
            if loops or self.radius is not None or self.tolerance is not None or self.topic is not None \
                    or self.soft is not None or len(self.files) != 1 or is_matrix_file(self.files[0]):
                raise ValueError(f"{what} applies to one query,db,tolerance CSV (OpenSeqSLAM's ground truth) as "
                                 "--gt, alone: not with --radius, --tolerance, --gt-soft, --gt-topic or matrices")
        if not pairs_file:
            return
        n = csv_columns(self.files[0])
        if n == 3 and unit is None:
            raise ValueError(f"{self.files[0]}: query,db,tolerance rows (OpenSeqSLAM's ground truth), whose "
                             f"tolerance column's unit the file does not say: give {what} N, the frames the tolerance "
                             "counts per frame of the file (10 for OpenSeqSLAM's Nordland sample: every 10th frame, "
                             "a tolerance at the full rate; 1: it counts the file's frames)")
        if n != 3 and unit is not None:
            raise ValueError(f"{what}: {self.files[0]} has {n} columns; it applies to query,db,tolerance rows")

    def no_match_error(self, db_indices=None, q_indices=None, exclude: int | None = None) -> ValueError:
        """The error for a ground truth in which no query frame has a true match, in the options' words.

        ``exclude``: loop closures (only pairs at least ``exclude`` frames apart count).
        """
        def span(idx) -> str:
            return f"{min(idx)}..{max(idx)}" if idx is not None and len(idx) else "none"

        if self.tolerance is not None:
            return ValueError(f"ground truth --tolerance {self.tolerance}: no query frame has a database frame "
                              f"within {self.tolerance} frame numbers (database frames {span(db_indices)}, "
                              f"query frames {span(q_indices)}); recall is undefined")
        files = f"--gt {', '.join(str(f) for f in self.files)}" if self.files else f"--gt-topic {self.topic_text}"
        if exclude is not None and self.radius is not None:
            return ValueError(f"ground truth {files} --radius {self.radius:g}: no frame is within "
                              f"{self.radius:g} of a frame at least --exclude {exclude} frames earlier; "
                              "there is no loop closure to find")
        if exclude is not None:
            return ValueError(f"ground truth {files}: no frame has a loop closure onto a frame at least "
                              f"--exclude {exclude} frames earlier; there is no loop closure to find")
        if self.radius is not None:
            return ValueError(f"ground truth {files} --radius {self.radius:g}: no query frame is within "
                              f"{self.radius:g} of a database frame; recall is undefined")
        return ValueError(f"ground truth {files[5:]}: none of its pairs names a query and a database frame that "
                          "are read; recall is undefined")


def sampling_step(indices) -> float:
    """Input frames per frame kept: the median step between a traverse's frame numbers (1 with fewer than two).

    ``--step 10`` gives 10; ``--fps`` on a video the ratio of the rates; a few unreadable frames do not change it.
    """
    idx = np.unique(np.asarray(indices, np.int64))
    return float(np.median(np.diff(idx))) if idx.size > 1 else 1.0


def _in_both_units(value: float, step: float) -> str:
    return (f"{value:g} frame{'' if value == 1 else 's'} kept = {value * step:g} input "
            f"frame{'' if value * step == 1 else 's'}")


def tolerance_text(flag: str, value: float, step: float) -> str:
    """A tolerance in both units, e.g. ``--tolerance 1: 1 frame kept = 10 input frames``."""
    return f"{flag} {value:g}: {_in_both_units(value, step)}"


def check_tolerance(spec: GroundTruthSpec, db_indices, q_indices) -> bool:
    """Say a ``--tolerance`` that probably means something else (one line, the run goes on); returns whether said.

    A tolerance of 0 at a subsampling (``--step`` > 1) accepts only the exact frame, where the neighbours kept are
    input frames apart; one wider than a tenth of the route (the frames kept of the shorter traverse) makes most of a
    route's pairs true: likely given in input frames.
    """
    tol = spec.tolerance
    if tol is None:
        return False
    step = sampling_step(db_indices)
    n = min(len(db_indices), len(q_indices))
    if tol == 0 and step > 1:
        warnings.warn(f"--tolerance 0 accepts only the exact frame, where frames kept are {step:g} input frames "
                      "apart; --tolerance 1 (a neighbour kept) was probably meant", UserWarning, stacklevel=3)
        return True
    if n and tol > max(n / 10, 1):
        meant = f"--tolerance {max(round(tol / step), 1)} ({tol} input frames)" if step > 1 else \
            f"--tolerance {max(n // 10, 1)} or less"
        warnings.warn(f"--tolerance {tol} counts frames kept and spans more than a tenth of the route ({n} frames "
                      f"kept, {_in_both_units(1, step)}): {meant} was probably meant", UserWarning,
                      stacklevel=3)
        return True
    return False


def check_radius(spec: GroundTruthSpec, db_xy) -> None:
    """Say a ``--radius`` smaller than the median travel between consecutive database frames kept: a query between
    two of them has no true match, and recall counts it lost (one line, the run goes on)."""
    xy = np.asarray(db_xy, np.float64)
    if spec.radius is None or xy.ndim != 2 or xy.shape[0] < 2:
        return
    step = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    step = step[np.isfinite(step) & (step > 0)]
    if step.size and spec.radius < float(np.median(step)):
        med = float(np.median(step))
        warnings.warn(f"--radius {spec.radius:g} is smaller than the median travel between consecutive database "
                      f"frames kept ({med:.3g}): a query between two of them has no true match; --radius {med:.3g} or "
                      "more was probably meant", UserWarning, stacklevel=3)


def build_gt(spec: GroundTruthSpec, db_names: Sequence[str], q_names: Sequence[str], db_indices: Sequence[int],
             q_indices: Sequence[int], db_traverse: str = "database", q_traverse: str = "query", totals=None,
             positions=None, rates=None):
    """(gt_hard, gt_soft) of the frames read, or (None, None) without ground truth.

    ``db_traverse`` / ``q_traverse``: names in a ``traverse,frame,x,y`` file; ``*_indices``: source frame numbers;
    ``totals``: frames per source where known (a matrix file must match); ``positions``: (database, query) positions
    the caller read, matched within ``spec.radius``; ``rates``: the sources' own frame rates, for a tolerance
    (:func:`aligned_frames`). Warns when most pairs are true; bad options or files raise ValueError.
    """
    if positions is not None:  # read by the caller from a checked spec
        check_radius(spec, positions[0])
        hard, soft = _from_positions(spec, positions[0], positions[1])
    else:
        hard, soft = _db_query_gt(spec, db_names, q_names, db_indices, q_indices, db_traverse, q_traverse, totals,
                                  rates)
    said = check_tolerance(spec, db_indices, q_indices)
    if hard is not None and not said:
        warn_if_mostly_true(spec, hard)
    return hard, soft


def _from_positions(spec: GroundTruthSpec, a, b):
    """Hard and soft ground truth within ``spec``'s radii; a frame without a position (a NaN row) has every pair
    in the soft band: unknown, left out of the metrics, while the method still saw the frame."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    ka, kb = ~np.isnan(a).any(axis=1), ~np.isnan(b).any(axis=1)
    big = not fits_dense(len(a), len(b))
    if ka.all() and kb.all():
        hard = gt_from_positions(a, b, spec.radius, sparse=big)
        return hard, (gt_from_positions(a, b, spec.soft, sparse=big) if spec.soft is not None else None)
    rows, cols, shape = np.flatnonzero(ka), np.flatnonzero(kb), (len(a), len(b))

    def within(radius):  # the pairs of frames with a position, at their places in the whole matrix
        g = gt_from_positions(a[ka], b[kb], radius, sparse=True).tocoo()
        return sp.csr_matrix((g.data, (rows[g.row], cols[g.col])), shape=shape, dtype=bool)

    hard = within(spec.radius)
    soft = within(spec.soft) if spec.soft is not None else hard.copy()
    ua, ub = np.flatnonzero(~ka), np.flatnonzero(~kb)
    unknown = sp.csr_matrix((np.ones(ua.size * shape[1] + shape[0] * ub.size, bool),
                             (np.r_[np.repeat(ua, shape[1]), np.tile(np.arange(shape[0]), ub.size)],
                              np.r_[np.tile(np.arange(shape[1]), ua.size), np.repeat(ub, shape[0])])), shape=shape)
    soft = (soft + unknown).astype(bool)
    return (hard, soft.tocsr()) if big else (hard.toarray(), soft.toarray())


def aligned_frames(db_names, q_names, db_indices, q_indices, rates=None) -> np.ndarray:
    """The query frames' places in the database's frame numbers, for a ``--tolerance`` between aligned traverses.

    Where both sources have frame rates (``rates``: database, query; :meth:`vpr.sources.Source.native_rate`) that
    differ, each is placed by its time; else, where every query frame is named as a database frame (a subsampled copy
    of one run, or datasets named frame by frame alike), at the frame of its name; else at its own frame number.
    A query placed otherwise than at its own number is said (one line).
    """
    q = np.asarray(q_indices, np.float64)
    db_rate, q_rate = rates if rates is not None else (None, None)
    where = {n: i for n, i in zip(db_names, db_indices, strict=False)}
    if db_rate and q_rate and not math.isclose(db_rate, q_rate, rel_tol=1e-3):
        at = q * (db_rate / q_rate)
        how = (f"at {q_rate:.4g} frames per second and the database's at {db_rate:.4g}: each is paired with the "
               "database frame of its time")
    elif len(where) == len(db_names) and len(q_names) and all(n in where for n in q_names):
        at = np.asarray([where[n] for n in q_names], np.float64)
        how = "named as database frames: each is paired with the database frame of its name"
    else:
        return q
    if not np.array_equal(at, q):
        warnings.warn(f"--tolerance: the query's frames are {how} (query frame {int(q[-1])} with database frame "
                      f"{at[-1]:g})", UserWarning, stacklevel=4)
    return at


def _db_query_gt(spec, db_names, q_names, db_indices, q_indices, db_traverse, q_traverse, totals, rates=None):
    spec.check()
    files = list(spec.files)
    if spec.tolerance is not None:  # in frames kept: the input frames a kept frame stands for
        step = sampling_step(db_indices)
        q_at = aligned_frames(db_names, q_names, db_indices, q_indices, rates)
        big = not fits_dense(len(db_indices), len(q_indices))  # a band, never the dense matrix
        hard = gt_from_frames(db_indices, q_at, spec.tolerance * step, sparse=big)
        soft = gt_from_frames(db_indices, q_at, spec.soft * step, sparse=big) if spec.soft is not None else None
        return hard, soft
    if not files:
        return None, None
    if is_matrix_file(files[0]):  # hard (and soft) matrices over the source frames
        hard = db_query_matrix(files[0], len(db_names), len(q_names), db_indices, q_indices, totals)
        soft = db_query_matrix(files[1], len(db_names), len(q_names), db_indices, q_indices, totals) \
            if len(files) == 2 else None
        return hard, (soft | hard if soft is not None else None)
    if spec.file_unit is not None:  # OpenSeqSLAM's query,db,tolerance rows (check() refused the rest)
        return load_tolerance_csv(files[0], len(db_names), len(q_names), spec.file_unit, db_indices=db_indices,
                                  q_indices=q_indices), None
    if spec.radius is None:  # one pairs file (check() refused the rest)
        hard = load_pairs_csv(files[0], len(db_names), len(q_names), db_names=db_names, q_names=q_names,
                              db_indices=db_indices, q_indices=q_indices)
        return hard, None
    if len(files) == 2:
        db_xy = positions_for_frames(files[0], db_names, db_indices, "database")
        q_xy = positions_for_frames(files[1], q_names, q_indices, "query")
    else:
        db_xy = positions_for(load_traverse_positions(files[0], db_traverse), db_indices, files[0], db_traverse)
        q_xy = positions_for(load_traverse_positions(files[0], q_traverse), q_indices, files[0], q_traverse)
    check_radius(spec, db_xy)
    big = not fits_dense(len(db_xy), len(q_xy))
    hard = gt_from_positions(db_xy, q_xy, spec.radius, sparse=big)
    soft = gt_from_positions(db_xy, q_xy, spec.soft, sparse=big) if spec.soft is not None else None
    return hard, soft


def build_loop_gt(spec: GroundTruthSpec, names: Sequence[str], indices: Sequence[int], traverse: str | None = None,
                  total: int | None = None, positions=None):
    """(gt_hard, gt_soft) of one stream's loop closures (T x T, rows earlier frame), or (None, None).

    From a positions CSV (with ``radius``, optionally ``soft``), a ``frame,earlier`` CSV, ``loop_pairs.csv`` or matrix
    files; both triangles filled (the metrics' mask says what is evaluated). ``traverse``: the stream's name in a file
    of several; ``total``: the stream's frames (a matrix must match); ``positions``: as read by the caller. Warns when
    most pairs are true.
    """
    if positions is not None:  # read by the caller from a checked spec
        check_radius(spec, positions)
        hard, soft = _from_positions(spec, positions, positions)
    else:
        hard, soft = _loop_gt(spec, names, indices, traverse, total)
    if hard is not None:
        warn_if_mostly_true(spec, hard, loops=True)
    return hard, soft


def _loop_gt(spec, names, indices, traverse, total):
    spec.check(loops=True)
    files = list(spec.files)
    if not files:
        return None, None
    n = len(names)
    if is_matrix_file(files[0]):
        hard = loop_matrix(files[0], indices, total)
        soft = loop_matrix(files[1], indices, total) | hard if len(files) == 2 else None
        return hard, soft
    if spec.radius is None and is_loop_pairs_file(files[0]):  # vpr render's loop_pairs.csv
        return load_loop_pairs(files[0], traverse, indices), None
    if spec.radius is None:
        pairs = load_pairs_csv(files[0], n, n, db_names=names, q_names=names, db_indices=indices, q_indices=indices,
                               columns=("frame", "earlier"))
        pairs = pairs.toarray() if hasattr(pairs, "toarray") else pairs
        return pairs | pairs.T, None
    xy = positions_of_frames(files[0], traverse, indices)
    check_radius(spec, xy)
    hard = gt_from_positions(xy, xy, spec.radius)
    return hard, (gt_from_positions(xy, xy, spec.soft) if spec.soft is not None else None)


def warn_if_mostly_true(spec: GroundTruthSpec, hard, loops: bool = False, share: float = 0.5) -> float:
    """Warn when more than ``share`` of all pairs are true matches; returns the share.

    Ground truth that makes (nearly) every pair true (``--radius 1e308``, a tolerance as long as the traverse, metres
    taken for kilometres) gives AP 1.000 whatever the method does. For loops the pairs are those of distinct frames (a
    frame always matches itself).
    """
    n = hard.shape[0] * hard.shape[1]
    true = int(hard.nnz if hasattr(hard, "nnz") else np.count_nonzero(hard))
    if loops:
        diag = hard.diagonal() if hasattr(hard, "diagonal") else np.diagonal(hard)
        true -= int(np.count_nonzero(diag))
        n -= min(hard.shape)
    got = true / n if n else 0.0
    if got > share:
        what = ", ".join(f"{k} {v}" for k, v in (("--tolerance", spec.tolerance), ("--radius", spec.radius))
                         if v is not None) or f"--gt {', '.join(map(str, spec.files))}"
        warnings.warn(f"ground truth {what}: {100 * got:.0f} % of all {'frame' if loops else 'database x query'} "
                      "pairs are true matches, so every metric is near its best whatever the method does (a unit "
                      "or tolerance mistake?)", UserWarning, stacklevel=3)
    return got


def check_loop_gt_files(spec: GroundTruthSpec, traverse: str | None = None) -> None:
    """Read ``spec``'s loop ground-truth files enough to refuse a bad one before any work.

    For a stream whose frames are not known yet (``vpr loops -``): the options, the matrices (square, numbers), the
    pairs CSV's columns and the positions file are checked; names in a pairs CSV can only be matched once the frames
    are read (:func:`build_loop_gt`).
    """
    spec.check(loops=True)
    files = list(spec.files)
    if not files:
        return
    if is_matrix_file(files[0]):
        for f in files:
            loop_matrix(f, [])
    elif spec.radius is not None:
        positions_of_frames(files[0], traverse, [])
    elif is_loop_pairs_file(files[0]):
        load_loop_pairs(files[0], traverse, [])
    else:
        read_rows(files[0], 2, "frame,earlier")


def build_stream_gt(spec: GroundTruthSpec, srcs, attempted, positions=None):
    """The loop ground truth of one stream, or of the sessions of one (``srcs``, in order), over the frames to
    attempt (``attempted``: each source's frame numbers); ``positions``: each source's (:func:`prepare_positions`)."""
    if len(srcs) == 1:
        src = srcs[0]
        return build_loop_gt(spec, src.names(), attempted[0], src.name, total=src.exact_total(),
                             positions=None if positions is None else positions[0])
    if positions is not None:
        return build_loop_gt(spec, [], [], positions=np.concatenate(positions))
    if spec.files and is_loop_pairs_file(spec.files[0]):
        raise ValueError(f"--gt {spec.files[0]}: vpr render's loop_pairs.csv pairs frames of one traverse; for "
                         "sessions give positions (its ground_truth.csv with --radius)")
    totals = [s.exact_total() for s in srcs]
    offsets = np.cumsum([0, *[t if t is not None else len(a) for t, a in zip(totals, attempted, strict=True)]])
    names = [f"{s.name}/{n}" for s in srcs for n in s.names()]
    indices = [int(i) + int(o) for a, o in zip(attempted, offsets, strict=False) for i in a]
    total = int(offsets[-1]) if all(t is not None for t in totals) else None
    return build_loop_gt(spec, names, indices, None, total=total)

