"""Nordland frames: locate the dataset, list the aligned frames, load and cache descriptors."""
from __future__ import annotations

import hashlib
import os
from pathlib import Path

import cv2
import numpy as np

from vpr import io as _io
from vpr.imageproc import seqslam_descriptors

__all__ = ["DATASETS_ENV", "DEFAULT_DATA", "SUBSETS", "DatasetError", "find_dataset", "frame_names", "load_images",
           "pixel_descriptors"]

#: Environment variable naming the folder that holds ``nordland_trimmed/``.
DATASETS_ENV = "VPR_DATASETS"
#: Dataset folder name inside ``$VPR_DATASETS``.
DATASET_NAME = "nordland_trimmed"
_CHECKOUT = Path(__file__).resolve().parents[2]
#: Last fallback, only when running from a source checkout: ``../shared/datasets`` next to the repository.
DEFAULT_DATA = _CHECKOUT.parent / "shared" / "datasets" / DATASET_NAME
#: Subset name -> step through the sorted file list (every 10th file: OpenSeqSLAM's demo subset).
SUBSETS = {"358": 10, "full": 1}
SEASONS = ("summer", "winter")


class DatasetError(ValueError):
    """The dataset folder is missing or inconsistent."""


def candidate_roots(data=None) -> list[Path]:
    """Where the dataset is looked for, in order: ``data``; else ``$VPR_DATASETS/nordland_trimmed``, then
    (source checkout only) :data:`DEFAULT_DATA`."""
    if data is not None:
        return [Path(data)]
    roots = []
    env = os.environ.get(DATASETS_ENV)
    if env:
        roots.append(Path(env) / DATASET_NAME)
    if (_CHECKOUT / "pyproject.toml").is_file():
        roots.append(DEFAULT_DATA)
    return roots


def find_dataset(data=None) -> Path:
    """The dataset root (a folder with ``summer/`` and ``winter/``), checked; see :func:`candidate_roots`.

    Raises
    ------
    DatasetError
        No candidate holds both seasons; the message says where it looked.
    """
    roots = candidate_roots(data)
    for root in roots:
        if all((root / s).is_dir() for s in SEASONS):
            return root
    looked = "; ".join(f"{', '.join(str(r / s) for s in SEASONS)}" for r in roots) or "nowhere"
    hint = ""
    if data is None:
        hint = f" (${DATASETS_ENV} is {'set' if os.environ.get(DATASETS_ENV) else 'unset'})"
    raise DatasetError(f"Nordland dataset not found: looked for {looked}{hint} (pass --data PATH to the folder "
                       f"holding summer/ and winter/, or set {DATASETS_ENV} to the folder holding {DATASET_NAME}/)")


def frame_names(root: Path, subset: str) -> list[str]:
    """File names present in both seasons, sorted, every ``SUBSETS[subset]``-th one.

    Raises
    ------
    DatasetError
        Unknown subset, no images, or the seasons' file names differ (frames must be aligned).
    """
    if subset not in SUBSETS:
        raise DatasetError(f"subset must be one of {sorted(SUBSETS)}, got {subset!r}")
    names = {s: sorted(p.name for p in (root / s).iterdir() if p.suffix.lower() in (".png", ".jpg", ".jpeg"))
             for s in SEASONS}
    if not names["summer"]:
        raise DatasetError(f"no images in {root / 'summer'}")
    if names["summer"] != names["winter"]:
        only = sorted(set(names["summer"]) ^ set(names["winter"]))[:5]
        raise DatasetError(f"{root}: summer/ and winter/ hold different file names (e.g. {only}); "
                           f"frames must be aligned by name")
    return names["summer"][:: SUBSETS[subset]]


def load_images(folder: Path, names: list[str]) -> list[np.ndarray]:
    """Read the named images with OpenCV (BGR uint8); a file that cannot be read is an error naming it."""

    out = []
    for n in names:
        img = cv2.imread(str(folder / n), cv2.IMREAD_COLOR)
        if img is None:
            raise DatasetError(f"cannot read image {folder / n}")
        out.append(img)
    return out


def pixel_descriptors(root: Path, season: str, names: list[str], cache_dir: Path | None = None,
                      progress: bool = False) -> np.ndarray:
    """OpenSeqSLAM's patch-normalised 64x32 thumbnails (frames x 2048, float32), cached.

    The cache file name carries a hash of the dataset path, the season and the
    file list, so a different subset or dataset never reads a stale cache.
    """
    key = hashlib.sha1("\n".join([str(root.resolve()), season, *names]).encode()).hexdigest()[:12]
    path = None if cache_dir is None else Path(cache_dir) / f"pixel_{season}_{len(names)}_{key}.npy"
    if path is not None and path.exists():
        desc = np.load(path)
        if desc.shape == (len(names), 2048):
            return desc
    chunks = []
    it = range(0, len(names), 512)
    if progress:
        from tqdm import tqdm  # only for the progress bar

        it = tqdm(it, desc=f"describe {season}", unit="chunk", leave=False)
    for i in it:
        chunks.append(seqslam_descriptors(load_images(root / season, names[i:i + 512]), name=season))
    desc = np.concatenate(chunks).astype(np.float32)
    if path is not None:
        _io.save_npy(path, desc)
    return desc
