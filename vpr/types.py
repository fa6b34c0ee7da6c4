"""The types every floor shares: an encoded traverse in, a match result out."""
from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol

import numpy as np
import scipy.sparse as sp

if TYPE_CHECKING:
    from vpr.sdr import RowLog

__all__ = ["EncodedTraverse", "ImageInput", "Column", "Decision", "Decider", "QueryLocalizer", "MapLocalizer",
           "FollowingLocalizer", "LateLocalizer", "StreamDetector", "FrameEncoder", "MatchResult", "ENCODER_INPUTS",
           "RATE_RATIO"]

#: Inputs that come from the encoder (every other input is an :class:`ImageInput` of a method).
ENCODER_INPUTS = {"sdr": "SDRs", "desc": "dense descriptors"}

#: Frame rates or speeds this far apart (a ratio) make a sequence of one source move several frames per frame of the
#: other and can cost the decisions their recall or precision; made to agree from here (research/docs/localize.md,
#: "Frame
#: rates"; a loop closure's place, research/docs/loops.md).
RATE_RATIO = 1.5


@dataclass(frozen=True)
class ImageInput:
    """An input a method computes from the images itself: ``name`` (its key in :attr:`EncodedTraverse.inputs` and
    the cache), ``description``, and ``compute(images, name)`` -> float32 (frames x dims), a module-level function
    (shipped to Dask workers) whose errors name ``name[i]``.
    """

    name: str
    description: str
    compute: Callable


class EncodedTraverse:
    """An encoded traverse: one name per frame and, by name, what the methods read per frame.

    ``sdr``: an SDR batch; ``desc``: the encoder's float32 descriptors; ``**inputs``: further inputs
    (:class:`ImageInput`), None left out.
    """

    def __init__(self, names, sdr=None, desc=None, **inputs):
        self.names = list(names)
        self.inputs = {k: v for k, v in {"sdr": sdr, "desc": desc, **inputs}.items() if v is not None}
        for key, value in self.inputs.items():
            if value.shape[0] != len(self.names):
                raise ValueError(f"encoded traverse: input {key!r} has {value.shape[0]} rows for "
                                 f"{len(self.names)} frame names")

    @property
    def sdr(self) -> sp.csr_matrix | None:
        """The SDR batch, or None."""
        return self.inputs.get("sdr")

    @property
    def desc(self) -> np.ndarray | None:
        """The encoder's dense descriptors, or None."""
        return self.inputs.get("desc")

    def only(self, keys) -> EncodedTraverse:
        """The same frames with only the inputs ``keys`` (those held)."""
        return EncodedTraverse(self.names, **{k: v for k, v in self.inputs.items() if k in set(keys)})

    def slice(self, start: int, stop: int) -> EncodedTraverse:
        """Frames ``start:stop`` with every input (a block of a long traverse)."""
        return EncodedTraverse(self.names[start:stop], **{k: v[start:stop] for k, v in self.inputs.items()})

    def take(self, frames) -> EncodedTraverse:
        """The frames at the indices ``frames``, in that order, with every input."""
        frames = np.asarray(frames, np.int64)
        return EncodedTraverse([self.names[i] for i in frames], **{k: v[frames] for k, v in self.inputs.items()})

    @classmethod
    def from_parts(cls, parts, prefixes) -> EncodedTraverse:
        """The traverses ``parts`` one after the other (a robot's sessions as one stream), frame names prefixed
        with their part's ``prefixes`` (``day/0001.png``); the inputs every part holds."""
        names = [f"{p}/{n}" for p, t in zip(prefixes, parts, strict=True) for n in t.names]
        keys = set.intersection(*(set(t.inputs) for t in parts))
        inputs = {}
        for k in keys:
            arrays = [t.inputs[k] for t in parts]
            inputs[k] = sp.vstack(arrays).tocsr() if sp.issparse(arrays[0]) else np.concatenate(arrays)
        return cls(names, **inputs)

    def __len__(self) -> int:
        return len(self.names)

    def __repr__(self) -> str:
        held = ", ".join(f"{k}={getattr(v, 'shape', '?')}" for k, v in self.inputs.items())
        return f"EncodedTraverse({len(self)} frames, {held})"


