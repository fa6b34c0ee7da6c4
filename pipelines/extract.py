"""Encoding stage: stream a source through an encoder, with an on-disk cache.

Frames are read in batches (never all images at once); what is kept per frame
is only what the methods need: the SDR row, the encoder's dense descriptor,
SeqSLAM's 64x32 patch-normalised pixels and, for geometric verification, a
grey thumbnail. Results are cached in ``cache_dir`` (``vpr match --out DIR``
uses ``DIR/cache``; ``vpr encode --cache DIR`` fills any folder ahead of time)
in one file per source and encoder conf, so a second run with another method
skips encoding (as hloc's extractors skip work done).

The work is split into frame ranges of the source (:func:`chunk_ranges`):
:func:`encode_chunk` reads and describes one range, :func:`assemble` joins the
ranges in order and fits and encodes the whole traverse. :func:`extract` runs
the chunks one after the other; ``pipelines.encode`` runs them on Dask workers.
Both write the same bytes, because the chunks are the same and everything that
depends on the whole traverse happens in :func:`assemble`.
"""
from __future__ import annotations

import hashlib
import json
import time
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from vpr import imageproc, io
from vpr.methods import EncodedTraverse
from vpr.sources import Source

__all__ = ["Extracted", "Chunk", "extract", "cache_key", "cache_path", "chunk_ranges", "encode_chunk", "assemble",
           "load_cache", "save_cache", "PARTS", "DEFAULT_CHUNK_FRAMES"]

# v2: one file per source + encoder conf holding any subset of PARTS, no timings (byte-reproducible)
CACHE_VERSION = 2
THUMB_MAX_SIDE = 640
#: What a cache file can hold per frame: SDR rows, the encoder's dense descriptor, SeqSLAM pixels.
PARTS = ("sdr", "desc", "pixels")
#: Frames per unit of work. Part of what the cache bytes depend on only for encoders whose
#: descriptor depends on the batch (e.g. cnn with batch_size > 1); all chunkings agree otherwise.
DEFAULT_CHUNK_FRAMES = 256


@dataclass
class Extracted:
    features: EncodedTraverse
    skipped: list = field(default_factory=list)
    ignored: int = 0
    seconds: float = 0.0
    cached: bool = False
    thumbs: list | None = None
    indices: list | None = None


@dataclass
class Chunk:
    """What one frame range of a source gives: the unit of (parallel) work.

    ``sdr`` is only set for encoders without a dense descriptor; the others are
    sparsified in :func:`assemble`, after fitting on the whole traverse.
    """

    start: int
    stop: int
    names: list
    indices: list
    skipped: list
    desc: np.ndarray | None = None
    sdr: sp.csr_matrix | None = None
    pixels: np.ndarray | None = None
    thumbs: list | None = None


def _projected(encoder) -> bool:
    return hasattr(encoder, "encode_descriptors") and hasattr(encoder, "fit_descriptors")


def _check_parts(parts) -> tuple[str, ...]:
    parts = tuple(parts)
    bad = [p for p in parts if p not in PARTS]
    if bad:
        raise ValueError(f"unknown part(s) {bad}; available: {', '.join(PARTS)}")
    return tuple(p for p in PARTS if p in parts)


def _needs(need_sdr: bool, need_desc: bool, need_pixels: bool) -> tuple[str, ...]:
    return tuple(p for p, need in zip(PARTS, (need_sdr, need_desc, need_pixels), strict=True) if need)


def cache_key(source: Source, encoder) -> str:
    """16 hex digits naming the source's content and selection and the encoder's full conf."""
    payload = json.dumps({"v": CACHE_VERSION, "source": source.key(), "encoder": encoder.name,
                          "conf": encoder.conf}, sort_keys=True, default=str)
    return hashlib.sha1(payload.encode()).hexdigest()[:16]


