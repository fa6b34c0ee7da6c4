"""Encoding stage: stream a source through an encoder, with an on-disk cache.

Frames are read in batches (never all images at once); what is kept per frame
is only what the methods need, by name (:class:`vpr.types.EncodedTraverse`):
``"sdr"`` and ``"desc"`` from the encoder, and every input a method computes
from the images itself (a :class:`vpr.types.ImageInput` it declares, e.g.
SeqSLAM's ``"pixels"``); for geometric verification also a grey thumbnail.
Results are cached in ``cache_dir`` (``vpr match --out DIR`` uses
``DIR/cache``; ``vpr encode --cache DIR`` fills any folder ahead of time) in
one file per source and encoder conf, so a second run with another method
skips encoding (as hloc's extractors skip work done).

The work is split into frame ranges of the source (:func:`chunk_ranges`):
:func:`encode_chunk` reads and describes one range, :func:`assemble` joins the
ranges in order and fits and encodes the whole traverse. :func:`extract` runs
the chunks one after the other (:func:`extract_all`: every source of a run);
``pipelines.encode`` runs them on Dask workers.
Both write the same bytes, because the chunks are the same and everything that
depends on the whole traverse happens in :func:`assemble`.
"""
from __future__ import annotations

import hashlib
import json
import time
import warnings
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from encoders.base import DescriptorEncoder
from vpr import imageproc, io, methods
from vpr import sdr as _sdr
from vpr.sources import FrameSkippedWarning, Source
from vpr.types import ENCODER_INPUTS, EncodedTraverse

__all__ = ["Extracted", "Chunk", "extract", "extract_all", "one_copy", "cache_key", "cache_path", "chunk_ranges",
           "encode_chunk", "assemble", "load_cache", "save_cache", "available_inputs", "check_inputs",
           "DEFAULT_CHUNK_FRAMES"]

# v2: one file per source + encoder conf holding any subset of the inputs, no timings (byte-reproducible)
CACHE_VERSION = 2
THUMB_MAX_SIDE = 640
#: Frames per unit of work. Part of what the cache bytes depend on only for encoders whose
#: descriptor depends on the batch (e.g. cnn with batch_size > 1); all chunkings agree otherwise.
DEFAULT_CHUNK_FRAMES = 256


def available_inputs() -> tuple[str, ...]:
    """Every input the extraction can provide: the encoder's, then each method's image inputs (sorted)."""
    return (*ENCODER_INPUTS, *sorted(methods.image_inputs()))


