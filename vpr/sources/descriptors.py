"""Global descriptors computed elsewhere (NetVLAD, MixVPR, SALAD, ...) as a source: one frame per row.

A ``.npy`` of N x D numbers (frames named ``000000``, ``000001``, ...), or hloc's global-feature ``.h5``
(``/<image name>/global_descriptor``, the names kept, in natural order as a folder's); a folder of the file's name
beside it (``db.npy`` and ``db/``) holding the images names the frames and shows them on the report page. Each
frame's "image" is its descriptor row: the ``descriptors`` encoder sparsifies them, ``seqslam-desc`` and ``pairwise``
read them as they are. Read without executing anything (no pickle); a file that is not N x D finite numbers is
refused naming what is wrong.
"""
from __future__ import annotations

import re
import warnings
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from .base import Frame, Source, natural_key, stat_token

__all__ = ["DescriptorSource", "read_descriptors", "DESCRIPTOR_EXTENSIONS", "is_descriptor_file", "names_carry_order",
           "ORDER_FILE", "ORDER_NAMES"]

DESCRIPTOR_EXTENSIONS = (".npy", ".h5", ".hdf5")


def is_descriptor_file(path) -> bool:
    """Whether ``path`` names a descriptor file (by its suffix)."""
    return Path(path).suffix.lower() in DESCRIPTOR_EXTENSIONS


#: how a descriptor file orders its frames (:attr:`DescriptorSource.order`)
ORDER_FILE, ORDER_NAMES = "file", "names"

#: the varying part of a frame name that carries an order: a number, a timestamp or a date (digits and separators)
_ORDERED = re.compile(r"[\d._:-]*\d[\d._:-]*")


def names_carry_order(names) -> bool:
    """Whether frame names carry the frames' order: what varies between them, once their common beginning and end are
    taken off, is a number, a timestamp or a date (``img_00012``, ``1403636579763555584``), not a hash or a place
    (``3fa9c2e1``, ``@0543256.96@4178906.70@...``)."""
    names = [n.rsplit("/", 1)[-1] for n in names]
    if len(names) < 2:
        return True
    stems = [n[: -len(Path(n).suffix)] if Path(n).suffix else n for n in names]
    lead = len(_common_prefix(stems))
    tail = len(_common_prefix([t[::-1] for t in stems]))
    while lead and stems[0][lead - 1].isdigit():  # a number's digits that happen to be common stay in it
        lead -= 1
    while tail and stems[0][len(stems[0]) - tail].isdigit():
        tail -= 1
    return all(_ORDERED.fullmatch(t[lead: len(t) - tail] if tail else t[lead:]) for t in stems)


def _common_prefix(texts) -> str:
    first, last = min(texts), max(texts)
    k = 0
    while k < min(len(first), len(last)) and first[k] == last[k]:
        k += 1
    return first[:k]


#: the name of an N x D dataset of descriptors, one row a frame (not an image's keypoints or scores)
_DESCRIPTOR_NAME = re.compile(r"desc|feat|emb|vlad|global|vector", re.IGNORECASE)


def _tracked(group) -> list[str] | None:
    """The members of an HDF5 group in the order they were created, or None where the group keeps no such order."""
    import h5py

    names: list[str] = []
    try:
        group.id.links.iterate(lambda n: names.append(n.decode("utf-8", "surrogateescape")),
                               idx_type=h5py.h5.INDEX_CRT_ORDER)
    except (KeyError, ValueError, RuntimeError):
        return None
    return names


def _walk(group, prefix: str, found: list, ordered: list) -> None:
    """Every dataset under ``group`` as (path, dataset), in the groups' creation order where each keeps one
    (``ordered`` gets False where one does not)."""
    import h5py

    members = _tracked(group)
    if members is None:
        ordered.append(False)
        members = list(group.keys())
    for name in members:
        obj = group.get(name)
        path = f"{prefix}{name}"
        if isinstance(obj, h5py.Group):
            _walk(obj, path + "/", found, ordered)
        elif isinstance(obj, h5py.Dataset):
            found.append((path, obj))


