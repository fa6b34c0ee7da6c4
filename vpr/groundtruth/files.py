"""Ground truth read from files: (query, db) pairs, per-frame positions, positions of rendered traverses."""
from __future__ import annotations

import csv
import math
import re
import warnings
from collections.abc import Sequence
from pathlib import Path, PurePath

import numpy as np
import scipy.sparse as sp

from vpr.checks import check_count
from vpr.similarity import fits_dense

from .matrices import gt_from_positions

__all__ = ["load_pairs_csv", "load_tolerance_csv", "csv_columns",
           "load_positions_csv", "gt_from_position_files", "load_traverse_positions",
           "positions_of_frames", "positions_for", "read_rows", "parse_float", "POSITION_COLUMNS",
           "positions_for_frames"]


_INT = re.compile(r"[+-]?\d+(?:\.0*)?")


def _parse_int(token: str) -> int | None:
    # "12.0" is accepted because spreadsheet and pandas exports often write floats
    if _INT.fullmatch(token):
        return int(token.split(".")[0])
    return None


def parse_float(token: str) -> float | None:
    try:
        return float(token)
    except ValueError:
        return None


def read_rows(path, n_cols: int, what: str) -> list[tuple[int, list[str]]]:
    """Content lines of a CSV file as (line number, stripped fields)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise FileNotFoundError(f"no such ground-truth file: {path}") from None
    except IsADirectoryError:
        raise ValueError(f"{path}: is a folder, expected a CSV file") from None
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path}: not a UTF-8 text file (byte {exc.start})") from None
    rows = []
    for lineno, line in enumerate(text.splitlines(), start=1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        if "," in s:
            try:
                fields = next(csv.reader([s], skipinitialspace=True))
            except csv.Error as exc:
                raise ValueError(f"{path}:{lineno}: {exc}") from None
        else:
            fields = s.split()
        fields = [f.strip() for f in fields]
        if len(fields) != n_cols:
            raise ValueError(f"{path}:{lineno}: expected {n_cols} columns ({what}), got {len(fields)}")
        rows.append((lineno, fields))
    if not rows:
        raise ValueError(f"{path}: empty file (no {what} rows)")
    return rows


def _alias_keys(name: str) -> list[str]:
    """The name itself, then without folders, then without extension."""
    p = PurePath(name.replace("\\", "/"))
    return [name, p.name, p.stem]


class _NameIndex:
    """Map a token to a position in ``names``: exact name first, then folder-less, then stem.

    An alias shared by several names matches none of them, so a token never silently picks one of two frames.
    """

    def __init__(self, names: Sequence[str]):
        self._levels: list[dict[str, int | None]] = [{}, {}, {}]
        for pos, name in enumerate(names):
            for level, key in zip(self._levels, _alias_keys(str(name)), strict=False):
                level[key] = None if key in level and level[key] != pos else pos

    def find(self, name: str) -> tuple[int | None, bool]:
        """Return (position, ambiguous) of the entry matching ``name`` at the first level that has it.

        ``name`` is reduced the same way at each level, so "0001.png" finds "0001" and "a.png" finds "imgs/a.png".
        """
        for level, key in zip(self._levels, _alias_keys(name), strict=False):
            if key in level:
                pos = level[key]
                return pos, pos is None
        return None, False



def _index_rows(indices, n: int, what: str) -> dict[int, int]:
    """Frame number -> output row."""
    if indices is None:
        return {i: i for i in range(n)}
    idx = [int(i) for i in indices]
    if len(idx) != n:
        raise ValueError(f"{what}: {len(idx)} frame numbers for {n} frames")
    rows = {k: r for r, k in enumerate(idx)}
    if len(rows) != n:
        raise ValueError(f"{what}: frame numbers are not unique")
    return rows


def _check_names(names, n: int, what: str):
    if names is not None and len(names) != n:
        raise ValueError(f"{what}: {len(names)} names for {n} frames")


def _pairs_matrix(rows_db, cols_q, n_db: int, n_q: int):
    """Bool (n_db, n_q), True at the (database, query) pairs given; sparse above
    :func:`~vpr.similarity.dense_pairs` pairs (a dense bool matrix of 50,000 x 50,000 frames would take 2.5 GB)."""
    rows_db, cols_q = np.asarray(rows_db, np.int64), np.asarray(cols_q, np.int64)
    if not fits_dense(n_db, n_q):
        gt = sp.csr_matrix((np.ones(rows_db.size, bool), (rows_db, cols_q)), shape=(n_db, n_q))
        gt.sum_duplicates()
        return gt
    gt = np.zeros((n_db, n_q), dtype=bool)
    gt[rows_db, cols_q] = True
    return gt


def load_pairs_csv(path, n_db: int, n_q: int, db_names: Sequence[str] | None = None,
                   q_names: Sequence[str] | None = None, *, db_indices: Sequence[int] | None = None,
                   q_indices: Sequence[int] | None = None, columns: tuple[str, str] = ("query", "db")):
    """Ground truth from a CSV of ``query,db`` pairs, one matching per line.

    A header names the columns ``query`` and ``db`` in either order (``columns``: other names, query first, e.g.
    ``("frame", "earlier")`` for one stream's loops); any other header is refused; without one the query comes first.
    A token matching a name in ``db_names`` / ``q_names`` is that frame. With ``db_indices`` / ``q_indices`` (source
    frame numbers of the frames read) a frame that was not read drops the pair with one warning; without, frames are
    0..n-1 and a larger number is an error.

    Returns bool (n_db, n_q), sparse above :func:`~vpr.similarity.dense_pairs` pairs. A missing file raises
    FileNotFoundError; a malformed one ValueError ``"FILE:LINE: reason"``.
    """
    n_db = check_count(n_db, "n_db", minimum=1)
    n_q = check_count(n_q, "n_q", minimum=1)
    _check_names(db_names, n_db, "db_names")
    _check_names(q_names, n_q, "q_names")
    sides = {
        "query": (_NameIndex(q_names) if q_names is not None else None, _index_rows(q_indices, n_q, "q_indices"),
                  q_indices is not None, n_q),
        "db": (_NameIndex(db_names) if db_names is not None else None, _index_rows(db_indices, n_db, "db_indices"),
               db_indices is not None, n_db),
    }
    label = {"query": columns[0], "db": columns[1]}
    rows = read_rows(path, 2, ",".join(columns))

    def resolve(token: str, role: str, where: str) -> tuple[int | None, str | None]:
        """(output row or None if the frame was not read, error message or None)."""
        lookup, by_index, has_indices, n = sides[role]
        name = label[role]
        if not token:
            return None, f"{where}: empty {name} field"
        if lookup is not None:
            pos, ambiguous = lookup.find(token)
            if ambiguous:
                return None, f"{where}: {name} frame name {token!r} matches several frames"
            if pos is not None:
                return pos, None
        k = _parse_int(token)
        if k is None:
            hint = "" if lookup is not None else f" (pass {'q' if role == 'query' else 'db'}_names to match names)"
            kind = "a known frame name or an integer frame number" if lookup is not None else "an integer"
            return None, f"{where}: {name} {token!r} is not {kind}{hint}"
        if k < 0:
            return None, f"{where}: {name} frame number {k} is negative"
        if k in by_index:
            return by_index[k], None
        if has_indices:
            return None, None
        return None, f"{where}: {name} frame number {k} out of range 0..{n - 1}"

    first_line, first = rows[0]
    order = (0, 1)  # headerless files are query,db
    header = [t.casefold() for t in first]
    if sorted(header) == sorted(c.casefold() for c in columns):
        # columns by name: a "db,query" header must not be read as query,db
        order = (header.index(columns[0].casefold()), header.index(columns[1].casefold()))
        rows = rows[1:]
    else:
        resolved_first = [resolve(t, r, "") for t, r in zip(first, ("query", "db"), strict=False)]
        if all(pos is None and err is not None and _parse_int(t) is None
               for t, (pos, err) in zip(first, resolved_first, strict=False)):
            # neither field is a frame: a header, but not one we can read
            raise ValueError(f"{path}:{first_line}: unknown header {','.join(first)!r}; expected the columns "
                             f"{columns[0]} and {columns[1]} (in either order), or no header and "
                             f"{columns[0]},{columns[1]} pairs")
    if not rows:
        raise ValueError(f"{path}: no pairs after the header on line {first_line}")

    rows_db, cols_q = [], []
    dropped = 0
    for lineno, fields in rows:
        q_tok, db_tok = fields[order[0]], fields[order[1]]
        where = f"{path}:{lineno}"
        q, err = resolve(q_tok, "query", where)
        if err:
            raise ValueError(err)
        d, err = resolve(db_tok, "db", where)
        if err:
            raise ValueError(err)
        if q is None or d is None:
            dropped += 1
            continue
        rows_db.append(d)
        cols_q.append(q)
    if dropped:
        warnings.warn(f"{path}: {dropped} pairs name frames that were not read; ignored", stacklevel=2)
    return _pairs_matrix(rows_db, cols_q, n_db, n_q)


def csv_columns(path) -> int:
    """The number of columns of the first content line of the CSV ``path`` (0: no content line)."""
    for line in Path(path).read_text(encoding="utf-8-sig", errors="replace").splitlines():
        s = line.strip()
        if s and not s.startswith("#"):
            return len(next(csv.reader([s], skipinitialspace=True))) if "," in s else len(s.split())
    return 0


def load_tolerance_csv(path, n_db: int, n_q: int, unit: int, *, db_indices: Sequence[int] | None = None,
                       q_indices: Sequence[int] | None = None):
    """Ground truth from OpenSeqSLAM's CSV of ``query,reference,tolerance`` rows (frames counted from 1, as MATLAB
    counts).

    A query row matches the database frames within ``tolerance // unit`` frames of its reference: ``unit`` is how
    many of the frames the tolerance counts one frame of the file stands for (OpenSeqSLAM's Nordland sample: 358 rows
    of every 10th frame, a tolerance of 15 frames at the full rate; ``unit=10``: within 1 frame). Frame ``k`` of the
    file is source frame ``k - 1``; with ``db_indices`` / ``q_indices`` (source frame numbers of the frames read)
    frames that were not read are left out (one warning), without them frames are 0..n-1 and a larger one is an
    error. An optional header names the three columns ``query``, ``db`` (or ``reference``) and ``tolerance``, in this
    order.

    Returns bool (n_db, n_q), sparse above :func:`~vpr.similarity.dense_pairs` pairs. A missing file raises
    FileNotFoundError; a malformed one ValueError ``"FILE:LINE: reason"``.
    """
    n_db = check_count(n_db, "n_db", minimum=1)
    n_q = check_count(n_q, "n_q", minimum=1)
    unit = check_count(unit, "unit", minimum=1)
    db_rows, q_rows = _index_rows(db_indices, n_db, "db_indices"), _index_rows(q_indices, n_q, "q_indices")
    rows = read_rows(path, 3, "query,db,tolerance")
    if _parse_int(rows[0][1][0]) is None:  # a header
        first_line, header = rows[0]
        if [h.casefold() for h in header] not in (["query", "db", "tolerance"], ["query", "reference", "tolerance"]):
            raise ValueError(f"{path}:{first_line}: unknown header {','.join(header)!r}; expected query,db,tolerance "
                             "or no header")
        rows = rows[1:]
        if not rows:
            raise ValueError(f"{path}: no rows after the header on line {first_line}")
    db_hits, q_hits, dropped = [], [], 0
    for lineno, fields in rows:
        values = [_parse_int(f) for f in fields]
        for name, v, f in zip(("query", "db", "tolerance"), values, fields, strict=True):
            if v is None:
                raise ValueError(f"{path}:{lineno}: {name} {f!r} is not an integer")
        q, ref, tol = values
        if q < 1 or ref < 1:
            raise ValueError(f"{path}:{lineno}: frame number {min(q, ref)}: the frames of a query,db,tolerance file "
                             "count from 1 (OpenSeqSLAM's, MATLAB's)")
        if tol < 0:
            raise ValueError(f"{path}:{lineno}: tolerance {tol} is negative")
        if q - 1 not in q_rows:
            if q_indices is None:
                raise ValueError(f"{path}:{lineno}: query frame {q} out of range 1..{n_q}")
            dropped += 1
            continue
        if db_indices is None and ref > n_db:
            raise ValueError(f"{path}:{lineno}: database frame {ref} out of range 1..{n_db}")
        reach = tol // unit
        hits = [db_rows[k] for k in range(ref - 1 - reach, ref + reach) if k in db_rows]
        dropped += not hits
        db_hits += hits
        q_hits += [q_rows[q - 1]] * len(hits)
    if dropped:
        warnings.warn(f"{path}: {dropped} rows name frames that were not read; ignored", stacklevel=2)
    return _pairs_matrix(db_hits, q_hits, n_db, n_q)


#: The names a positions file's header may give its three columns (any case, any order).
POSITION_COLUMNS = {
    "frame": ("frame", "name", "image", "file", "filename", "path", "index"),
    "x": ("x", "east", "easting", "utm_east"),
    "y": ("y", "north", "northing", "utm_north"),
}


def _position_order(path, first_line: int, header: list[str]) -> tuple[int, int, int]:
    """Where the frame, x and y columns are, read from a header by name; any other header is refused."""
    keys = [h.casefold() for h in header]
    order = []
    for names in POSITION_COLUMNS.values():
        at = [i for i, k in enumerate(keys) if k in names]
        if len(at) != 1:
            break
        order.append(at[0])
    if len(order) != 3 or len(set(order)) != 3:
        raise ValueError(f"{path}:{first_line}: unknown header {','.join(header)!r}; expected the columns frame, x "
                         "and y (any order; also name / easting / northing), or no header and frame,x,y rows")
    return order[0], order[1], order[2]


def _load_positions(path):
    rows = read_rows(path, 3, "frame,x,y")
    first_line, first = rows[0]
    order = (0, 1, 2)  # headerless files are frame,x,y
    if sum(parse_float(t) is None for t in first) >= 2:
        # two fields that are not numbers: a header, read by name (an "x,y,frame" header must not be read as frame,x,y)
        order = _position_order(path, first_line, first)
        rows = rows[1:]
        if not rows:
            raise ValueError(f"{path}: no positions after the header on line {first_line}")
    tokens, xy, lines = [], [], []
    for lineno, fields in rows:
        frame, xs, ys = (fields[i] for i in order)
        where = f"{path}:{lineno}"
        if not frame:
            raise ValueError(f"{where}: empty frame field")
        for label, tok in (("x", xs), ("y", ys)):
            v = parse_float(tok)
            if v is None:
                raise ValueError(f"{where}: {label} {tok!r} is not a number")
            if not math.isfinite(v):
                raise ValueError(f"{where}: {label} is {tok!r}, expected a finite number")
        tokens.append(frame)
        xy.append((float(xs), float(ys)))
        lines.append(lineno)
    ints = [_parse_int(t) for t in tokens]
    if all(k is not None for k in ints):
        frames = ints
    else:
        frames = tokens
    seen: dict = {}
    for f, lineno in zip(frames, lines, strict=False):
        if isinstance(f, int) and f < 0:
            raise ValueError(f"{path}:{lineno}: frame number {f} is negative")
        if f in seen:
            raise ValueError(f"{path}:{lineno}: duplicate frame {f!r} (first on line {seen[f]})")
        seen[f] = lineno
    return frames, tokens, np.asarray(xy, dtype=np.float64).reshape(-1, 2), lines


def load_positions_csv(path) -> tuple[list[str] | np.ndarray, np.ndarray]:
    """Per-frame positions from lines of ``frame,x,y`` (header optional).

    Returns ``(frames, xy)``: int64 frame numbers when every frame field is an integer, else names; float64 (n, 2)
    positions in file order. A missing file raises FileNotFoundError; a malformed one (columns, coordinates, negative
    or duplicate frame) ValueError ``"FILE:LINE: reason"``.
    """
    frames, _, xy, _ = _load_positions(path)
    if frames and isinstance(frames[0], int):
        return np.asarray(frames, dtype=np.int64), xy
    return list(frames), xy


def positions_for_frames(path, names, indices, role: str) -> np.ndarray:
    """Positions of the frames read, one row per frame in reading order."""
    frames, tokens, xy, _ = _load_positions(path)
    if names is None and indices is None and not isinstance(frames[0], int):
        return xy  # named rows without frame names to match: file order
    if names is not None:
        if indices is not None and len(indices) != len(names):
            raise ValueError(f"{role}: {len(indices)} frame numbers for {len(names)} names")
        lookup = _NameIndex(tokens)
        found = [lookup.find(str(n)) for n in names]
        # integer-looking tokens may still be names such as "0001" for 0001.png
        if not isinstance(frames[0], int) or all(pos is not None for pos, _ in found):
            missing = [n for n, (pos, _) in zip(names, found, strict=False) if pos is None]
            if missing:
                raise ValueError(f"{path}: no position for {len(missing)} of the {len(names)} {role} frames read, "
                                 f"e.g. {', '.join(repr(m) for m in missing[:3])}")
            return xy[[pos for pos, _ in found]]
        wanted = list(indices) if indices is not None else list(range(len(names)))
    elif indices is not None:
        wanted = list(indices)
    else:
        wanted = list(range(max(frames) + 1))
    row_of = {k: r for r, k in enumerate(frames)}
    missing = [k for k in wanted if k not in row_of]
    if missing:
        raise ValueError(f"{path}: no position for {len(missing)} of the {len(wanted)} {role} frames, "
                         f"e.g. frame number {', '.join(str(m) for m in missing[:3])}")
    return xy[[row_of[k] for k in wanted]]


def gt_from_position_files(db_csv, q_csv, radius: float, db_names: Sequence[str] | None = None,
                           q_names: Sequence[str] | None = None, *, db_indices: Sequence[int] | None = None,
                           q_indices: Sequence[int] | None = None) -> np.ndarray:
    """Ground truth from per-frame ``frame,x,y`` files of both traverses: pairs within ``radius`` (inclusive).

    Rows of frames not read are ignored; a frame read without a row is an error. Rows are matched to frames by
    ``db_names`` / ``q_names`` (integer-looking rows too when every name matches one; without names, named rows in
    file order) or by ``db_indices`` / ``q_indices`` (default 0, 1, 2, ...). Returns bool (n_db, n_q), sparse above
    :func:`~vpr.similarity.dense_pairs` pairs.
    """
    r = parse_float(str(radius)) if not isinstance(radius, bool) else None
    if r is None or not math.isfinite(r) or r < 0:
        raise ValueError(f"radius must be a finite number >= 0, got {radius!r}")
    db_xy = positions_for_frames(db_csv, db_names, db_indices, "database")
    q_xy = positions_for_frames(q_csv, q_names, q_indices, "query")
    return gt_from_positions(db_xy, q_xy, r, sparse=not fits_dense(len(db_xy), len(q_xy)))


# --------------------------------------------------------------------------- #
# rows "traverse,frame,x,y" (as written by vpr render) and the match pipeline's choice
# --------------------------------------------------------------------------- #
def load_traverse_positions(path, traverse: str | None) -> dict[int, tuple[float, float]]:
    """Rows ``traverse,frame,x,y[,...]`` (as ``vpr render`` writes) of one traverse: frame -> (x, y).

    ``traverse`` None: the file must hold one traverse. A source named like a file (``laps.mp4``) also matches the
    rows of its stem. A missing file raises FileNotFoundError; no such header, a malformed row (``FILE:LINE: reason``)
    or no row for ``traverse`` ValueError.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"ground truth file not found: {path}")
    rows = {}
    with open(path, newline="", encoding="utf-8") as fh:
        reader = csv.reader(fh)
        header = next(reader, None)
        if header is None:
            raise ValueError(f"{path}: empty ground truth file")
        cols = [h.strip().lower() for h in header]
        need = {"traverse", "frame", "x", "y"}
        if not need <= set(cols):
            raise ValueError(f"{path}:1: expected a header with columns {sorted(need)}, got {header}")
        ti, fi, xi, yi = (cols.index(c) for c in ("traverse", "frame", "x", "y"))
        names = (traverse, str(Path(traverse).with_suffix(""))) if traverse is not None else ()
        by_name: dict[str, dict] = {n: {} for n in names}
        for line_no, row in enumerate(reader, start=2):
            if not row or row[0].startswith("#"):
                continue
            if len(row) != len(cols):
                raise ValueError(f"{path}:{line_no}: expected {len(cols)} columns, got {len(row)}")
            if traverse is None:
                by_name.setdefault(row[ti], {})
            elif row[ti] not in by_name:
                continue
            try:
                x, y = float(row[xi]), float(row[yi])
                by_name[row[ti]][int(row[fi])] = (x, y)
            except ValueError:
                raise ValueError(f"{path}:{line_no}: frame must be an integer and x, y numbers") from None
            if not (math.isfinite(x) and math.isfinite(y)):
                raise ValueError(f"{path}:{line_no}: x, y must be finite numbers, got {row[xi]}, {row[yi]}")
    if traverse is None:  # a stream without a name (stdin): the file's only traverse
        if len(by_name) != 1:
            raise ValueError(f"{path}: {len(by_name)} traverses ({', '.join(sorted(by_name)) or 'none'}); a stream "
                             "without a name needs a file with one traverse, or frame,x,y rows")
        return next(iter(by_name.values()))
    rows = by_name[traverse] or by_name[names[1]]
    if not rows:
        raise ValueError(f"{path}: no rows for traverse {traverse!r}")
    return rows


