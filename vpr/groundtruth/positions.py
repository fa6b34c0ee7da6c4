"""Where every frame was: positions for ground truth within a radius and for ``--every``, before any frame is read."""
from __future__ import annotations

import warnings
from collections.abc import Mapping
from dataclasses import replace

import numpy as np

from vpr.checks import per_input
from vpr.paths import speed_step
from vpr.types import RATE_RATIO

from . import trajectories as tr
from .files import load_traverse_positions, positions_for, positions_for_frames, positions_of_frames
from .spec import GroundTruthSpec

__all__ = ["input_spec", "prepare_positions", "frame_positions", "Positions", "same_sampling"]


class Positions(list):
    """Each source's frame positions, and the GPS ``origin`` (latitude, longitude) they are metres from (or None)."""

    origin: tuple | None = None


def _csv_positions(src, path, role: str, single: bool) -> np.ndarray:
    idx = src.indices()
    if single:  # one file for one stream (loops), or the combined traverse,frame,x,y of vpr render
        return positions_of_frames(path, src.name if src.name else None, idx)
    with open(path, encoding="utf-8-sig") as fh:
        combined = "traverse" in fh.readline().lower()
    if combined:
        return positions_for(load_traverse_positions(path, src.name), idx, path, src.name)
    return positions_for_frames(path, src.names(), idx, role)


def _timed(stamps, t, values, kind: str, where: str) -> tuple[np.ndarray, str, str]:
    """Positions at the frames' times, and why the frames without one have none (the outages' spans)."""
    xy, why = tr.positions_at(stamps, t, values)
    notes = []
    if (why == 1).any():
        notes.append(f"{int((why == 1).sum())} outside the time span of {where}")
    if (why == 2).any():
        gaps = tr.outages(t)
        g = int(np.argmax(gaps[:, 1] - gaps[:, 0]))
        notes.append(f"{int((why == 2).sum())} in {len(gaps)} outage{'s' if len(gaps) > 1 else ''} of {where} "
                     f"(no position for over {tr.outage_limit(t):g} s; longest {float(gaps[g, 1] - gaps[g, 0]):.1f} s, "
                     f"from {float(gaps[g, 0] - t[0]):.1f} s after its first sample), not interpolated across")
    short = tr.short_gaps(t)
    stamps = np.asarray(stamps, np.float64)
    inside = np.zeros(len(xy), bool)
    for a, b in short:
        inside |= (stamps > a) & (stamps < b)
    if inside.any():
        g = int(np.argmax(short[:, 1] - short[:, 0]))
        warnings.warn(f"{where}: {int(inside.sum())} frames fall in {len(short)} short gap"
                      f"{'s' if len(short) > 1 else ''} of its positions (longest "
                      f"{float(short[g, 1] - short[g, 0]):.1f}"
                      f" s, from {float(short[g, 0] - t[0]):.1f} s after its first sample; fixes without a position "
                      f"are dropped) and are interpolated across them (gaps over {tr.outage_limit(t):g} s are "
                      "outages, not interpolated)", UserWarning, stacklevel=4)
    return xy, kind, "; ".join(notes)


def _check_alike(srcs, path) -> None:
    """Refuse one ``traverse,frame,x,y`` file for sessions named alike (``run1/img``, ``run2/img``) unless its rows
    tell them apart: the rows of ``img`` would be taken for both."""
    alike = [s for s in srcs if "/" in s.name]
    if not alike:
        return
    try:
        for s in alike:
            load_traverse_positions(path, s.name)
    except ValueError:
        base = " / ".join(sorted({repr(s.name.rsplit("/", 1)[-1]) for s in alike}))
        raise ValueError(f"--gt {path}: {' and '.join(str(s.path) for s in alike)} share a name ({base}); "
                         f"the file's traverse column must tell them apart ({', '.join(repr(s.name) for s in alike)}), "
                         "or give one positions file per session (--gt FILE [FILE ...], in order)") from None