def _hloc(path: Path) -> tuple[list[str], np.ndarray | list[np.ndarray], bool]:
    """(names, descriptors, whether the file keeps the frames' order) of an HDF5 descriptor file: hloc's
    ``/<image name>/global_descriptor`` (one row each), or one N x D dataset (frames named by their row)."""
    import h5py  # only descriptor files need it

    try:
        with h5py.File(path, "r") as f:
            datasets: list = []
            ordered: list[bool] = []
            _walk(f, "", datasets, ordered)
            hloc = [(n.rsplit("/", 1)[0], d) for n, d in datasets
                    if n.rsplit("/", 1)[-1] == "global_descriptor" and "/" in n]
            if hloc:
                return [n for n, _ in hloc], [np.asarray(d[()]) for _, d in hloc], all(ordered)
            matrices = [(n, d) for n, d in datasets if d.ndim == 2 and d.dtype.kind in "biuf"
                        and _DESCRIPTOR_NAME.search(n.rsplit("/", 1)[-1])]
            if len(matrices) == 1:
                a = np.asarray(matrices[0][1][()])
                return [f"{i:06d}" for i in range(a.shape[0])], a, True
            seen = ", ".join(f"/{n} {tuple(d.shape)} {d.dtype}" for n, d in datasets[:5]) or "no dataset"
    except OSError as e:
        raise ValueError(f"{path}: not a readable HDF5 file ({e})") from None
    more = f" and {len(datasets) - 5} more" if len(datasets) > 5 else ""
    why = "several N x D datasets of descriptors" if len(matrices) > 1 else \
        "no global_descriptor and no N x D dataset of descriptors"
    raise ValueError(f"{path}: {why} (found {seen}{more}); expected hloc's global features "
                     "(/<image name>/global_descriptor) or one N x D dataset of frames x dimensions named as "
                     "descriptors (global_descriptor, descriptors, features, embeddings ...)")


def read_descriptors(path, prefix: str | None = None) -> tuple[list[str], np.ndarray, str | None]:
    """(frame names, float32 descriptors N x D, how the frames are ordered) of a descriptor file.

    The order: :data:`ORDER_FILE` (a ``.npy``'s rows; an ``.h5`` written keeping the order its frames were created
    in, ``track_order=True``), :data:`ORDER_NAMES` (an ``.h5`` that keeps none, as hloc writes it: the frames in the
    natural order of their names) or None (neither: names that carry no order, :func:`names_carry_order`).
    ``prefix``: an ``.h5``'s frames whose names begin with it alone (hloc's ``db_prefix`` / ``query_prefix``).

    Raises
    ------
    FileNotFoundError
        No such file.
    ValueError
        Not a ``.npy`` of numbers or an hloc ``.h5``; empty; not N x D; descriptors of unequal length; a row with
        NaN or inf (the first rows named); no frame of ``prefix``.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no such descriptor file: {path}")
    if path.stat().st_size == 0:
        raise ValueError(f"{path}: an empty file (0 bytes), not descriptors")
    order: str | None = ORDER_FILE
    if path.suffix.lower() == ".npy":
        if prefix is not None:
            raise ValueError(f"{path}: a prefix picks frames of an .h5 by name; a .npy's frames have none")
        try:
            a = np.load(path, allow_pickle=False)
        except (ValueError, EOFError, OSError) as e:  # an object array (pickle) or a damaged file: never run
            raise ValueError(f"{path}: not a .npy of numbers ({_short(e)})") from None
        names = None
    else:
        names, rows, ordered = _hloc(path)
        if prefix is not None:
            keep = [k for k, n in enumerate(names) if n.startswith(prefix)]
            if not keep:
                raise ValueError(f"{path}: no frame name begins with {prefix!r} (names such as {names[0]!r})")
            names = [names[k] for k in keep]
            rows = [rows[k] for k in keep] if isinstance(rows, list) else rows[keep]
        if isinstance(rows, list):
            lengths = sorted({r.size for r in rows})
            if len(lengths) > 1:
                raise ValueError(f"{path}: descriptors of unequal length ({', '.join(map(str, lengths[:4]))})")
            a = np.stack([r.ravel() for r in rows])
        else:
            a = rows
        if not ordered:
            order = ORDER_NAMES if names_carry_order(names) else None
            at = sorted(range(len(names)), key=lambda k: natural_key(names[k]))
            names, a = [names[k] for k in at], a[at]
    if a.dtype.kind not in "biuf":
        raise ValueError(f"{path}: descriptors must be numbers, got dtype {a.dtype}")
    if a.ndim != 2 or not a.shape[0] or not a.shape[1]:
        raise ValueError(f"{path}: descriptors must be N x D (frames x dimensions), got shape {a.shape}")
    if names is None:
        names = [f"{i:06d}" for i in range(a.shape[0])]
    bad = np.flatnonzero(~np.isfinite(a).all(axis=1))
    if bad.size:
        raise ValueError(f"{path}: {bad.size} descriptor row(s) hold NaN or inf (frames "
                         f"{', '.join(names[i] for i in bad[:5])}{' ...' if bad.size > 5 else ''})")
    return names, np.ascontiguousarray(a, np.float32), order


def _short(e: Exception) -> str:
    """An exception's message on one line, cut at a word and said so where it is long."""
    text = " ".join(str(e).split())
    if len(text) <= 160:
        return text
    return text[:160].rsplit(" ", 1)[0] + " ..."