def check_inputs(inputs, what: str = "input") -> tuple[str, ...]:
    """``inputs`` checked against :func:`available_inputs`, in that order (``what`` names them in the error)."""
    inputs = tuple(inputs)
    known = available_inputs()
    bad = [p for p in inputs if p not in known]
    if bad:
        raise ValueError(f"unknown {what}(s) {bad}; available: {', '.join(known)}")
    return tuple(p for p in known if p in inputs)


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

    ``arrays`` holds the dense inputs (the encoder's ``"desc"`` and the image
    inputs); ``sdr`` is only set for encoders without a dense descriptor (the
    others are sparsified in :func:`assemble`, after fitting on the whole traverse).
    """

    start: int
    stop: int
    names: list
    indices: list
    skipped: list
    arrays: dict = field(default_factory=dict)
    sdr: sp.csr_matrix | None = None
    thumbs: list | None = None


def cache_key(source: Source, encoder) -> str:
    """16 hex digits naming the source's content and selection and the encoder's full conf."""
    payload = json.dumps({"v": CACHE_VERSION, "source": source.key(), "encoder": encoder.name,
                          "conf": encoder.conf}, sort_keys=True, default=str)
    return hashlib.sha1(payload.encode("utf-8", "surrogateescape")).hexdigest()[:16]


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


def encode_chunk(source: Source, encoder, start: int, stop: int, inputs=("sdr",), thumbs: bool = False,
                 batch_size: int = 64, on_batch=None) -> Chunk:
    """Read and describe the frames at positions ``start:stop`` of ``source``.

    Parameters
    ----------
    encoder : an encoder from :func:`encoders.get` (not fitted: fitting needs the whole traverse)
    inputs : names of the inputs to compute (:func:`available_inputs`).
    thumbs : keep grey thumbnails (longest side <= 640 px).
    batch_size : frames passed to the encoder at once.
    on_batch : optional callable(n_frames) after each batch (progress).
    """
    inputs = check_inputs(inputs)
    if isinstance(batch_size, bool) or not isinstance(batch_size, (int, np.integer)) or batch_size < 1:
        raise ValueError(f"batch_size must be a positive integer, got {batch_size!r}")
    described = isinstance(encoder, DescriptorEncoder)
    image_inputs = methods.image_inputs()
    need_desc = "desc" in inputs or ("sdr" in inputs and described)
    dense = [p for p in inputs if p not in ENCODER_INPUTS]
    names, indices, sdr_rows, small = [], [], [], []
    blocks: dict[str, list] = {p: [] for p in (["desc"] if need_desc else []) + dense}

    def flush(batch):
        images = [f.image for f in batch]
        if need_desc:
            try:
                d = encoder.describe(images)
            except NotImplementedError as e:  # the base class's "no dense descriptor"
                raise ValueError(f"a method run needs dense descriptors but {e}; "
                                 "choose an encoder with one (pixel, projection, cnn, orb)") from e
            blocks["desc"].append(np.asarray(d, dtype=np.float32))
        if "sdr" in inputs and not described:
            sdr_rows.append(sp.csr_matrix(encoder.encode(images)))
        for p in dense:
            name = f"{source.path}: frames {batch[0].name}..{batch[-1].name}"
            blocks[p].append(np.asarray(image_inputs[p].compute(images, name), np.float32))
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
                 arrays=one_copy({p: np.concatenate(b) for p, b in blocks.items() if b}),
                 sdr=sp.vstack(sdr_rows).tocsr() if sdr_rows else None, thumbs=small if thumbs else None)


def one_copy(arrays: dict) -> dict:
    """``arrays`` with every array equal to an earlier one replaced by that one (read-only: it is shared).

    The ``pixel`` encoder's descriptor and SeqSLAM's pixels are the same
    numbers: held and stored once, not twice.
    """
    out: dict = {}
    for p, a in arrays.items():
        twin = next((b for b in out.values() if b is a or (b.shape == a.shape and b.dtype == a.dtype
                                                           and np.array_equal(b, a))), None)
        if twin is not None:
            twin.flags.writeable = False
        out[p] = a if twin is None else twin
    return out


def assemble(source: Source, encoder, chunks, inputs=("sdr",)) -> Extracted:
    """Join ``chunks`` (in frame order) into one encoded traverse; fit the encoder where its conf asks.

    Encoders built on a dense descriptor (:class:`encoders.base.DescriptorEncoder`)
    are fitted on the whole traverse when their conf asks for it
    (``standardise="fit"``): the descriptors of all chunks are joined first,
    then standardised and sparsified together.

    Raises
    ------
    ValueError
        No readable frame in the whole source.
    """
    inputs = check_inputs(inputs)
    chunks = sorted(chunks, key=lambda c: c.start)
    names = [n for c in chunks for n in c.names]
    skipped = [s for c in chunks for s in c.skipped]
    if not names:
        msg = f"no readable frames in {source.path}"
        if skipped:
            msg += f" ({len(skipped)} skipped; first: {skipped[0][0]}: {skipped[0][1]})"
        raise ValueError(msg)
    full = [c for c in chunks if c.names]  # chunks with every frame skipped carry no arrays
    joined, arrays = {}, {}  # inputs that are one array in every chunk are joined once
    for p in full[0].arrays:
        key = tuple(id(c.arrays[p]) for c in full)
        if key not in joined:
            joined[key] = np.concatenate([c.arrays[p] for c in full]) if len(full) > 1 else full[0].arrays[p]
        arrays[p] = joined[key]
    arrays = one_copy(arrays)
    sdr = None
    if "sdr" in inputs:
        if isinstance(encoder, DescriptorEncoder):
            if encoder.conf.get("standardise") == "fit":
                encoder.fit_descriptors(arrays["desc"])
            sdr = sp.csr_matrix(encoder.encode_descriptors(arrays["desc"]))
        else:
            sdr = sp.vstack([c.sdr for c in full]).tocsr()
    feats = EncodedTraverse(names, sdr=sdr, **{p: a for p, a in arrays.items() if p in inputs})
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
    held = [p for p in available_inputs() if p in f.inputs]
    meta = {"version": CACHE_VERSION, "parts": held, "skipped": ex.skipped, "ignored": ex.ignored,
            "source": str(source.path), "source_key": source.key(), "encoder": encoder.name, "conf": encoder.conf}
    arrays = {"names": np.array(f.names, dtype=str), "indices": np.array(ex.indices or [], dtype=np.int64)}
    if "sdr" in held:
        s = sp.csr_matrix(f.sdr)
        arrays.update(sdr_indptr=s.indptr.astype(np.int64), sdr_indices=s.indices.astype(np.int32),
                      sdr_shape=np.array(s.shape, dtype=np.int64))
    dense = one_copy({p: np.asarray(f.inputs[p], np.float32) for p in held if p != "sdr"})
    meta["same"] = {}  # an input equal to one stored before it is stored once
    for p, a in dense.items():
        twin = next((q for q in dense if dense[q] is a), p)
        if twin == p:
            arrays[p] = a
        else:
            meta["same"][p] = twin
    arrays["meta"] = np.array(json.dumps(meta, sort_keys=True, default=str))
    with io.atomic_path(path, suffix=".npz") as tmp:
        with open(tmp, "wb") as fh:
            _write_npz(fh, arrays)
    return Path(path)


def _same(a, b) -> bool:
    """Equal as they are stored in a cache file's JSON metadata."""
    return json.dumps(a, sort_keys=True, default=str) == json.dumps(b, sort_keys=True, default=str)