@dataclass
class Column:
    """One frame's evidence over its ``n`` candidate frames ``0 .. n - 1``.

    ``rows``: the candidates with evidence (sorted), ``z`` their scores (float32, as a similarity matrix keeps them);
    every other candidate scores ``fill``. ``frame``: the frame the column belongs to (-1: not said).
    """

    rows: np.ndarray
    z: np.ndarray
    fill: float
    n: int
    frame: int = -1

    def best(self) -> tuple[int, float]:
        """(best candidate, its score), the smaller frame on ties; (-1, -inf) without evidence."""
        if not self.rows.size:
            return -1, float("-inf")
        k = int(np.argmax(self.z))
        return int(self.rows[k]), float(self.z[k])

    def top(self, k: int | None) -> tuple[np.ndarray, np.ndarray]:
        """The ``k`` candidates of most evidence (None: all with evidence) and their scores, best first."""
        order = np.lexsort((self.rows, -self.z.astype(np.float64)))[:k]
        return self.rows[order], self.z[order]

    def kept(self, k: int | None) -> Column:
        """The column cut to its ``k`` candidates of most evidence (None: itself); the others score ``fill``."""
        if k is None or self.rows.size <= k:
            return self
        rows, z = self.top(k)
        order = np.argsort(rows, kind="stable")
        return Column(rows[order], z[order], self.fill, self.n, self.frame)

    def dense(self) -> np.ndarray:
        """The scores of all ``n`` candidates."""
        out = np.full(self.n, self.fill, np.float32)
        out[self.rows] = self.z
        return out


@dataclass
class Decision:
    """What a decision says of a frame (scalar fields) or of every frame of a traverse (arrays).

    ``best``: the frame it matches (-1: none); ``score``: the decision's statistic; ``accepted``; ``margin``: how far
    the best place stood out of the others in this frame; ``frame``: the frame decided; ``column``: its evidence,
    where one frame was decided online; ``reversed``: the query runs the map backwards at this frame (not accepted).
    """

    best: int | np.ndarray
    score: float | np.ndarray
    accepted: bool | np.ndarray
    margin: float | np.ndarray = 0.0
    frame: int | np.ndarray = -1
    column: Column | None = None
    reversed: bool | np.ndarray = False

    @classmethod
    def stack(cls, decisions: Iterable[Decision]) -> Decision:
        """The decisions of single frames as one :class:`Decision` of arrays (in the order given)."""
        ds = list(decisions)
        return cls(np.array([d.best for d in ds], np.int64), np.array([d.score for d in ds], np.float64),
                   np.array([d.accepted for d in ds], bool), np.array([d.margin for d in ds], np.float64),
                   np.array([d.frame for d in ds], np.int64), reversed=np.array([d.reversed for d in ds], bool))