class DescriptorSource(Source):
    """The frames of a descriptor file, each frame's image its descriptor row (1-D float32)."""

    kind = "descriptors"
    has_images = False

    @classmethod
    def accepts(cls, path: Path) -> bool:
        return is_descriptor_file(path)

    options = frozenset({"step", "max_frames", "prefix"})

    def __init__(self, path, step=None, max_frames=None, prefix=None):
        super().__init__(path)
        self.all_names, self.rows, self.order = read_descriptors(self.path, prefix)
        self.prefix = prefix
        if prefix:
            self.name = f"{self.name}:{prefix.rstrip('/')}"
        if self.order == ORDER_NAMES:
            warnings.warn(f"{self.path}{f' ({prefix}*)' if prefix else ''}: the file keeps no order of its frames "
                          f"(hloc writes none): they are read in the natural order of their names ({self.all_names[0]}"
                          f" .. {self.all_names[-1]})", UserWarning, stacklevel=3)
        self.images = self._images_beside()
        picked = np.arange(len(self.all_names))[::int(step or 1)]
        self._picked = picked[:max_frames] if max_frames is not None else picked
        self.step, self.max_frames = step, max_frames

    def _images_beside(self) -> list[Path] | None:
        """The images of the folder beside the file, of its name without the suffix (``db.npy`` and ``db/``), one a
        row: they name the frames of a ``.npy``; an ``.h5``'s names must be theirs. None without such a folder; a
        count or a name that differs is refused."""
        folder = self.path.with_suffix("")
        if not folder.is_dir():
            return None
        from .files import FolderSource  # a folder's images, as a folder source lists them

        names = FolderSource(folder).names()
        if len(names) != len(self.all_names):
            raise ValueError(f"{self.path}: {len(self.all_names)} descriptors, but the folder beside it, {folder}, "
                             f"holds {len(names)} images")
        if self.path.suffix.lower() == ".npy":
            self.all_names = names
        else:
            missing = [n for n in self.all_names if n not in set(names)]
            if missing:
                raise ValueError(f"{self.path}: {len(missing)} descriptor names are not images of {folder} (first: "
                                 f"{missing[0]})")
        return [folder / n for n in self.all_names]

    def frame_paths(self) -> list[Path] | None:
        """The images beside the file (:meth:`_images_beside`) of the frames :meth:`indices` names, or None."""
        return None if self.images is None else [self.images[i] for i in self.indices()]

    @property
    def dim(self) -> int:
        """The descriptors' length."""
        return int(self.rows.shape[1])

    def names(self) -> list[str]:
        return [self.all_names[i] for i in self._picked if self._allowed(int(i))]

    def indices(self) -> list[int]:
        return [int(i) for i in self._picked if self._allowed(int(i))]

    def key(self) -> str:
        return (f"{stat_token(self.path.resolve())}|prefix={self.prefix}|step={self.step}|max={self.max_frames}|"
                f"{len(self.indices())}")

    def exact_total(self) -> int | None:
        return len(self.all_names)

    def _selected(self):
        return self.indices()

    def _frames(self, selection) -> Iterator[Frame]:
        for i in selection:
            yield Frame(int(i), self.all_names[i], self.rows[i])
