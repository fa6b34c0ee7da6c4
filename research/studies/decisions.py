"""The decision benchmark: what the commands accept with their defaults, beside SeqSLAM's ratio test, same frames.

Every row runs the product as a user does (``vpr compare``, ``vpr learn`` +
``vpr localize``, ``vpr loops``; defaults, ground truth by positions along the
route) and prints, for ``rshosm-seq`` and for SeqSLAM on the same frames:
accepted, P(acc), R(acc) (``-``: a precision over nothing accepted), and what the
run said of the query's speed (``matched again``: the run followed a speed it read;
``said``: a line on stderr; ``-``: nothing).

Three settings:

- **database -> query** (``compare``, ``localize``; SeqSLAM from ``compare``, and
  SeqSLAM online beside ``localize``: ``seqslam.causal=true``, each frame's sequence
  the frames up to it, as an online run sees them):
  Nordland summer -> winter every file, first 300 / 1,000 / all 3,576 (right within
  1 file, soft 3); every 10th file (358) at the same speed, 2x (the query every
  20th), 0.5x (every 5th) and reversed; Gardens Point day_left -> day_right (right
  within 2 frames, soft 8) at 1x, 2x, 0.5x (the map every 2nd) and reversed.
- **one run** (``vpr loops FOLDER``; SeqSLAM: ``--method seqslam``): Gardens Point
  day_left then day_right in one folder, and with the revisit at 2x; Nordland
  summer then winter every 10th; RTAB-Map's indoor loop (its own ground truth);
  forward-only drives (Nordland summer every 10th, every file first 1,000, Gardens
  Point day_left), where every closure is false.
- **sessions** (``vpr loops S1 S2``): the database -> query pairs above as two
  sessions of one stream, at 1x, 2x, 0.5x and reversed; and two short sessions (the
  first 111 frames of Gardens Point's two traverses, of Nordland's every 10th).

Runs are kept under ``--out`` (a second call prints the table from them). ``--arg`` (repeatable) is added to
every run of ``rshosm-seq`` (e.g. ``--arg=--method-conf --arg=rshosm-seq.confirm_frames=0``, ``--arg=--query-speed
--arg=as-is``): a mechanism taken out, the table with and without it; ``--base DIR`` reads SeqSLAM's loop runs
from a run of the defaults instead of running them again.

Usage: VPR_DATASETS=../shared/datasets python -m research.studies.decisions [--out results/decisions] [--only SETTING]
    [--arg ARG ...] [--base DIR]
"""
from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import time
import warnings
from pathlib import Path

from pipelines.cli import main as vpr
from research.studies.cells import decisions_cell
from research.studies.speed_models import linked, positions_csv

SETTINGS = ("match", "one_run", "sessions")
#: arguments added to every run of rshosm-seq (``--arg``) and the run whose SeqSLAM loops are read (``--base``)
EXTRA: list[str] = []
BASE: list[Path] = []
#: stderr words of a run that says the query's speed
SPEED_WORDS = ("driven faster", "driven slower", "another speed", "faster than", "slower than")


def data_root() -> Path:
    root = Path(os.environ.get("VPR_DATASETS", Path(__file__).resolve().parents[3] / "shared" / "datasets"))
    if not (root / "nordland_trimmed").is_dir():
        raise SystemExit(f"{root}: no nordland_trimmed; set VPR_DATASETS to the shared datasets")
    return root


def run(argv: list, out: Path) -> tuple[dict, list[str]]:
    """``vpr ARGV --out OUT`` once (kept: a later call reads it); its metrics.json's methods and the lines it said on
    stderr about the speed."""
    said = out / "said.txt"
    if not (out / "metrics.json").exists():
        err = io.StringIO()
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err), \
                warnings.catch_warnings(record=True) as w:
            warnings.simplefilter("always")
            code = vpr([str(a) for a in [*argv, "--out", out, "--no-progress"]])
        lines = err.getvalue().splitlines() + [str(x.message) for x in w]
        if code:
            raise SystemExit(f"vpr {' '.join(map(str, argv))}: exit {code}\n" + "\n".join(lines[-5:]))
        out.mkdir(parents=True, exist_ok=True)
        said.write_text("\n".join(x for x in lines if any(s in x for s in SPEED_WORDS)))
    text = said.read_text() if said.exists() else ""
    return json.loads((out / "metrics.json").read_text())["methods"], [x for x in text.splitlines() if x]


