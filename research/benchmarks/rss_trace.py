"""Resident memory of a command, read every second: where in a run its peak lies.

Runs COMMAND (its output to files in ``--out``), reads ``VmRSS`` from
``/proc/PID/status`` every ``--every`` seconds and prints the seconds and
megabytes every ``--print-every`` samples, then the largest sample and when.
A peak shorter than the interval is missed: ``/usr/bin/time -v`` gives the
exact maximum.

Usage: python research/benchmarks/rss_trace.py [--every 1] [--print-every 10] [--out DIR] -- COMMAND ...
e.g.   python research/benchmarks/rss_trace.py -- vpr compare DB QUERY --preset fast --tolerance 2 --out OUT
--no-progress
"""
from __future__ import annotations

import argparse
import subprocess
import time
from pathlib import Path


def rss_kb(pid: int) -> int | None:
    """The process's resident set in kB (None once it has gone)."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    except (FileNotFoundError, ProcessLookupError):
        return None
    return None


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--every", type=float, default=1.0, help="seconds between samples")
    ap.add_argument("--print-every", type=int, default=10, help="print one sample in this many")
    ap.add_argument("--out", type=Path, default=Path("."), help="folder for the command's stdout.txt / stderr.txt")
    ap.add_argument("command", nargs=argparse.REMAINDER)
    a = ap.parse_args(argv)
    cmd = a.command[1:] if a.command[:1] == ["--"] else a.command
    if not cmd:
        ap.error("give the command after --")
    a.out.mkdir(parents=True, exist_ok=True)
    with open(a.out / "stdout.txt", "w") as out, open(a.out / "stderr.txt", "w") as err:
        proc = subprocess.Popen(cmd, stdout=out, stderr=err)
        t0, peak, n = time.monotonic(), (0.0, 0), 0
        while proc.poll() is None:
            kb = rss_kb(proc.pid)
            if kb is not None:
                t = time.monotonic() - t0
                peak = max(peak, (t, kb), key=lambda p: p[1])
                if n % a.print_every == 0:
                    print(f"{t:7.0f} s {kb / 1024:9.0f} MB", flush=True)
                n += 1
            time.sleep(a.every)
    print(f"exit {proc.returncode}; largest sample {peak[1]:,} kB at {peak[0]:.0f} s")


if __name__ == "__main__":
    main()