class Decider(ABC):
    """Decides a stream one frame at a time, from the frame's :class:`Column`, with the state the stream carries.

    Every decider implements :meth:`_decide`, :meth:`new_session`, :meth:`state` and :meth:`load_state`;
    :meth:`decide` checks the column and counts the frames; deciders that read the frames' SDRs override
    :meth:`add_sdr`. ``frames``: frames decided; ``starts``: each session's first frame; ``n_bits``: the width of
    the SDRs it reads (None: it reads none, or was not told).
    """

    frames: int = 0
    starts: np.ndarray
    n_bits: int | None = None

    @property
    @abstractmethod
    def accept_score(self) -> float:
        """The score at which this decider accepts (a second opinion ranks its own accepts with it)."""

    def decide(self, column: Column) -> Decision:
        """The decision of the frame whose evidence is ``column``."""
        if not isinstance(column, Column):
            raise TypeError(f"{type(self).__name__}.decide takes a Column, got {type(column).__name__}")
        d = self._decide(column)
        self.frames += 1
        return d

    @abstractmethod
    def _decide(self, column: Column) -> Decision:
        """The decision of one frame (``self.frames`` frames decided before it)."""

    @abstractmethod
    def new_session(self) -> None:
        """The next frame starts a new session: nothing of the last frames' path carries over."""

    def add_sdr(self, bits) -> None:  # noqa: B027 - a hook most deciders do not need
        """The next frame's active bits (sorted), given before its column, for deciders that read them."""

    @property
    def rows(self) -> RowLog | None:
        """The SDR rows of the frames given so far (:meth:`add_sdr`) where this decider keeps them; None: it keeps
        none."""
        return None

    @property
    def pair_verified(self) -> bool:
        """Whether the frame decided last was accepted on the evidence of its own pair of frames (a second opinion's
        geometry, or its tracking of a path it confirmed), which the frames after it need not confirm; False: on the
        sequence's evidence, or not accepted."""
        return False

    @abstractmethod
    def state(self) -> tuple[dict, dict]:
        """(header, arrays) after the frames decided so far; :meth:`load_state` continues from them."""

    @abstractmethod
    def load_state(self, header: dict, arrays: dict) -> Decider:
        """Continue from a :meth:`state`; returns self."""


class QueryLocalizer(Protocol):
    """Answers a query stream frame by frame against a learned map (:class:`MapLocalizer`,
    :class:`FollowingLocalizer`)."""

    def update(self, sdr_row) -> Decision:
        """The next query frame's decision (an SDR row: 1-row batch, dense row or bit indices)."""

    def reset(self) -> None:
        """A new query traverse: nothing of the last frames carries over."""

    def warm_up(self) -> None:
        """Compile (or load) the kernels now, so that the first frame's latency is its own."""


class MapLocalizer(ABC):
    """What a map holds (``vpr learn``, ``vpr localize``): a database learned by a method that runs online, answering
    a query stream frame by frame. Handed out by the method (``Method.localizer``) and read again from a map file by
    it (``Method.restore_localizer``).

    ``names``: the database frames' names; ``conf``: the whole conf (recorded in metrics.json); ``sessions``: each map
    session's first frame; ``frames``: the query frames read since the last :meth:`reset` (a saved state's included).
    """

    names: list[str]
    conf: dict
    sessions: np.ndarray
    frames: int

    @property
    def n_db(self) -> int:
        return len(self.names)

    @property
    @abstractmethod
    def top_k(self) -> int | None:
        """The database frames an answer lists (None: every frame with evidence)."""

    @abstractmethod
    def update(self, sdr_row) -> Decision:
        """The next query frame's decision (an SDR row: 1-row batch, dense row or bit indices)."""

    @abstractmethod
    def reset(self) -> None:
        """A new query traverse: nothing of the last frames carries over."""

    @abstractmethod
    def warm_up(self) -> None:
        """Compile (or load) the kernels now, so that the first frame's latency is its own."""

    @abstractmethod
    def reconfigure(self, **conf) -> MapLocalizer:
        """This map with other query-time settings, continuing its state (ValueError for a setting the map fixed)."""

    @abstractmethod
    def every(self, k: int, phase: int = 0) -> np.ndarray:
        """The frame numbers of one map frame in ``k`` of each session, from the session's frame ``phase`` on."""

    @abstractmethod
    def relearned(self, db_sdr, keep, progress: bool = False) -> MapLocalizer:
        """A localizer of the same conf learned from the map frames numbered ``keep`` alone (their SDRs
        ``db_sdr[keep]``)."""

    @abstractmethod
    def map_state(self) -> tuple[dict, dict[str, dict]]:
        """(header, parts: name -> arrays) of what was learned and of the query so far, for a map file; part names
        other than ``enc``, ``qenc``, ``db`` and ``follow``."""