def speed_cell(m: dict, said: list[str]) -> str:
    """What a run did with the query's speed: matched again at another sampling, said, or nothing."""
    s = m.get("sampling") or {}
    again = []
    if s.get("db_step") or s.get("query_step"):
        again.append(f"one {'map' if s.get('db_step') else 'query'} frame in {s.get('db_step') or s.get('query_step')}")
    again += [f"session {f['session']} at {f['speed']:.2f}, one {'earlier' if f.get('db_step') else 'later'} frame in "
              f"{f.get('db_step') or f.get('query_step')}" for f in s.get("sessions", [])
              if f.get("db_step") or f.get("query_step")]
    again += [f"frames {r['frames'][0]}-{r['frames'][1]} at {r['speed']:.2f} ({r['closures']} closures)"
              for r in s.get("runs", [])]
    if again:
        return "matched again: " + "; ".join(again)
    return f"said ({len(said)})" if said else "-"


class Streams:
    """The shared datasets' streams as folders of links, with each frame's position along the route (a CSV)."""

    def __init__(self, data: Path, root: Path):
        self.root = root / "streams"
        gp, nl = data / "gardens_point_day", data / "nordland_trimmed"
        self.left, self.right = sorted((gp / "day_left").iterdir()), sorted((gp / "day_right").iterdir())
        self.summer, self.winter = sorted((nl / "summer").iterdir()), sorted((nl / "winter").iterdir())
        self.rtabmap = data / "rtabmap_loop"

    def folder(self, name: str, files: list[Path], number) -> tuple[Path, Path]:
        """A folder of ``files`` (links, named by their place in it) and its positions CSV."""
        folder, x = linked(self.root, name, files, number, numbered=True)
        return folder, positions_csv(self.root / f"{name}.csv", x)

    def gp(self, name: str, files: list[Path]):
        return self.folder(name, files, lambda f: int(f.stem.removeprefix("Image")))

    def nl(self, name: str, files: list[Path], unit: int = 1):
        """Nordland files are numbered 10 apart; ``unit``: files a frame of the stream stands for (every 10th: 10)."""
        return self.folder(name, files, lambda f: int(f.stem.split("-")[-1]) / 10 / unit)


def match_pairs(s: Streams):
    """(name, database (folder, positions), query (folder, positions), radius, soft) of the database -> query rows."""
    yield "Nordland every file, first 300", s.nl("s300", s.summer[:300]), s.nl("w300", s.winter[:300]), 1, 3
    yield "Nordland every file, first 1,000", s.nl("s1000", s.summer[:1000]), s.nl("w1000", s.winter[:1000]), 1, 3
    yield "Nordland every file, all 3,576", s.nl("s_all", s.summer), s.nl("w_all", s.winter), 1, 3
    s10 = s.nl("s10", s.summer[::10], 10)
    yield "Nordland every 10th (358), 1x", s10, s.nl("w10", s.winter[::10], 10), 1, 3
    yield "Nordland every 10th, query 2x", s10, s.nl("w20", s.winter[::20], 10), 1, 3
    yield "Nordland every 10th, query 0.5x", s10, s.nl("w5", s.winter[::5], 10), 1, 3
    yield "Nordland every 10th, query reversed", s10, s.nl("w10_rev", s.winter[::10][::-1], 10), 1, 3
    left = s.gp("left", s.left)
    yield "Gardens Point, 1x", left, s.gp("right", s.right), 2, 8
    yield "Gardens Point, query 2x", left, s.gp("right2", s.right[::2]), 2, 8
    yield "Gardens Point, query 0.5x", s.gp("left2", s.left[::2]), s.gp("right", s.right), 2, 8
    yield "Gardens Point, query reversed", left, s.gp("right_rev", s.right[::-1]), 2, 8