def frame_positions(src, spec: GroundTruthSpec, file: str | None, role: str, single: bool = False,
                    topic: str | None = None) -> tuple[np.ndarray, str, str]:
    """(positions (n, d), kind, note) of ``src``'s frames to attempt; NaN rows: frames without a position.

    ``kind`` ``"latlon"`` (degrees: GPS, to be put in metres about one origin for every source of a run) or
    ``"metres"``. ``file``: this source's ``--gt`` file or keyword (None with ``--gt-topic``); ``topic``: this
    source's ``--gt-topic``; ``single``: the file holds this stream alone (loop closure). ``note`` says why frames
    have no position ("" when it goes without saying).
    """
    what = f"{role} {src.path}"
    if topic is not None:
        t, values, kind = src.trajectory(topic)
        return _timed(src.stamps(), t, values, kind, topic)
    if file == "names":
        return tr.utm_from_names(src.names()), "metres", ""
    if file == "exif":
        paths = src.frame_paths()
        if paths is None:
            raise ValueError(f"--gt exif: {what} is not a folder or list of photos")
        latlon, _ = tr.exif_positions(paths)
        if np.isnan(latlon[:, 0]).all():
            raise ValueError(f"--gt exif: no photo of {what} has a GPS position in its EXIF")
        return latlon, "latlon", "without a GPS position in the EXIF"
    kind = tr.trajectory_format(file)
    if kind == "tum":
        stamps = src.stamps()
        if stamps is None:
            raise ValueError(f"--gt {file}: a TUM trajectory is matched to the frames by time, and {what} has no "
                             "times (a bag, a video, or images named by their timestamps)")
        t, xyz = tr.load_tum(file)
        return _timed(stamps, t, xyz, "metres", str(file))
    if kind == "kitti":
        xyz = tr.load_kitti(file)
        idx = np.asarray(src.indices(), np.int64)
        if idx.size and idx.max() >= xyz.shape[0]:
            raise ValueError(f"--gt {file}: {xyz.shape[0]} KITTI poses, but {what} has frame {int(idx.max())}")
        return xyz[idx], "metres", ""
    return _csv_positions(src, file, role, single), "metres", ""


def input_spec(spec: GroundTruthSpec, k: int, n: int) -> GroundTruthSpec:
    """The position ground truth of the ``k``-th of ``n`` traverses read one at a time (a database learned, then its
    query; the sessions of a stream): its own positions file of ``--gt FILE1 FILE2 ...`` and its own ``--gt-topic``.

    One file stays every traverse's where it names each (``names``, ``exif``, a ``traverse,frame,x,y`` CSV); one
    trajectory or ``frame,x,y`` CSV for several traverses, or a count of files that is neither one nor ``n``, is
    refused. A spec without ``--radius`` (pairs, matrices, ``--tolerance``) is the run's, returned as it is.
    """
    if not spec.positional:
        return spec
    topics = per_input(spec.topic, n, "--gt-topic")
    files = list(spec.files)
    if spec.topic is None and len(files) != n and (len(files) != 1 or spec.keyword is None and not
                                                    _names_traverses(files[0])):
        kind = tr.trajectory_format(files[0]) if len(files) == 1 else None
        what = (f"one {'trajectory' if kind else 'positions file'}" if len(files) == 1 else
                f"{len(files)} positions files")
        raise ValueError(f"--gt {' '.join(files)}: {what} for {n} traverse{'s' if n > 1 else ''}; give one per "
                         f"traverse, in order (--gt {' '.join(f'FILE{j + 1}' for j in range(n))})"
                         + (", or one CSV with traverse,frame,x,y rows" if n > 1 else ""))
    own = tuple(files) if len(files) != n or n == 1 else (files[k],)
    return replace(spec, files=own, topic=topics[k])


def _names_traverses(path) -> bool:
    """Whether the positions CSV ``path`` has a traverse column (``traverse,frame,x,y``: every traverse's rows)."""
    if tr.trajectory_format(path) is not None:
        return False
    with open(path, encoding="utf-8-sig") as fh:
        return "traverse" in fh.readline().lower()