class FollowingLocalizer(ABC):
    """Answers a query stream over a :class:`MapLocalizer`, following a query driven at another speed than the map
    (handed out by ``Method.follower``). ``mode``: +1 while a faster query is followed, -1 a slower, 0 at the map's
    speed; ``step``: the sampling k it follows at; ``follows_faster``: whether a faster one can be followed."""

    mode: int
    step: int

    @property
    @abstractmethod
    def follows_faster(self) -> bool: ...

    @abstractmethod
    def update(self, sdr_row) -> Decision: ...

    @abstractmethod
    def reset(self) -> None: ...

    @abstractmethod
    def warm_up(self) -> None: ...

    @abstractmethod
    def sampling(self) -> dict | None:
        """metrics.json's ``sampling`` of the frames so far (None: every frame as it came)."""

    @abstractmethod
    def state(self) -> tuple[dict, dict]:
        """(header, arrays) of what it carries besides the map's localizer."""

    @abstractmethod
    def load_state(self, header: dict, arrays: dict) -> FollowingLocalizer:
        """Continue from a :meth:`state`; returns self."""


class LateLocalizer(ABC):
    """Answers a query stream over a :class:`MapLocalizer` (or its :class:`FollowingLocalizer`) ``lag`` frames late,
    each frame with the evidence of the frames after it (handed out by ``Method.late``). ``waiting``: the frames
    read, not yet answered, oldest first."""

    lag: int
    waiting: list

    @abstractmethod
    def update(self, sdr_row) -> list[Decision]:
        """Read the next query frame; the decisions now due (of earlier frames, in order)."""

    @abstractmethod
    def flush(self) -> list[Decision]:
        """The decisions of the frames still waiting (the stream ended), each with the frames there are after it."""

    @abstractmethod
    def reset(self) -> list[Decision]:
        """A new query traverse: the frames waiting are decided first (returned), then nothing carries over."""

    @abstractmethod
    def warm_up(self) -> None: ...

    @abstractmethod
    def state(self) -> tuple[dict, dict]:
        """(header, arrays) of what it carries besides what answers at once (the frames waiting)."""

    @abstractmethod
    def load_state(self, header: dict, arrays: dict) -> LateLocalizer:
        """Continue from a :meth:`state`; returns self."""


class StreamDetector(ABC):
    """Loop closure within one stream, online, one frame at a time (``vpr loops -``): handed out by a method that runs
    online (``Method.loop_detector``) and read again from its saved state (``Method.resume_loop_detector``).

    ``names``: the frames' names so far; ``encoder``: the :class:`FrameEncoder` of its images (None: SDR rows);
    ``conf``: the whole conf with ``exclude`` (recorded in metrics.json); ``meta``: caller metadata :meth:`save`
    stores (``method``, ``encoder``, ``encoder_conf``, ...).
    """

    names: list[str]
    encoder: FrameEncoder | None
    conf: dict
    meta: dict

    @property
    def frames(self) -> int:
        """Frames given so far (those before a resume too)."""
        return len(self.names)

    @property
    @abstractmethod
    def starts(self) -> list[int]:
        """Each session's first frame."""

    @property
    @abstractmethod
    def waiting(self) -> int:
        """Frames given whose answers wait in the detector (for the frames after a closure)."""

    @property
    @abstractmethod
    def top_k(self) -> int | None:
        """The earlier frames an answer lists (None: every frame with evidence)."""

    @abstractmethod
    def warm_up(self) -> None: ...

    @abstractmethod
    def update_encoded(self, rows, name: str | None = None) -> Decision | None:
        """The next frame, given what its encoder's ``push`` returned for it; None while its answer waits."""

    @abstractmethod
    def take_late(self) -> list[Decision]:
        """The answers of earlier frames decided since the last call, in frame order."""

    @abstractmethod
    def flush(self, closures: bool = True) -> None:
        """The stream ends (``closures``) or pauses for a save (not ``closures``): decide what can be."""

    @abstractmethod
    def new_session(self) -> None:
        """The next frame starts a new run of the robot."""

    @abstractmethod
    def save(self, path):
        """Write the detector's state, its encoder's and :attr:`meta` (one atomic file)."""

    def opinion_report(self) -> dict | None:
        """What a second opinion on its closures did (metrics.json's ``geometry``), or None without one."""
        return None


