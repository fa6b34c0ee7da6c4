"""Write a rendered continuous drive as two frame-aligned folders of up to 50,000 frames.

The scene is ``research/benchmarks/long_drive.json``: a 20 km procedural street driven
twice at the same steady 2 m/s and 5 frames per second, 0.4 m per frame, so
about ten frames per place as a robot records them (unlike the random places
of ``make_large_folders.py``, consecutive frames look alike): a summer day
as the database, a winter dusk in another lane as the query. Both traverses
sample the route at the same positions, so frame ``i`` of the query shows the
place of frame ``i`` of the database (ground truth ``--tolerance`` in frames:
5 frames are 2 m). Frames are 160 x 120 BGR PNG, written as they are rendered.

Usage: python research/benchmarks/make_rendered_drive.py OUT [--n 50000] [--seed S (another world; 0: the spec's)]
then: python research/benchmarks/bench_scale_images.py --source rendered --data DIR --tolerance 5
(which writes ``DIR/frames`` with this script)
"""
from __future__ import annotations

import json
from pathlib import Path

import cv2

SPEC = Path(__file__).with_name("long_drive.json")


def write_folders(out, n: int = 50_000, seed: int = 0) -> bool:
    """Write ``out/db`` and ``out/query`` (the first ``n`` frames of each traverse) unless a complete set is there.

    ``seed``: the world's (0: the spec's own). True if written.
    """
    from tqdm import tqdm

    from vpr.render.scene import SceneRenderer, apply_overrides
    from vpr.render.spec import load_spec

    out = Path(out)
    done = out / "done.json"
    want = {"n": n, "seed": seed, "spec": json.loads(SPEC.read_text())}
    if done.is_file() and json.loads(done.read_text()) == want:
        return False
    spec = apply_overrides(load_spec(SPEC), seed=seed or None)
    renderer = SceneRenderer(spec)
    done.unlink(missing_ok=True)
    for name, tspec in zip(("db", "query"), spec["traverses"], strict=True):
        plan = renderer.plan(tspec)
        if plan.n < n:
            raise ValueError(f"{SPEC}: traverse {tspec['name']} has {plan.n} frames, fewer than --n {n}")
        folder = out / name
        folder.mkdir(parents=True, exist_ok=True)
        frames = renderer.frames(tspec, plan)
        for i in tqdm(range(n), desc=f"render {name}", unit="frame", disable=None):
            cv2.imwrite(str(folder / f"{i:06d}.png"), next(frames))
    done.write_text(json.dumps(want))
    return True


def main(argv=None):
    from make_large_folders import main as folders_main  # beside this script

    folders_main(argv, write_folders, __doc__, "rendered 160 x 120 PNG")


if __name__ == "__main__":
    main()