def prepare_positions(srcs, roles, spec: GroundTruthSpec, every: float | None = None, loops: bool | None = None,
                      need: bool | None = None, origin: tuple | None = None) -> list | None:
    """Every source's frame positions (aligned with its ``indices()`` after this), or None when none are needed.

    Frames without a position keep NaN (warned); ``every`` (metres) keeps one frame per ``every`` metres of travel
    (the rest left out, said); a source without any position is refused. ``need``: positions wanted (default:
    ``--radius``); ``loops``: one stream's options. GPS positions go to metres about one ``origin`` (default: the
    first fix), kept in the :class:`Positions` result.
    """
    need = spec.positional if need is None else need
    if not need:
        if every is not None:
            raise ValueError("--every needs the frames' positions: --gt-topic TOPIC, or --gt FILE / names / exif, "
                             "with --radius")
        return None
    # the options, before they are used (build_gt takes the positions as given)
    spec.check(loops=len(srcs) == 1 if loops is None else loops, sessions=len(srcs))
    own = [input_spec(spec, k, len(srcs)) for k in range(len(srcs))]
    if len(srcs) > 1 and len(spec.files) == 1 and spec.keyword is None:
        _check_alike(srcs, spec.files[0])
    read = []
    for src, role, mine in zip(srcs, roles, own, strict=True):
        file = None if mine.topic is not None else mine.files[0]
        read.append(frame_positions(src, mine, file, role, single=len(srcs) == 1, topic=mine.topic))
    # GPS in metres about one origin for every source (each bag's own first fix would shift one traverse)
    if origin is None:
        origin = next((tuple(float(a) for a in v[~np.isnan(v).any(axis=1)][0]) for v, kind, _ in read
                       if kind == "latlon" and not np.isnan(v).all()), None)
    out = Positions()
    out.origin = origin
    for src, role, (values, kind, note) in zip(srcs, roles, read, strict=True):
        xy = np.asarray(values, np.float64)
        if kind == "latlon":
            xy = np.where(np.isnan(xy), np.nan, tr.latlon_to_metres(xy[:, 0], xy[:, 1], origin))
        idx = np.asarray(src.indices(), np.int64)
        known = ~np.isnan(xy).any(axis=1)
        if not known.all():
            if not known.any():
                raise ValueError(f"{role} {src.path}: none of its {idx.size} frames has a position ({note})")
            what = ("left out, since --every samples by travel" if every is not None else
                    "the method sees them as every frame, and their pairs are left out of the metrics")
            warnings.warn(f"{role} {src.path}: {int((~known).sum())} of {idx.size} frames have no position "
                          f"({note}); not extrapolated: {what}", UserWarning, stacklevel=2)
        if every is not None:
            keep = tr.every(xy, every)
            src.restrict(idx[keep])
            idx, xy = idx[keep], xy[keep]
        out.append(xy)
    return out


def same_sampling(the_map, every: float | None, positions: bool, where: str, progress: bool = False):
    """A map (:class:`vpr.maps.Map`) and a query's ``--every`` made to agree; returns (map, query's every).

    The sequence evidence follows a query that moves about one map frame per query frame; a query sampled coarser than
    the map moves several, and its decisions lose their precision. A query ``--every`` coarser than the map's
    sampling: the map is learned again at it (``Map.subset``); a map learned ``--every D`` and a query with
    ``positions``: the query is sampled so too. Each is said (``where``: the map's path); where neither can be done,
    the difference is said.
    """
    map_every, spacing = the_map.info.get("every"), the_map.spacing()
    said = None
    if every is not None and map_every != every:
        if spacing is None:
            said = (f"the map has no positions, so its sampling is unknown; a query one frame per {every:g} m keeps "
                    "its precision only if the map was sampled alike")
        elif spacing < every / 1.5 and the_map.sdr is None:
            said = (f"the map was learned every {spacing:.2g} m of travel and the query comes every {every:g} m, but "
                    f"the map holds no SDRs to learn it again so: learn it again (vpr learn --every {every:g}m), or "
                    "its decisions lose their precision")
        elif spacing < every / 1.5:
            keep = tr.every(the_map.positions, every)
            said = (f"the map was learned every {spacing:.2g} m of travel and the query comes every {every:g} m: the "
                    f"map is learned again one frame per {every:g} m ({keep.size} of {the_map.localizer.n_db} "
                    "frames), so that its sequences follow the query's")
            the_map = the_map.subset(keep, progress)
    elif every is None and map_every is not None and positions:
        said = f"the map was learned one frame per {map_every:g} m of travel: the query is sampled so too " \
               f"(--every {map_every:g}m)"
        every = map_every
    elif every is None and map_every is not None:
        said = (f"the map was learned one frame per {map_every:g} m of travel and the query's frames are taken as "
                f"they come: give the query --every {map_every:g}m with its positions (--gt-topic, --gt), or its "
                "decisions lose their precision")
    if said:
        warnings.warn(f"{where}: {said}", UserWarning, stacklevel=2)
    return the_map, every


