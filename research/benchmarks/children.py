"""A benchmark's measurement run in a fresh child process (its own peak RSS, its own threads): one JSON line back."""
from __future__ import annotations

import json
import subprocess


def child_json(cmd: list[str], what: str, env: dict | None = None) -> dict:
    """Run ``cmd`` and return the JSON of the last line it printed; a failure raises RuntimeError naming ``what``
    with the end of the child's stderr."""
    res = subprocess.run(cmd, capture_output=True, text=True, env=env)
    if res.returncode:
        raise RuntimeError(f"{what} failed:\n{res.stderr[-3000:]}")
    return json.loads(res.stdout.strip().splitlines()[-1])