def positions_for(rows, indices, path, traverse) -> np.ndarray:
    missing = [i for i in indices if i not in rows]
    if missing:
        raise ValueError(f"{path}: no position for frame {missing[0]} of traverse {traverse!r}")
    return np.array([rows[i] for i in indices])


def positions_of_frames(path, traverse: str | None, indices: Sequence[int]) -> np.ndarray:
    """(x, y) of the frames numbered ``indices`` from a ``frame,x,y`` or ``traverse,frame,x,y`` file."""
    with open(path, encoding="utf-8") as fh:
        first = fh.readline().lower()
    if "traverse" in first:
        return positions_for(load_traverse_positions(path, traverse), indices, path, traverse)
    keys, xy = load_positions_csv(path)
    rows = {int(k) if not isinstance(k, str) else k: tuple(v) for k, v in zip(keys, xy, strict=True)}
    return positions_for(rows, indices, path, traverse)


#: Header of the loop pairs ``vpr render`` writes (``loop_pairs.csv``).
LOOP_PAIRS_HEADER = ("traverse", "frame_a", "frame_b", "distance")


def is_loop_pairs_file(path) -> bool:
    """Whether ``path`` is a CSV with the header of ``vpr render``'s ``loop_pairs.csv``."""
    try:
        with open(path, encoding="utf-8-sig") as fh:
            first = next((s for s in (line.strip() for line in fh) if s and not s.startswith("#")), "")
    except (OSError, UnicodeDecodeError):
        return False
    return tuple(f.strip().casefold() for f in first.split(",")) == LOOP_PAIRS_HEADER