def short_sessions(s: Streams):
    """(name, earlier session, later session, radius, soft) of two short sessions (111 frames each)."""
    yield ("Gardens Point, 111 frames each", s.gp("left111", s.left[:111]), s.gp("right111", s.right[:111]), 2, 8)
    yield ("Nordland every 10th, 111 frames each", s.nl("s10_111", s.summer[::10][:111], 10),
           s.nl("w10_111", s.winter[::10][:111], 10), 1, 3)


def one_run_streams(s: Streams):
    """(name, folder, ground-truth options, exclude or None) of the one-run rows."""
    yield "Gardens Point day_left + day_right (400)", s.gp("gp_lr", s.left + s.right), 2, 8
    yield "Gardens Point, the revisit at 2x (300)", s.gp("gp_lr2", s.left + s.right[::2]), 2, 8
    s10 = s.summer[::10]
    yield "Nordland summer + winter every 10th (716)", s.nl("nl_sw10", s10 + s.winter[::10], 10), 1, 3
    yield "RTAB-Map indoor loop (84)", (s.rtabmap / "images", s.rtabmap / "loop_gt.bmp"), None, None
    yield "forward only: Nordland summer every 10th (358)", s.nl("fw_s10", s10, 10), 1, 3
    yield "forward only: Nordland summer every file, first 1,000", s.nl("fw_s1000", s.summer[:1000]), 1, 3
    yield "forward only: Gardens Point day_left (200)", s.gp("fw_left", s.left), 2, 8


def _gt(p, radius, soft) -> list:
    if radius is None:
        return ["--gt", p]
    return ["--gt", p, "--radius", radius, "--gt-soft", soft]


def match_table(s: Streams, out: Path) -> None:
    print("\n### Database -> query: accepted, P(acc), R(acc)\n")
    print("| stream | compare rshosm-seq | localize rshosm-seq | SeqSLAM (compare) | SeqSLAM online (causal) | "
          "speed: compare / localize |")
    print("|---|---|---|---|---|---|")
    cache = ["--cache", out / "cache"]
    for name, (db, p_db), (q, p_q), radius, soft in match_pairs(s):
        key = f"{db.name}-{q.name}"
        gt = ["--gt", p_db, p_q, "--radius", radius, "--gt-soft", soft]
        cmp, said_c = run(["compare", db, q, "--methods", "rshosm-seq,seqslam", *gt, *cache, *EXTRA],
                          out / "compare" / key)
        loc, said_l = run(["localize", learned_map(db, p_db, out), q, "--gt", p_q, "--radius", radius, "--gt-soft",
                           soft, *EXTRA], out / "localize" / key)
        causal, _ = run(["compare", db, q, "--methods", "seqslam", "--method-conf", "seqslam.causal=true", *gt, *cache],
                        out / "compare_causal" / key)
        r = loc["rshosm-seq"]
        print(f"| {name} | {decisions_cell(cmp['rshosm-seq'], frames=False)} | {decisions_cell(r, frames=False)} | "
              f"{decisions_cell(cmp['seqslam'], frames=False)} | {decisions_cell(causal['seqslam'], frames=False)} | "
              f"{speed_cell(cmp['rshosm-seq'], said_c)} / "
              f"{speed_cell(r, said_l)} |", flush=True)


def learned_map(db: Path, positions: Path, out: Path) -> Path:
    """The map ``vpr learn`` writes of ``db`` with its positions, learned once under ``out``."""
    the_map = out / "maps" / f"{db.name}.npz"
    if not the_map.exists():
        err = io.StringIO()
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err), \
                warnings.catch_warnings(action="ignore"):
            if vpr([str(a) for a in ["learn", db, "--gt", positions, "--out", the_map, "--no-progress"]]):
                raise SystemExit(f"vpr learn {db}: {err.getvalue()[-500:]}")
    return the_map


