"""The report page: its size, and how long headless Chromium takes to load it, on real and large runs.

Runs ``vpr compare`` on Gardens Point day_left vs day_right (the real pair of
folders, ``--tolerance 2 --gt-soft 8``), then ``vpr loops --method pairwise`` on a
rendered 10,000-frame drive (``loop_revisits`` at 64x48, positions as ground truth),
and opens each ``report.html`` in the distribution's headless Chromium
(Selenium) ``--repeats`` times: the load time (navigation start to the load
event, min / median / max), console errors, whether the table the browser
shows equals ``metrics.json``, and the strips shown per method.

    VPR_DATASETS=../shared/datasets python research/benchmarks/bench_report.py [--frames 10000] [--repeats 3]
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))


def _vpr(*argv) -> float:
    t = time.perf_counter()
    subprocess.run([sys.executable, "-m", "pipelines.cli", *map(str, argv), "--no-progress"], check=True, cwd=ROOT,
                   stdout=subprocess.DEVNULL)
    return time.perf_counter() - t


def _browse(page: Path, kind: str, repeats: int) -> dict:
    from selenium.webdriver.common.by import By

    from tests.browser import chromium
    from vpr.report import table_cells

    metrics = json.loads((page.parent / "metrics.json").read_text())["methods"]
    loads, errors, same, strips = [], 0, True, {}
    for _ in range(repeats):
        with chromium() as browser:
            browser.get(page.as_uri())
            loads.append(browser.execute_script(
                "const t = performance.timing; return t.loadEventEnd - t.navigationStart") / 1000)
            errors += sum(e["level"] == "SEVERE" for e in browser.get_log("browser"))
            for m, v in metrics.items():
                shown = [td.text for td in browser.find_elements(By.CSS_SELECTOR, f'tr[data-method="{m}"] td')[1:]]
                same &= shown == table_cells(v, kind)
            for s in browser.find_elements(By.CSS_SELECTOR, ".strip"):
                strips[s.get_attribute("data-method")] = strips.get(s.get_attribute("data-method"), 0) + 1
    return {"MB": page.stat().st_size / 1e6, "load_s": loads, "errors": errors, "table_equals_metrics": same,
            "strips": {m: n // repeats for m, n in strips.items()}}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=10000)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)
    data = Path(os.environ.get("VPR_DATASETS", ROOT.parent / "shared" / "datasets"))
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        gp = data / "gardens_point_day"
        sec = _vpr("compare", gp / "day_left", gp / "day_right", "--out", tmp / "gp", "--tolerance", 2,
                   "--gt-soft", 8)
        rows.append(("Gardens Point day_left vs day_right (vpr compare, 200 x 200)", sec,
                     _browse(tmp / "gp" / "report.html", "match", args.repeats)))
        from vpr.render import write_scene

        res = write_scene("loop_revisits", tmp / "drive", size=(64, 48), n_frames=args.frames, progress=False)
        folder = res["traverses"]["laps"]["folder"]
        # pairwise: the page's size and load time depend on the frames, not on the method
        sec = _vpr("loops", folder, "--out", tmp / "loops", "--gt", res["ground_truth"], "--radius", 4,
                   "--preset", "fast", "--method", "pairwise")
        rows.append((f"rendered drive, {args.frames:,} frames (vpr loops --method pairwise)", sec,
                     _browse(tmp / "loops" / "report.html", "loops", args.repeats)))
    print("| run | run s | page MB | Chromium load s (min / median / max) | console errors | table = metrics.json "
          "| strips per method |")
    print("|---|---:|---:|---|---:|---|---|")
    for name, sec, r in rows:
        lo = r["load_s"]
        print(f"| {name} | {sec:.1f} | {r['MB']:.2f} | {min(lo):.2f} / {statistics.median(lo):.2f} / {max(lo):.2f} "
              f"| {r['errors']} | {'yes' if r['table_equals_metrics'] else 'NO'} | "
              + ", ".join(f"{m} {n}" for m, n in r["strips"].items()) + " |")


if __name__ == "__main__":
    main()