class FrameEncoder(ABC):
    """Encodes a stream's images one at a time into SDR rows, some frames possibly waiting for later ones (causal
    standardisation), with a state a restart continues."""

    @property
    @abstractmethod
    def delay(self) -> int:
        """Frames a frame may wait for its SDR."""

    @property
    @abstractmethod
    def waiting(self) -> int:
        """Frames pushed whose SDRs have not been given yet."""

    @abstractmethod
    def push(self, image) -> sp.csr_matrix:
        """The SDR rows of the frames now ready, in order (0 or more)."""

    @abstractmethod
    def flush(self) -> sp.csr_matrix:
        """The SDR rows of the frames still waiting (a stream that ends)."""

    @abstractmethod
    def new_session(self) -> sp.csr_matrix:
        """A new run starts: the rows of the frames still waiting; nothing of the last run's statistics goes on."""

    @abstractmethod
    def state(self) -> tuple[dict, dict]:
        """(header, arrays) that :meth:`load_state` continues from."""

    @abstractmethod
    def load_state(self, header: dict, arrays: dict) -> FrameEncoder:
        """Continue from a :meth:`state`; returns self."""


@dataclass
class MatchResult:
    """Database x query similarity (dense, or top-K sparse), best database frame per query, its score,
    the accept decision, the matching time in seconds and the conf used.

    ``best`` is -1 (score ``-inf``) for a query without any candidate.
    """

    method: str
    similarity: np.ndarray | sp.csr_matrix
    best: np.ndarray
    score: np.ndarray
    accepted: np.ndarray
    seconds: float
    conf: dict = field(default_factory=dict)
    #: how the result was matched when the query was driven at another speed than the database
    #: (:func:`vpr.methods.match_at_speed`): ``{"speed": first pass's path speed, "db_step" or "query_step": k}``
    #: (and ``"db_apart"``: frames the maps placed apart, undecided; or ``"query_apart"``: frames the queries placed
    #: apart from the frames around them, undecided, and ``"query_filled"``: a slower query's frames placed between
    #: accepted ones); None: every frame as it came
    sampling: dict | None = None
    #: query frames at which the query runs the map backwards (:attr:`Decision.reversed`: not accepted)
    reversed: int = 0

    @classmethod
    def from_decisions(cls, method: str, decisions, n_rows: int, top_k: int | None, seconds: float,
                       conf: dict | None = None) -> MatchResult:
        """The result of frames decided one at a time (online): each decision's column, its ``top_k`` candidates
        (None: all with evidence), as a column of the top-K sparse similarity (``n_rows`` candidates x the
        decisions, in the order given); its best (-1 and score ``-inf`` without a candidate) and acceptance."""
        ds = list(decisions)
        best = np.array([d.best for d in ds], np.int64)
        score = np.array([d.score for d in ds], np.float64)
        score = np.where(np.isfinite(score) & (best >= 0), score, -np.inf)
        cand = [d.column.top(top_k) if d.column is not None else (np.zeros(0, np.int64), np.zeros(0, np.float32))
                for d in ds]
        ptr = np.r_[0, np.cumsum([c.size for c, _ in cand])]
        S = sp.csc_matrix((np.concatenate([z for _, z in cand] + [np.zeros(0, np.float32)]).astype(np.float32),
                           np.concatenate([c for c, _ in cand] + [np.zeros(0, np.int64)]).astype(np.int64), ptr),
                          shape=(int(n_rows), len(ds))).tocsr()
        return cls(method, S, best, score, np.array([d.accepted for d in ds], bool), seconds, dict(conf or {}),
                   reversed=sum(bool(d.reversed) for d in ds))
