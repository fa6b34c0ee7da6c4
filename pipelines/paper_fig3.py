"""Reproduce Fig. 3 of Neubert, Ahmad & Protzel (KI 2018) on the simulated grid world.

Left panel: SHOSM vs rSHOSM (p_extra = 0.01 and 0.05), no noise, no aliasing.
Right panel: single-frame comparison of the input SDRs vs rSHOSM (p_extra = 0.05) for
(a=0, n=0.5), (a=5, n=0) and (a=5, n=0.5): ``a`` pairs of places share one SDR,
``n`` is the fraction of 1-bits moved per observation.

Trajectory: 10 laps of a 20-place loop (200 observations). Similarity: overlap of
winner codes (rSHOSM) or of input SDRs (single frames), T x T; every pair i < j is a
decision, ground truth = same place. Metrics are averaged over seeds.

Run: ``vpr paper-fig3 --out results/fig3`` or ``python -m pipelines.paper_fig3 --out DIR``.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from pipelines.args import add_common_arguments
from vpr import evaluate, groundtruth, io, methods, plots, presets, simulate
from vpr.types import EncodedTraverse

__all__ = ["CURVES_LEFT", "CURVES_RIGHT", "run_curve", "run", "main"]

COMMANDS = {"paper-fig3": "reproduce Fig. 3 of the paper on the simulated grid world"}

#: name -> (method, p_extra, aliasing a, noise n): :data:`vpr.presets.PAPER_FIG3`
CURVES_LEFT, CURVES_RIGHT = presets.PAPER_FIG3["left"], presets.PAPER_FIG3["right"]


def _conf(method: str, p_extra: float, seed: int) -> dict:
    """The method's conf for a curve: a memory's ``p_extra`` and ``seed`` where it has them."""
    known = methods.get_class(method).default_conf
    return {k: v for k, v in (("p_extra", p_extra), ("seed", seed)) if k in known}


def run_curve(method: str, p_extra: float, aliasing: int, noise: float, seed: int, n_loops: int = 10) -> dict:
    """One curve for one seed: the method's loop similarity of all pairs i < j, metrics and the PR curve."""
    obs, places = simulate.simulate_loops(aliasing=aliasing, noise=noise, n_loops=n_loops, seed=seed)
    seq = EncodedTraverse([str(i) for i in range(obs.shape[0])], sdr=obs)
    t = time.perf_counter()
    S = methods.get(method, **_conf(method, p_extra, seed)).loops(seq, exclude=1).similarity
    seconds = time.perf_counter() - t
    gt = groundtruth.gt_from_labels(places, places)
    mask = groundtruth.loop_closure_mask(len(places), exclude=1)
    prec, rec, _ = evaluate.pr_curve(S, gt, mask=mask)
    return {"ap": evaluate.average_precision(S, gt, mask=mask), "auc_pr": evaluate.auc_from_pr(prec, rec),
            "recall_at_100p": evaluate.recall_at_100p(S, gt, mask=mask),
            "seconds": seconds, "precision": prec, "recall": rec}


