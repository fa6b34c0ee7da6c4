"""Global descriptors computed elsewhere (NetVLAD, MixVPR, SALAD, ...) as a source: one frame per row.

A ``.npy`` of N x D numbers (frames named ``000000``, ``000001``, ...), or hloc's global-feature ``.h5``
(``/<image name>/global_descriptor``, the names kept, in natural order as a folder's); a folder of the file's name
beside it (``db.npy`` and ``db/``) holding the images names the frames and shows them on the report page. Each
frame's "image" is its descriptor row: the ``descriptors`` encoder sparsifies them, ``seqslam-desc`` and ``pairwise``
read them as they are. Read without executing anything (no pickle); a file that is not N x D finite numbers is
refused naming what is wrong.
"""
from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np

from .base import Frame, Source, natural_key, stat_token

__all__ = ["DescriptorSource", "read_descriptors", "DESCRIPTOR_EXTENSIONS", "is_descriptor_file"]

DESCRIPTOR_EXTENSIONS = (".npy", ".h5", ".hdf5")


def is_descriptor_file(path) -> bool:
    """Whether ``path`` names a descriptor file (by its suffix)."""
    return Path(path).suffix.lower() in DESCRIPTOR_EXTENSIONS


def _hloc(path: Path) -> tuple[list[str], list[np.ndarray]]:
    import h5py  # only descriptor files need it

    found: list[tuple[str, np.ndarray]] = []

    def visit(name, obj):
        if isinstance(obj, h5py.Dataset) and name.rsplit("/", 1)[-1] == "global_descriptor":
            found.append((name.rsplit("/", 1)[0] if "/" in name else "", np.asarray(obj[()])))

    try:
        with h5py.File(path, "r") as f:
            f.visititems(visit)
    except OSError as e:
        raise ValueError(f"{path}: not a readable HDF5 file ({e})") from None
    if not found:
        raise ValueError(f"{path}: no global_descriptor in it (hloc global features: /<image name>/global_descriptor)")
    found.sort(key=lambda item: natural_key(item[0]))
    return [n for n, _ in found], [d for _, d in found]


def read_descriptors(path) -> tuple[list[str], np.ndarray]:
    """(frame names, float32 descriptors N x D) of a descriptor file.

    Raises
    ------
    FileNotFoundError
        No such file.
    ValueError
        Not a ``.npy`` of numbers or an hloc ``.h5``; empty; not N x D; descriptors of unequal length; a row with
        NaN or inf (the first rows named).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no such descriptor file: {path}")
    if path.suffix.lower() == ".npy":
        try:
            a = np.load(path, allow_pickle=False)
        except ValueError as e:  # an object array (pickle) or a damaged file: never run
            raise ValueError(f"{path}: not a .npy of numbers ({' '.join(str(e).split())[:120]})") from None
        names = None
    else:
        names, rows = _hloc(path)
        lengths = sorted({r.size for r in rows})
        if len(lengths) > 1:
            raise ValueError(f"{path}: descriptors of unequal length ({', '.join(map(str, lengths[:4]))})")
        a = np.stack([r.ravel() for r in rows])
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
    return names, np.ascontiguousarray(a, np.float32)


class DescriptorSource(Source):
    """The frames of a descriptor file, each frame's image its descriptor row (1-D float32)."""

    kind = "descriptors"
    has_images = False

    @classmethod
    def accepts(cls, path: Path) -> bool:
        return is_descriptor_file(path)

    def __init__(self, path, step=None, max_frames=None):
        super().__init__(path)
        self.all_names, self.rows = read_descriptors(self.path)
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
        return f"{stat_token(self.path.resolve())}|step={self.step}|max={self.max_frames}|{len(self.indices())}"

    def exact_total(self) -> int | None:
        return len(self.all_names)

    def _selected(self):
        return self.indices()

    def _frames(self, selection) -> Iterator[Frame]:
        for i in selection:
            yield Frame(int(i), self.all_names[i], self.rows[i])
