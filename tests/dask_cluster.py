"""A real Dask cluster on 127.0.0.1 for the tests that kill a worker mid-run (`dask scheduler` + `dask worker`)."""
from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def dask_cli() -> list[str]:
    exe = Path(sys.executable).parent / "dask"
    return [str(exe)] if exe.exists() else [shutil.which("dask") or "dask"]


def stop(procs) -> None:
    for p in procs:
        if p.poll() is None:
            p.send_signal(signal.SIGTERM)
    for p in procs:
        try:
            p.wait(timeout=10)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait(timeout=10)


@contextlib.contextmanager
def cluster(tmp_path: Path, preload: Path, env: dict, names=("w1", "w2")):
    """Yield (scheduler address, {name: worker process}, log path); every process is stopped after.

    Workers: one thread, no nanny (a killed worker stays dead), ``preload`` imported in each.
    """
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]), **env}
    sched_file = tmp_path / "scheduler.json"
    log_path = tmp_path / "cluster.log"
    logs = open(log_path, "w")
    procs = [subprocess.Popen(dask_cli() + ["scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                                            "--dashboard-address", "127.0.0.1:0", "--scheduler-file", str(sched_file),
                                            "--idle-timeout", "120"],
                              env=env, stdout=logs, stderr=subprocess.STDOUT)]
    try:
        deadline = time.monotonic() + 60
        while not (sched_file.is_file() and sched_file.stat().st_size > 0):
            assert time.monotonic() < deadline, "dask scheduler did not start"
            assert procs[0].poll() is None, log_path.read_text()
            time.sleep(0.2)
        address = json.loads(sched_file.read_text())["address"]
        workers = {}
        for name in names:
            workers[name] = subprocess.Popen(
                dask_cli() + ["worker", address, "--nthreads", "1", "--no-nanny", "--no-dashboard", "--host",
                              "127.0.0.1", "--dashboard-address", "127.0.0.1:0", "--name", name, "--preload",
                              str(preload), "--death-timeout", "60", "--local-directory", str(tmp_path / name)],
                env=env, stdout=logs, stderr=subprocess.STDOUT)
            procs.append(workers[name])
        from distributed import Client

        with Client(address, timeout="30s") as watcher:
            watcher.wait_for_workers(len(names), timeout=60)
        yield address, workers, log_path
    finally:
        stop(procs)
        logs.close()


@contextlib.contextmanager
def busy_cluster(tmp_path: Path, preload_source: str):
    """:func:`cluster` whose workers import ``preload_source`` and see ``VPR_TEST_BUSY_DIR``.

    The preload marks the work a worker holds as files in that folder (so a test knows whom to
    kill); yields (scheduler address, {name: worker process}, log path, busy folder).
    """
    busy_dir = tmp_path / "busy"
    busy_dir.mkdir()
    preload = tmp_path / "slow_preload.py"
    preload.write_text(preload_source)
    with cluster(tmp_path, preload, {"VPR_TEST_BUSY_DIR": str(busy_dir)}) as (address, workers, log):
        yield address, workers, log, busy_dir


def run_in_thread(fn, timeout: float, log_path: Path):
    """``fn()`` in a thread, its result; its exception raised here; a failure naming the log after ``timeout``.

    In a thread because, should the cluster lose every worker, Dask would wait for new ones for ever.
    """
    result = {}

    def target():
        try:
            result["value"] = fn()
        except BaseException as exc:  # reported by the calling thread below
            result["error"] = exc

    run = threading.Thread(target=target, daemon=True)
    run.start()
    run.join(timeout=timeout)
    if "error" in result:
        raise result["error"]
    assert "value" in result, f"the run did not finish in {timeout} s: " + log_path.read_text()[-3000:]
    return result["value"]


def kill_a_busy_worker(workers: dict, busy_dir: Path, timeout: float = 60.0) -> list:
    """Start a thread that SIGKILLs the first worker found holding work (a ``<pid>.busy`` file in ``busy_dir``,
    :func:`busy_cluster`); returns the list it appends the killed worker's name to."""
    killed: list = []

    def kill():
        deadline = time.monotonic() + timeout
        while not killed and time.monotonic() < deadline:
            for busy in sorted(busy_dir.glob("*.busy")):
                name = next((n for n, p in workers.items() if p.pid == int(busy.stem)), None)
                if name is not None:
                    workers[name].send_signal(signal.SIGKILL)  # no goodbye to the scheduler
                    workers[name].wait(timeout=10)
                    killed.append(name)
                    break
            time.sleep(0.05)

    threading.Thread(target=kill, daemon=True).start()
    return killed


def slowed_task(module: str, name: str, seconds: float) -> str:
    """Preload source for :func:`busy_cluster`: ``module.name`` (a task function) sleeps ``seconds`` first and
    marks its worker busy meanwhile (``<pid>.busy`` in ``VPR_TEST_BUSY_DIR``), so a test can kill it mid-task."""
    return f"""
import os, time
from pathlib import Path
import {module} as target
if not hasattr(target, "unslowed_{name}"):
    target.unslowed_{name} = target.{name}

    def _slow(*args, **kwargs):
        busy = Path(os.environ["VPR_TEST_BUSY_DIR"]) / f"{{os.getpid()}}.busy"
        busy.write_text("")
        time.sleep({seconds})
        try:
            return target.unslowed_{name}(*args, **kwargs)
        finally:
            busy.unlink()

    target.{name} = _slow
"""