def load_cache(path, source: Source | None = None, encoder=None) -> Extracted | None:
    """Read a cache file; None when it is missing, damaged, of another version, or (given ``source`` and
    ``encoder``) written for another source or encoder conf: a file is trusted by its content, not its name."""
    try:
        with np.load(path, allow_pickle=False) as z:
            d = {k: z[k] for k in z.files}
        meta = json.loads(str(d["meta"]))
        if meta.get("version") != CACHE_VERSION:
            return None
        if source is not None and not _same(meta.get("source_key"), source.key()):
            warnings.warn(f"cache {path} was written for another source ({meta.get('source')}); encoding "
                          f"{source.path} again", stacklevel=2)
            return None
        if encoder is not None and not (meta.get("encoder") == encoder.name and _same(meta.get("conf"), encoder.conf)):
            return None
        held = {}
        for p in meta["parts"]:
            if p == "sdr":
                idx = d["sdr_indices"]
                held[p] = sp.csr_matrix((np.ones(idx.size, bool), idx, d["sdr_indptr"]), shape=tuple(d["sdr_shape"]))
            else:
                twin = meta.get("same", {}).get(p)
                held[p] = d[p] if twin is None else d[twin]
                if twin is not None:  # one array read as two inputs: never written in place
                    d[twin].flags.writeable = False
        feats = EncodedTraverse(d["names"].tolist(), **held)
        return Extracted(feats, [tuple(s) for s in meta["skipped"]], meta["ignored"], 0.0, True,
                         indices=d["indices"].tolist())
    except Exception:  # a damaged cache is recomputed, never trusted
        return None


def held_inputs(ex: Extracted) -> tuple[str, ...]:
    """The inputs an extraction (or a cache file) holds."""
    return tuple(p for p in available_inputs() if p in ex.features.inputs)


def _only(features: EncodedTraverse, inputs) -> EncodedTraverse:
    return EncodedTraverse(features.names, **{k: v for k, v in features.inputs.items() if k in set(inputs)})


