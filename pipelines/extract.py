"""Encoding stage: stream a source through an encoder, with an on-disk cache.

Frames are read in batches (never all images at once); what is kept per frame
is only what the methods need: the SDR row, the encoder's dense descriptor,
SeqSLAM's 64x32 patch-normalised pixels and, for geometric verification, a
grey thumbnail. Results are cached under ``cache_dir`` keyed by the source's
content key, the encoder name and conf and what was asked for, so a second run
with another method skips encoding (as hloc's extractors skip work done).
"""
from __future__ import annotations

import hashlib
import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from vpr import imageproc, io
from vpr.methods import EncodedTraverse
from vpr.sources import Source, iter_batches

__all__ = ["Extracted", "extract", "cache_key"]

CACHE_VERSION = 1
THUMB_MAX_SIDE = 640


@dataclass
class Extracted:
    features: EncodedTraverse
    skipped: list = field(default_factory=list)
    ignored: int = 0
    seconds: float = 0.0
    cached: bool = False
    thumbs: list | None = None
    indices: list | None = None


def _projected(encoder) -> bool:
    return hasattr(encoder, "encode_descriptors") and hasattr(encoder, "fit_descriptors")


def cache_key(source: Source, encoder, need_sdr: bool, need_desc: bool, need_pixels: bool) -> str:
    payload = json.dumps({"v": CACHE_VERSION, "source": source.key(), "encoder": encoder.name,
                          "conf": encoder.conf, "sdr": need_sdr, "desc": need_desc, "pixels": need_pixels},
                         sort_keys=True, default=str)
    return hashlib.sha1(payload.encode()).hexdigest()[:16]


def _save_cache(path: Path, ex: Extracted) -> None:
    f = ex.features
    arrays = {"names": np.array(f.names, dtype=str), "indices": np.array(ex.indices or [], dtype=np.int64),
              "meta": np.array(json.dumps({"skipped": ex.skipped, "ignored": ex.ignored, "seconds": ex.seconds}))}
    if f.sdr is not None:
        arrays.update(sdr_indptr=f.sdr.indptr, sdr_indices=f.sdr.indices, sdr_shape=np.array(f.sdr.shape))
    if f.desc is not None:
        arrays["desc"] = f.desc
    if f.pixels is not None:
        arrays["pixels"] = f.pixels
    with io.atomic_path(path, suffix=".npz") as tmp:
        with open(tmp, "wb") as fh:
            np.savez(fh, **arrays)


def _load_cache(path: Path) -> Extracted | None:
    try:
        with np.load(path, allow_pickle=False) as z:
            d = {k: z[k] for k in z.files}
        meta = json.loads(str(d["meta"]))
        sdr = None
        if "sdr_indptr" in d:
            idx = d["sdr_indices"]
            sdr = sp.csr_matrix((np.ones(idx.size, bool), idx, d["sdr_indptr"]), shape=tuple(d["sdr_shape"]))
        feats = EncodedTraverse(names=d["names"].tolist(), sdr=sdr, desc=d.get("desc"), pixels=d.get("pixels"))
        return Extracted(feats, [tuple(s) for s in meta["skipped"]], meta["ignored"], meta["seconds"], True,
                         indices=d["indices"].tolist())
    except Exception:  # a damaged cache is recomputed, never trusted
        return None


def extract(source: Source, encoder, need_sdr=True, need_desc=False, need_pixels=False, thumbs=False,
            cache_dir=None, batch_size=64, progress=True) -> Extracted:
    """Encode every readable frame of ``source``.

    Parameters
    ----------
    encoder : an encoder from :func:`encoders.get`
    need_sdr, need_desc, need_pixels : what to compute (SDRs, the encoder's dense
        descriptor, SeqSLAM's patch-normalised 64x32 pixels).
    thumbs : keep grey thumbnails (longest side <= 640 px) for geometric verification.
    cache_dir : folder for the cache, or None for no cache. Thumbnails are not cached.

    Notes
    -----
    Encoders built on a dense descriptor (``encode_descriptors``) are fitted on
    the whole traverse when their conf asks for it (``standardise="fit"``): the
    descriptors are collected first, then standardised and sparsified together.
    """
    from tqdm import tqdm

    path = None
    if cache_dir is not None and not thumbs:
        path = Path(cache_dir) / f"{source.name}-{encoder.name}-{cache_key(source, encoder, need_sdr, need_desc, need_pixels)}.npz"
        if path.is_file():
            hit = _load_cache(path)
            if hit is not None:
                return hit
    projected = _projected(encoder)
    t = time.perf_counter()
    names, indices, sdr_rows, descs, pixels, small = [], [], [], [], [], []
    total = len(source.names())
    with tqdm(total=total, desc=f"encode {source.name}", unit="frame", disable=not progress, leave=False) as bar:
        for batch in iter_batches(source, batch_size):
            images = [f.image for f in batch]
            names += [f.name for f in batch]
            indices += [f.index for f in batch]
            d = None
            if need_desc or (need_sdr and projected):
                try:
                    d = encoder.describe(images)
                except NotImplementedError as e:  # the base class's "no dense descriptor"
                    raise ValueError(f"a method needs dense descriptors (e.g. seqslam-desc), but {e}; "
                                     f"choose an encoder with one (pixel, projection, cnn, orb)") from e
                descs.append(d)
            if need_sdr and not projected:
                sdr_rows.append(encoder.encode(images))
            if need_pixels:
                pixels.append(np.stack([imageproc.seqslam_preprocess(im, name=f.name).ravel()
                                        for im, f in zip(images, batch)]))
            if thumbs:
                for im in images:
                    g = imageproc.to_grey(im)
                    s = THUMB_MAX_SIDE / max(g.shape)
                    small.append(imageproc.resize(g, (round(g.shape[1] * s), round(g.shape[0] * s))) if s < 1 else g)
            bar.update(len(batch))
    if not names:
        raise ValueError(f"no readable frames in {source.path}")
    desc = np.concatenate(descs).astype(np.float32) if descs else None
    sdr = None
    if need_sdr:
        if projected:
            if encoder.conf.get("standardise") == "fit":
                encoder.fit_descriptors(desc)
            sdr = encoder.encode_descriptors(desc)
        else:
            sdr = sp.vstack(sdr_rows).tocsr()
    feats = EncodedTraverse(names=names, sdr=sdr, desc=desc if need_desc else None,
                     pixels=np.concatenate(pixels).astype(np.float32) if pixels else None)
    ex = Extracted(feats, list(source.skipped), source.ignored, time.perf_counter() - t, False,
                   small if thumbs else None, indices)
    if path is not None:
        _save_cache(path, ex)
    return ex