def same_rate(the_map, src, fps: float | None, where: str, progress: bool = False):
    """A map and a query at different frame rates made to agree; returns (map, fps to read the query at).

    Without ``--every``, a query whose frames come :data:`RATE_RATIO` or more times slower than the map's: the map is
    learned again at the query's rate (every k-th frame of each session). A query that comes faster is read at the
    map's rate where its source can be (that fps returned, else None). Each is said (``where``: the map's path). The
    same speed is assumed.
    """
    map_rate, rate, can_resample = the_map.info.get("rate"), src.rate(), fps is None and "fps" in src.options
    if not map_rate or not rate or the_map.info.get("every") is not None:
        return the_map, None
    said, fps = None, None
    head = f"the map's frames came at {map_rate:.3g} per second and the query's come at {rate:.3g}"
    if map_rate >= rate * RATE_RATIO:
        k = int(map_rate / rate + 0.5)
        if the_map.sdr is None:
            said = (f"{head}, but the map holds no SDRs to learn it again so: learn it again with --fps {rate:.3g}, "
                    "or its decisions lose their precision")
        else:
            keep = the_map.localizer.every(k)
            said = (f"{head}: the map is learned again from one frame in {k} ({keep.size} of "
                    f"{the_map.localizer.n_db}), so that its sequences follow the query's")
            the_map = the_map.subset(keep, progress)
            the_map.info["rate"] = map_rate / k
    elif rate >= map_rate * RATE_RATIO:
        if can_resample:
            fps = float(map_rate)
            said = f"{head}: the query is read at the map's rate (--fps {fps:.3g})"
        else:
            said = (f"{head}: read the query at the map's rate (--fps {map_rate:.3g} on a video or bag), or its "
                    "decisions lose their precision")
    if said:
        warnings.warn(f"{where}: {said}", UserWarning, stacklevel=2)
    return the_map, fps


def check_speeds(speeds: Mapping[str, float | None], paths: str = "accepted paths", fix: str | None = None) -> None:
    """Warn for each method (``speeds``: method -> :func:`vpr.evaluate.path_speed`, metrics.json's ``path_speed``)
    whose ``paths`` move :data:`RATE_RATIO` or more times faster or slower than one frame a frame
    (:func:`speed_step`): the query was driven at another speed than the frames it is matched to, which the evidence
    does not expect; the warning names ``fix``, by default the sampling that makes them agree."""
    for label, v in speeds.items():
        k = speed_step(v)
        if k:
            then = fix or (f"learn the map from one frame in {k} (vpr learn DB --step {k}) and localise against it"
                           if k > 0 else f"localise one query frame in {-k} against a learned map (--step {-k})")
            warnings.warn(f"{label}: along its {paths} the query moves {v:.2g} of the frames it matches a "
                          f"frame: driven {'faster' if v > 1 else 'slower'} than they were at the same frame rate, its "
                          f"answers may trail the place; {then} (research/docs/localize.md)", UserWarning, stacklevel=2)


def runs_backwards(reversed_frames: int, accepted: int, frames: int) -> bool:
    """Whether a query runs the map backwards: it is localised so (metrics.json ``reversed_frames``) at more than
    half of its ``frames`` (those decided so far) and at more frames than it is accepted along the map. The one rule
    of every command that says it, batch and online."""
    return int(reversed_frames) > int(accepted) and 2 * int(reversed_frames) > int(frames)


def check_reversed(counts: Mapping[str, tuple[int, int]], frames: int) -> None:
    """Warn for each method (``counts``: method -> (frames localised running the map backwards, metrics.json's
    ``reversed_frames``; frames accepted)) whose query of ``frames`` runs the map backwards (:func:`runs_backwards`):
    those frames are not accepted."""
    for label, (n, accepted) in counts.items():
        if runs_backwards(n, accepted, frames):
            warnings.warn(f"{label}: the query runs the map backwards ({n} frames localised so, {accepted} accepted "
                          "along it): those frames' answers are not accepted (the sequence evidence follows the map's "
                          "direction; docs/internals.md, vpr/shosm/decide.py)", UserWarning, stacklevel=2)


def check_rates(srcs, every: float | None = None, against_first: bool = False) -> None:
    """Warn when the sources' frame rates (where they have times) are :data:`RATE_RATIO` or more apart and frames
    are not chosen by travel (``every``): a sequence of one moves several frames per frame of the other.
    ``against_first``: each source against the first (queries against a database), else all together (sessions)."""
    if every is not None:
        return
    for group in ([srcs[0], s] for s in srcs[1:]) if against_first else [srcs]:
        _check_rates(group)


def _check_rates(srcs) -> None:
    rates = [(s, r) for s, r in ((s, s.rate()) for s in srcs) if r]
    if len(rates) < 2:
        return
    (slow, lo), (fast, hi) = min(rates, key=lambda x: x[1]), max(rates, key=lambda x: x[1])
    if hi >= lo * RATE_RATIO:
        warnings.warn(f"{fast.path} comes at {hi:.3g} frames per second and {slow.path} at {lo:.3g}: a sequence of "
                      f"one moves {hi / lo:.2g} frames per frame of the other, and decisions lose their precision; "
                      f"read them alike (--fps {lo:.3g}) or one frame per so many metres (--every)",
                      UserWarning, stacklevel=2)