def cache_path(cache_dir, source: Source, encoder) -> Path:
    """The cache file of ``source`` encoded by ``encoder`` in ``cache_dir``."""
    return Path(cache_dir) / f"{source.name}-{encoder.name}-{cache_key(source, encoder)}.npz"


def chunk_ranges(n_frames: int, chunk_frames: int = DEFAULT_CHUNK_FRAMES) -> list[tuple[int, int]]:
    """``[(0, c), (c, 2c), ...]`` covering ``n_frames`` positions."""
    if isinstance(chunk_frames, bool) or not isinstance(chunk_frames, (int, np.integer)) or chunk_frames < 1:
        raise ValueError(f"chunk_frames must be a positive integer, got {chunk_frames!r}")
    return [(a, min(a + int(chunk_frames), n_frames)) for a in range(0, n_frames, int(chunk_frames))]


def _thumb(im: np.ndarray) -> np.ndarray:
    g = imageproc.to_grey(im)
    s = THUMB_MAX_SIDE / max(g.shape)
    return imageproc.resize(g, (round(g.shape[1] * s), round(g.shape[0] * s))) if s < 1 else g


def encode_chunk(source: Source, encoder, start: int, stop: int, parts=PARTS, thumbs: bool = False,
                 batch_size: int = 64, on_batch=None) -> Chunk:
    """Read and describe the frames at positions ``start:stop`` of ``source``.

    Parameters
    ----------
    encoder : an encoder from :func:`encoders.get` (not fitted: fitting needs the whole traverse)
    parts : subset of :data:`PARTS` to compute.
    thumbs : keep grey thumbnails (longest side <= 640 px).
    batch_size : frames passed to the encoder at once.
    on_batch : optional callable(n_frames) after each batch (progress).
    """
    parts = _check_parts(parts)
    if isinstance(batch_size, bool) or not isinstance(batch_size, (int, np.integer)) or batch_size < 1:
        raise ValueError(f"batch_size must be a positive integer, got {batch_size!r}")
    projected = _projected(encoder)
    need_sdr, need_desc, need_pixels = (p in parts for p in PARTS)
    names, indices, sdr_rows, descs, pixels, small = [], [], [], [], [], []

    def flush(batch):
        images = [f.image for f in batch]
        if need_desc or (need_sdr and projected):
            try:
                d = encoder.describe(images)
            except NotImplementedError as e:  # the base class's "no dense descriptor"
                raise ValueError(f"a method needs dense descriptors (e.g. seqslam-desc), but {e}; "
                                 "choose an encoder with one (pixel, projection, cnn, orb)") from e
            descs.append(np.asarray(d, dtype=np.float32))
        if need_sdr and not projected:
            sdr_rows.append(sp.csr_matrix(encoder.encode(images)))
        if need_pixels:
            pixels.append(np.stack([imageproc.seqslam_preprocess(im, name=f.name).ravel()
                                    for im, f in zip(images, batch, strict=True)]).astype(np.float32))
        if thumbs:
            small.extend(_thumb(im) for im in images)
        if on_batch is not None:
            on_batch(len(batch))

    batch = []
    for frame in source.iter_range(start, stop):
        names.append(frame.name)
        indices.append(int(frame.index))
        batch.append(frame)
        if len(batch) == batch_size:
            flush(batch)
            batch = []
    if batch:
        flush(batch)
    return Chunk(start, stop, names, indices, [tuple(s) for s in source.skipped],
                 desc=np.concatenate(descs) if descs else None,
                 sdr=sp.vstack(sdr_rows).tocsr() if sdr_rows else None,
                 pixels=np.concatenate(pixels) if pixels else None,
                 thumbs=small if thumbs else None)