def run(out_dir, seeds: int = 5, n_loops: int = 10, progress: bool = True) -> dict:
    """Run both panels, write ``fig3_left.png``, ``fig3_right.png`` and ``metrics.json``; return the metrics."""
    if seeds < 1:
        raise ValueError(f"seeds must be >= 1, got {seeds}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    from tqdm import tqdm

    panels = {"left": CURVES_LEFT, "right": CURVES_RIGHT}
    metrics = {"curves": {}, "params": {"seeds": seeds, "n_loops": n_loops, "places_per_loop": 20,
                                         "n_bits": 2048, "n_active": 40,
                                         "memory": _memory_conf()}}
    jobs = [(panel, name, spec, s) for panel, curves in panels.items() for name, spec in curves.items()
            for s in range(seeds)]
    results: dict = {}
    for panel, name, spec, s in tqdm(jobs, desc="paper-fig3", unit="run", disable=not progress):
        results.setdefault((panel, name), []).append(run_curve(*spec, seed=s, n_loops=n_loops))
    for panel, curves in panels.items():
        plot_curves = {}
        for name, (method, p, a, n) in curves.items():
            rs = results[(panel, name)]
            ap = [r["ap"] for r in rs]
            auc = [r["auc_pr"] for r in rs]
            r100 = [r["recall_at_100p"] for r in rs]
            metrics["curves"][name] = {
                "panel": panel, "method": method, "p_extra": p, "aliasing": a, "noise": n,
                "ap": float(np.mean(ap)), "ap_std": float(np.std(ap)),
                "auc_pr": float(np.mean(auc)), "auc_pr_std": float(np.std(auc)),
                "recall_at_100p": float(np.mean(r100)), "recall_at_100p_std": float(np.std(r100)),
                "per_seed": {"ap": ap, "auc_pr": auc, "recall_at_100p": r100},
                "seconds": float(np.mean([r["seconds"] for r in rs])),
            }
            # the curves drawn are seed 0's; metrics.json has the means over all seeds
            plot_curves[name] = (rs[0]["precision"], rs[0]["recall"])
        title = ("SHOSM vs rSHOSM (no noise, no aliasing)" if panel == "left"
                 else "single frames vs rSHOSM (a = aliased pairs, n = noise)")
        plots.plot_pr(plot_curves, out / f"fig3_{panel}.png", title=f"{title}; seed 0",
                      ap={name: results[(panel, name)][0]["ap"] for name in curves})
    io.save_json(out / "metrics.json", metrics)
    from vpr.report import write_table

    header = [("ap", "AP"), ("ap_std", "(std)"), ("auc_pr", "AUC"), ("auc_pr_std", "(std)"),
              ("recall_at_100p", "R@100P"), ("recall_at_100p_std", "(std)")]
    write_table(out, "vpr paper-fig3: the paper's Fig. 3 on its simulated world",
                header, [(name, [f"{m[k]:.3f}" for k, _ in header]) for name, m in metrics["curves"].items()],
                [(f"Fig. 3 {panel} (seed 0)", out / f"fig3_{panel}.png") for panel in panels],
                [f"means over {seeds} seeds, {n_loops} laps of a 20-place loop; the settings: "
                 + json.dumps(metrics["params"], sort_keys=True)])
    return metrics


def _memory_conf() -> dict:
    """The default conf of the memory the curves learn (the method of theirs with a ``p_extra``)."""
    name = next(m for c in (CURVES_LEFT, CURVES_RIGHT) for m, *_ in c.values()
                if "p_extra" in methods.get_class(m).default_conf)
    return {k: v for k, v in methods.get(name).conf.items() if k != "top_k"}


def format_table(metrics: dict) -> str:
    lines = [f"{'curve':<28} {'AP':>7} {'(std)':>7} {'AUC':>7} {'(std)':>7} {'R@100P':>7} {'(std)':>7}"]
    for name, m in metrics["curves"].items():
        lines.append(f"{name:<28} {m['ap']:7.3f} {m['ap_std']:7.3f} {m['auc_pr']:7.3f} {m['auc_pr_std']:7.3f}"
                     f" {m['recall_at_100p']:7.3f}"
                     f" {m['recall_at_100p_std']:7.3f}")
    return "\n".join(lines)


def add_arguments(ap: argparse.ArgumentParser, command: str = "paper-fig3") -> None:
    ap.add_argument("--out", required=True, help="output folder (plots and metrics.json)")
    ap.add_argument("--seeds", type=int, default=5, help="seeds to average over (default 5)")
    ap.add_argument("--loops", type=int, default=10, help="laps of the 20-place loop (default 10)")
    add_common_arguments(ap)


def run_command(args) -> int:
    metrics = run(args.out, seeds=args.seeds, n_loops=args.loops, progress=not args.no_progress)
    print(format_table(metrics))
    print(f"wrote {Path(args.out) / 'report.html'} (open it: the table and both panels), fig3_left.png, "
          "fig3_right.png, metrics.json")
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m pipelines.paper_fig3", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    add_arguments(ap)
    return run_command(ap.parse_args(argv))


if __name__ == "__main__":
    raise SystemExit(main())
