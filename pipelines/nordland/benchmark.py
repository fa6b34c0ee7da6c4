"""The Nordland summer (database) vs winter (query) benchmark.

Every method sees the same frames: the pixel descriptor (OpenSeqSLAM's
patch-normalised 64x32 grey thumbnail) and, for the SDR methods, its random
projection top-k SDR with per-traverse standardisation (each season's encoder
is fitted on that season's own frames, which removes the season's mean
appearance; see ``research/docs/experiments.md`` for why).
"""
from __future__ import annotations

import time
from pathlib import Path

import encoders
from vpr import evaluate, groundtruth, methods, presets
from vpr import io as _io
from vpr.types import EncodedTraverse

from .data import SUBSETS, find_dataset, frame_names, pixel_descriptors

__all__ = ["METHOD_SPECS", "encode_sdrs", "run_methods", "run_benchmark", "markdown_table"]

#: Benchmark entry -> (vpr.methods name, conf): :data:`vpr.presets.NORDLAND_METHODS`
METHOD_SPECS = presets.NORDLAND_METHODS


def encode_sdrs(db_desc, q_desc, n_bits: int = 2048, k: int = 40, standardise: str = "fit", seed: int = 0):
    """Random-projection top-k SDRs of both traverses; with ``"fit"`` each traverse is fitted on itself."""

    out = []
    for desc in (db_desc, q_desc):
        enc = encoders.get("projection", descriptor="pixel", n_bits=n_bits, k=k, standardise=standardise, seed=seed)
        if standardise == "fit":
            enc.fit_descriptors(desc)
        out.append(enc.encode_descriptors(desc))
    return out[0], out[1]


def run_methods(db_desc, q_desc, db_sdr, q_sdr, specs: dict, progress: bool = False) -> tuple[dict, dict]:
    """Run and evaluate every ``specs`` entry with the project's harness (:func:`vpr.evaluate.run_methods`).

    Ground truth: |i - j| <= 1 true, 1 < |i - j| <= 3 ignored. Returns
    ``(metrics, curves)``: label -> metric dict (with the method's seconds, CPU
    seconds and the process's peak RSS after it), label -> (precision, recall).
    """
    n_db, n_q = len(db_desc), len(q_desc)
    names = [str(i) for i in range(max(n_db, n_q))]
    db = EncodedTraverse(names[:n_db], sdr=db_sdr, desc=db_desc, pixels=db_desc)
    q = EncodedTraverse(names[:n_q], sdr=q_sdr, desc=q_desc, pixels=q_desc)
    gh, gs = groundtruth.gt_from_tolerance(n_db, n_q, 1), groundtruth.gt_from_tolerance(n_db, n_q, 3)
    runners = {label: methods.get(method, **conf) for label, (method, conf) in specs.items()}  # bad conf: now
    done = evaluate.run_methods(runners, lambda r: r.match(db, q, progress=progress), gh, gs, resources=True)
    return {k: m for k, (m, _) in done.items()}, {k: c for k, (_, c) in done.items()}


def markdown_table(metrics: dict, title: str | None = None) -> str:
    """Markdown table of AP, AUC, R@100P, R@1 and seconds per method."""
    lines = [f"**{title}**", ""] if title else []
    lines += ["| method | AP | AUC | R@100P | R@1 | R@5 | seconds (wall) | seconds (CPU) |",
              "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for label, m in metrics.items():
        lines.append(f"| {label} | {m['ap']:.3f} | {m['auc_pr']:.3f} | {m['recall_at_100p']:.3f} | "
                     f"{m['recall_at_1']:.3f} | {m['recall_at_5']:.3f} | {m['seconds']:.2f} | {m['cpu_seconds']:.2f} |")
    return "\n".join(lines) + "\n"


def run_benchmark(subset: str, out, data=None, k: int = 40, threshold: float | None = None,
                  progress: bool = True) -> dict:
    """Load, encode, run every method, evaluate; write ``metrics.json``, ``pr.png`` and ``table.md``.

    Parameters
    ----------
    subset : {"358", "full"}
    out : output folder (descriptors are cached in ``out/cache``).
    data : dataset folder; default: see :func:`pipelines.nordland.data.candidate_roots`.
    k : active bits of the 2048-bit SDRs.
    threshold : minicolumn threshold of both rSHOSM methods (default: the method defaults).

    Returns
    -------
    dict: the content of ``metrics.json``.
    """
    from vpr.plots import plot_pr  # matplotlib: slow to import, only needed for the plot

    out = Path(out)
    t0 = time.perf_counter()
    root = find_dataset(data)
    names = frame_names(root, subset)
    db_desc = pixel_descriptors(root, "summer", names, out / "cache", progress)
    q_desc = pixel_descriptors(root, "winter", names, out / "cache", progress)
    t_enc = time.perf_counter()
    db_sdr, q_sdr = encode_sdrs(db_desc, q_desc, k=k)
    t_enc = time.perf_counter() - t_enc
    specs = {label: (m, dict(c)) for label, (m, c) in METHOD_SPECS.items()}
    if threshold is not None:
        for m, c in specs.values():
            if "threshold" in methods.get_class(m).default_conf:
                c["threshold"] = float(threshold)
    metrics, curves = run_methods(db_desc, q_desc, db_sdr, q_sdr, specs, progress)
    out.mkdir(parents=True, exist_ok=True)
    title = f"Nordland summer vs winter, {len(names)} frames (subset {subset})"
    plot_pr(curves, out / "pr.png", title=title, ap={lbl: m["ap"] for lbl, m in metrics.items()})
    table = markdown_table(metrics, title)
    with _io.atomic_open(out / "table.md", "w", encoding="utf-8") as fh:
        fh.write(table)
    doc = {
        "subset": subset, "frames": len(names), "step": SUBSETS[subset], "data": str(root),
        "ground_truth": {"hard": "|i - j| <= 1", "soft": "|i - j| <= 3", "tolerance_unit": "frames kept",
                         "frame_step": SUBSETS[subset], "tolerance_input_frames": SUBSETS[subset],
                         "tolerance_text": groundtruth.tolerance_text("tolerance", 1, SUBSETS[subset]),
                         "gt_soft_text": groundtruth.tolerance_text("soft", 3, SUBSETS[subset])},
        "sdr": {"encoder": "projection", "descriptor": "pixel", "n_bits": 2048, "k": k, "standardise": "fit",
                "fitted_on": "each traverse itself", "seconds": t_enc},
        "methods": {label: {"method": m, "conf": methods.get(m, **c).conf, **metrics[label]}
                    for label, (m, c) in specs.items()},
        "peak_rss_mb": evaluate.peak_rss_mb(),
        "total_seconds": time.perf_counter() - t0,
    }
    _io.save_json(out / "metrics.json", doc)
    from vpr.report import write_table

    header = [("ap", "AP"), ("auc_pr", "AUC"), ("recall_at_100p", "R@100P"), ("recall_at_1", "R@1"),
              ("recall_at_5", "R@5"), ("seconds", "seconds")]
    truth = doc["ground_truth"]
    write_table(out, f"vpr nordland: {title}", header,
                [(label, [f"{m[k]:.3f}" if k != "seconds" else f"{m[k]:.2f}" for k, _ in header])
                 for label, m in metrics.items()], [("precision-recall", out / "pr.png")],
                [f"ground truth in frames kept: {truth['tolerance_text']} true; {truth['gt_soft_text']} ignored",
                 f"data {root}, subset {subset}: {len(names)} frames of each season"])
    return doc