def assemble(source: Source, encoder, chunks, parts=PARTS) -> Extracted:
    """Join ``chunks`` (in frame order) into one encoded traverse; fit the encoder where its conf asks.

    Encoders built on a dense descriptor (``encode_descriptors``) are fitted on
    the whole traverse when their conf asks for it (``standardise="fit"``): the
    descriptors of all chunks are joined first, then standardised and
    sparsified together.

    Raises
    ------
    ValueError
        No readable frame in the whole source.
    """
    parts = _check_parts(parts)
    chunks = sorted(chunks, key=lambda c: c.start)
    names = [n for c in chunks for n in c.names]
    skipped = [s for c in chunks for s in c.skipped]
    if not names:
        msg = f"no readable frames in {source.path}"
        if skipped:
            msg += f" ({len(skipped)} skipped; first: {skipped[0][0]}: {skipped[0][1]})"
        raise ValueError(msg)
    full = [c for c in chunks if c.names]  # chunks with every frame skipped carry no arrays

    def joined(attr):
        arrays = [getattr(c, attr) for c in full]
        return np.concatenate(arrays) if arrays and arrays[0] is not None else None

    desc, pixels = joined("desc"), joined("pixels")
    sdr = None
    if "sdr" in parts:
        if _projected(encoder):
            if encoder.conf.get("standardise") == "fit":
                encoder.fit_descriptors(desc)
            sdr = sp.csr_matrix(encoder.encode_descriptors(desc))
        else:
            sdr = sp.vstack([c.sdr for c in full]).tocsr()
    feats = EncodedTraverse(names=names, sdr=sdr, desc=desc if "desc" in parts else None,
                     pixels=pixels if "pixels" in parts else None)
    thumbs = [t for c in chunks for t in (c.thumbs or [])] if any(c.thumbs is not None for c in chunks) else None
    return Extracted(feats, skipped, source.ignored, 0.0, False, thumbs, [i for c in chunks for i in c.indices])


def _write_npz(fh, arrays: dict) -> None:
    """``np.savez`` with fixed zip timestamps, so equal arrays give equal bytes."""
    with zipfile.ZipFile(fh, "w", compression=zipfile.ZIP_STORED, allowZip64=True) as zf:
        for name, arr in arrays.items():
            info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            with zf.open(info, "w", force_zip64=True) as f:
                np.lib.format.write_array(f, np.asanyarray(arr), allow_pickle=False)


def save_cache(path, ex: Extracted, source: Source, encoder) -> Path:
    """Write ``ex`` (without thumbnails) atomically; equal content gives equal bytes."""
    f = ex.features
    held = [p for p, a in zip(PARTS, (f.sdr, f.desc, f.pixels), strict=True) if a is not None]
    meta = {"version": CACHE_VERSION, "parts": held, "skipped": ex.skipped, "ignored": ex.ignored,
            "source": str(source.path), "source_key": source.key(), "encoder": encoder.name, "conf": encoder.conf}
    arrays = {"names": np.array(f.names, dtype=str), "indices": np.array(ex.indices or [], dtype=np.int64),
              "meta": np.array(json.dumps(meta, sort_keys=True, default=str))}
    if f.sdr is not None:
        s = sp.csr_matrix(f.sdr)
        arrays.update(sdr_indptr=s.indptr.astype(np.int64), sdr_indices=s.indices.astype(np.int32),
                      sdr_shape=np.array(s.shape, dtype=np.int64))
    if f.desc is not None:
        arrays["desc"] = np.asarray(f.desc, np.float32)
    if f.pixels is not None:
        arrays["pixels"] = np.asarray(f.pixels, np.float32)
    with io.atomic_path(path, suffix=".npz") as tmp:
        with open(tmp, "wb") as fh:
            _write_npz(fh, arrays)
    return Path(path)