def one_run_table(s: Streams, out: Path) -> None:
    print("\n### One run (vpr loops FOLDER): accepted, P(acc), R(acc); forward-only drives: every closure is false\n")
    print("| stream | rshosm-seq | SeqSLAM | speed said (rshosm-seq) |")
    print("|---|---|---|---|")
    for name, (folder, p), radius, soft in one_run_streams(s):
        key = folder.name if folder.name != "images" else "rtabmap"
        got = {m: _loops([folder, "--method", m, *_gt(p, radius, soft)], out, "loops", f"{key}-{m}")
               for m in ("rshosm-seq", "seqslam")}
        m = got["rshosm-seq"][0]["rshosm-seq"]
        print(f"| {name} | {decisions_cell(m, frames=False)} | "
              f"{decisions_cell(got['seqslam'][0]['seqslam'], frames=False)} | {speed_cell(m, got['rshosm-seq'][1])} |",
              flush=True)


def sessions_table(s: Streams, out: Path) -> None:
    print("\n### Sessions (vpr loops S1 S2): closures of the later session onto the earlier; accepted, P(acc), "
          "R(acc)\n")
    print("| stream | rshosm-seq | SeqSLAM | speed said (rshosm-seq) |")
    print("|---|---|---|---|")
    pairs = [p for p in match_pairs(s) if "first" not in p[0] and "all" not in p[0]]  # every file: the match rows
    for name, (db, p_db), (q, p_q), radius, soft in [*pairs, *short_sessions(s)]:
        key = f"{db.name}-{q.name}"
        gt = ["--gt", p_db, p_q, "--radius", radius, "--gt-soft", soft]
        got = {m: _loops([db, q, "--method", m, *gt], out, "sessions", f"{key}-{m}") for m in ("rshosm-seq", "seqslam")}
        cells = [decisions_cell(_later(got[m][0][m]), frames=False) for m in ("rshosm-seq", "seqslam")]
        m = got["rshosm-seq"][0]["rshosm-seq"]
        print(f"| {name} | {' | '.join(cells)} | {speed_cell(m, got['rshosm-seq'][1])} |", flush=True)


def _loops(argv: list, out: Path, setting: str, key: str):
    """``vpr loops ARGV`` kept under ``out/setting/key``: rshosm-seq's with :data:`EXTRA`, SeqSLAM's read from
    :data:`BASE` where it is there."""
    if argv[argv.index("--method") + 1] == "rshosm-seq":
        return run(["loops", *argv, *EXTRA], out / setting / key)
    kept = [b / setting / key for b in BASE if (b / setting / key / "metrics.json").exists()]
    return run(["loops", *argv], kept[0] if kept else out / setting / key)


def _later(m: dict) -> dict:
    """The closures of the later session onto the earlier one (metrics.json's ``sessions``)."""
    rows = [r for r in m.get("sessions") or [] if r["session"] != r["onto"]]
    if len(rows) != 1:
        raise SystemExit(f"expected one pair of sessions, got {m.get('sessions')}")
    r = rows[0]
    return {"n_accepted": r["accepted"], "precision_accepted": r["precision"], "recall_accepted": r["recall"] or 0.0}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("results/decisions"))
    ap.add_argument("--only", choices=SETTINGS, action="append", help="one setting (repeatable); default all")
    ap.add_argument("--arg", action="append", default=[], help="an argument added to every run of rshosm-seq")
    ap.add_argument("--base", type=Path, help="read SeqSLAM's loop runs from this --out of the defaults")
    args = ap.parse_args(argv)
    EXTRA[:] = args.arg
    BASE[:] = [args.base] if args.base else []
    streams = Streams(data_root(), args.out)
    t = time.perf_counter()
    tables = {"match": match_table, "one_run": one_run_table, "sessions": sessions_table}
    for name in args.only or SETTINGS:
        tables[name](streams, args.out)
    print(f"\n({time.perf_counter() - t:.0f} s)")


if __name__ == "__main__":
    main()