def load_loop_pairs(path, traverse: str | None, indices: Sequence[int]) -> np.ndarray:
    """Loop ground truth (T x T bool, both triangles) of the frames read, from ``vpr render``'s ``loop_pairs.csv``.

    Rows ``traverse,frame_a,frame_b,distance`` (source frame numbers); the rows of ``traverse`` are read, or all rows
    when the file has one traverse only (a stream read from stdin has no traverse name). Pairs with a frame that was
    not read are left out.
    """
    rows = read_rows(path, 4, ",".join(LOOP_PAIRS_HEADER))[1:]
    names = {r[0] for _, r in rows}
    if traverse not in names and len(names) > 1:  # None (stdin): the file's only traverse
        raise ValueError(f"{path}: no loop pairs of traverse {traverse!r}; traverses: {', '.join(sorted(names))}")
    pos = _index_rows(indices, len(indices), "indices")
    out = np.zeros((len(indices), len(indices)), bool)
    for lineno, (t, a, b, _) in rows:
        if traverse in names and t != traverse:
            continue
        fa, fb = _parse_int(a), _parse_int(b)
        if fa is None or fb is None or fa < 0 or fb < 0:
            raise ValueError(f"{path}:{lineno}: frame_a and frame_b must be frame numbers >= 0, got {a!r}, {b!r}")
        if fa in pos and fb in pos:
            out[pos[fa], pos[fb]] = out[pos[fb], pos[fa]] = True
    return out