def load_cache(path) -> Extracted | None:
    """Read a cache file; None when it is missing, damaged or of another version."""
    try:
        with np.load(path, allow_pickle=False) as z:
            d = {k: z[k] for k in z.files}
        meta = json.loads(str(d["meta"]))
        if meta.get("version") != CACHE_VERSION:
            return None
        sdr = None
        if "sdr_indptr" in d:
            idx = d["sdr_indices"]
            sdr = sp.csr_matrix((np.ones(idx.size, bool), idx, d["sdr_indptr"]), shape=tuple(d["sdr_shape"]))
        feats = EncodedTraverse(names=d["names"].tolist(), sdr=sdr, desc=d.get("desc"), pixels=d.get("pixels"))
        return Extracted(feats, [tuple(s) for s in meta["skipped"]], meta["ignored"], 0.0, True,
                         indices=d["indices"].tolist())
    except Exception:  # a damaged cache is recomputed, never trusted
        return None


def _held(ex: Extracted) -> tuple[str, ...]:
    f = ex.features
    return tuple(p for p, a in zip(PARTS, (f.sdr, f.desc, f.pixels), strict=True) if a is not None)


def _only(ex: Extracted, parts) -> Extracted:
    """``ex`` with the parts not asked for dropped (a cache may hold more)."""
    f = ex.features
    ex.features = EncodedTraverse(f.names, f.sdr if "sdr" in parts else None, f.desc if "desc" in parts else None,
                           f.pixels if "pixels" in parts else None)
    return ex


def extract(source: Source, encoder, need_sdr=True, need_desc=False, need_pixels=False, thumbs=False,
            cache_dir=None, batch_size=64, progress=True, chunk_frames=DEFAULT_CHUNK_FRAMES) -> Extracted:
    """Encode every readable frame of ``source``, or read it from the cache.

    Parameters
    ----------
    encoder : an encoder from :func:`encoders.get`
    need_sdr, need_desc, need_pixels : what to compute (SDRs, the encoder's dense
        descriptor, SeqSLAM's patch-normalised 64x32 pixels).
    thumbs : keep grey thumbnails (longest side <= 640 px) for geometric verification;
        they are not cached (a cache hit reads the frames again for them only).
    cache_dir : folder of the cache (e.g. one filled by ``vpr encode --cache DIR``), or None.
        A cache file holding more parts than asked for is used; one holding fewer
        is recomputed with the union of both and replaced.
    chunk_frames : frames per unit of work (see :data:`DEFAULT_CHUNK_FRAMES`).

    Notes
    -----
    See :func:`assemble` for encoders fitted on the whole traverse.
    """
    from tqdm import tqdm

    parts = _needs(need_sdr, need_desc, need_pixels)
    t = time.perf_counter()
    path = cache_path(cache_dir, source, encoder) if cache_dir is not None else None
    hit = load_cache(path) if path is not None and path.is_file() else None
    if hit is not None and set(parts) <= set(_held(hit)):
        if thumbs:
            chunks = [encode_chunk(source, encoder, a, b, (), thumbs=True, batch_size=batch_size)
                      for a, b in chunk_ranges(len(source.names()), chunk_frames)]
            if [n for c in chunks for n in c.names] != hit.features.names:
                raise ValueError(f"{source.path}: the readable frames differ from the cache {path}; "
                                 "delete it and run again")
            hit.thumbs = [t for c in chunks for t in c.thumbs]
        hit.seconds = time.perf_counter() - t
        return _only(hit, parts)
    stored = _held(hit) if hit is not None else ()
    todo = tuple(p for p in PARTS if p in parts or p in stored)
    total = len(source.names())
    with tqdm(total=total, desc=f"encode {source.name}", unit="frame", disable=not progress, leave=False) as bar:
        chunks = [encode_chunk(source, encoder, a, b, todo, thumbs=thumbs, batch_size=batch_size,
                               on_batch=bar.update) for a, b in chunk_ranges(total, chunk_frames)]
    ex = assemble(source, encoder, chunks, todo)
    source.skipped = list(ex.skipped)
    if path is not None:
        save_cache(path, ex, source, encoder)
    ex.seconds = time.perf_counter() - t
    return _only(ex, parts)