def extract(source: Source, encoder, inputs=("sdr",), thumbs=False, cache_dir=None, batch_size=64, progress=True,
            chunk_frames=DEFAULT_CHUNK_FRAMES) -> Extracted:
    """Encode every readable frame of ``source``, or read it from the cache.

    Parameters
    ----------
    encoder : an encoder from :func:`encoders.get`
    inputs : names of what to compute: ``"sdr"``, ``"desc"`` (the encoder's dense
        descriptor) and any image input of a method (:func:`available_inputs`;
        e.g. the union of the methods' ``required_inputs``).
    thumbs : keep grey thumbnails (longest side <= 640 px) for geometric verification;
        they are not cached (a cache hit reads the frames again for them only).
    cache_dir : folder of the cache (e.g. one filled by ``vpr encode --cache DIR``), or None.
        A cache file holding more inputs than asked for is used; one holding fewer
        is recomputed with the union of both and replaced.
    chunk_frames : frames per unit of work (see :data:`DEFAULT_CHUNK_FRAMES`).

    Notes
    -----
    See :func:`assemble` for encoders fitted on the whole traverse.
    """
    from tqdm import tqdm

    inputs = check_inputs(inputs)
    t = time.perf_counter()
    path = cache_path(cache_dir, source, encoder) if cache_dir is not None else None
    hit = load_cache(path, source, encoder) if path is not None and path.is_file() else None
    if hit is not None and set(inputs) <= set(held_inputs(hit)):
        if thumbs:
            chunks = [encode_chunk(source, encoder, a, b, (), thumbs=True, batch_size=batch_size)
                      for a, b in chunk_ranges(len(source.names()), chunk_frames)]
            if [n for c in chunks for n in c.names] != hit.features.names:
                raise ValueError(f"{source.path}: the readable frames differ from the cache {path}; "
                                 "delete it and run again")
            hit.thumbs = [t for c in chunks for t in c.thumbs]
        hit.seconds = time.perf_counter() - t
        hit.features = _only(hit.features, inputs)
        return hit
    todo = check_inputs(set(inputs) | set(held_inputs(hit) if hit is not None else ()))
    total = len(source.names())
    with tqdm(total=total, desc=f"encode {source.name}", unit="frame", disable=not progress, leave=False) as bar:
        chunks = [encode_chunk(source, encoder, a, b, todo, thumbs=thumbs, batch_size=batch_size,
                               on_batch=bar.update) for a, b in chunk_ranges(total, chunk_frames)]
    ex = assemble(source, encoder, chunks, todo)
    source.skipped = list(ex.skipped)
    if path is not None:
        try:
            save_cache(path, ex, source, encoder)
        except OSError as e:  # the run goes on; the next one encodes again
            warnings.warn(f"cache {path.parent}: not written ({e.strerror or e}); the encodings are not cached",
                          stacklevel=2)
    ex.seconds = time.perf_counter() - t
    ex.features = _only(ex.features, inputs)
    return ex


def extract_all(srcs, roles, encoder, inputs, cache_dir=None, thumbs: bool = False, progress: bool = True):
    """:func:`extract` of every source, with one warning per source whose frames were skipped or whose SDRs
    cannot tell its frames apart (:func:`vpr.sdr.degenerate`)."""
    exs = []
    for src, role in zip(srcs, roles, strict=True):
        attempted = len(src.indices())
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", FrameSkippedWarning)  # one line per source below, not one per frame
            ex = extract(src, encoder, tuple(sorted(inputs)), thumbs=thumbs, cache_dir=cache_dir, progress=progress)
        lost = attempted - len(ex.features)
        if lost > 0 or ex.skipped:
            first = f" (first: {ex.skipped[0][0]}: {ex.skipped[0][1]})" if ex.skipped else ""
            warnings.warn(f"{role} {src.path}: {lost} of {attempted} frames could not be read and were skipped{first}",
                          UserWarning, stacklevel=2)
        bad = _sdr.degenerate(ex.features.sdr) if ex.features.sdr is not None else None
        if bad:
            warnings.warn(f"{role} {src.path}: {bad}; matching those frames is guesswork (encoder {encoder.name})",
                          UserWarning, stacklevel=2)
        exs.append(ex)
    return exs
