"""Batch processing on Dask (`distributed`): every recording of a manifest is one task.

By default a LocalCluster of N worker processes with one thread each on 127.0.0.1 (the pipeline
is single-threaded and holds the GIL for much of a scan, so processes, not threads, scale); with
`scheduler` a running Dask scheduler (`dask scheduler` + `dask worker`), whose workers must import
the same forestslam and see the same file system (input, truth and OUT paths are absolute).

Failures stay isolated: errors of a recording's data fail that recording inside its task; any
other exception is retried once by Dask (`retries=1`); a worker that dies while running a task
(crash, out-of-memory kill) makes the scheduler re-run it elsewhere, and after
`distributed.scheduler.allowed-failures` deaths the task ends in KilledWorker. The LocalCluster
sets that to 1 (retried once); a scheduler given by address uses its own setting (Dask's default
is 3; start it with DASK_DISTRIBUTED__SCHEDULER__ALLOWED_FAILURES=1 for the same behaviour), and
its workers their own monitoring settings (LOCAL_CONFIG shows the lean ones used locally).
"""

from __future__ import annotations

import contextlib
import logging
import os
import time
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from forestslam.batch.job import failed_row, finished_row, one_line, process_recording
from forestslam.batch.manifest import Recording
from forestslam.batch.progress import BatchProgress
from forestslam.errors import InputError
from forestslam.job import Job

log = logging.getLogger(__name__)

POLL_S = 0.2
# The local cluster's Dask settings. One retry of a task whose worker died. Dask's monitoring
# defaults (a 10 ms stack profiler in every worker, 20 ms event-loop ticks, 100 ms memory polls)
# cost 2-4 % of a core per process when idle (measured here) and more while tasks run; a batch of
# minutes-long tasks needs none of that resolution. Dask's nanny also starts its workers with
# MALLOC_TRIM_THRESHOLD_=65536 (to hand memory back to the OS early), which switches off glibc's
# dynamic mmap threshold: every array above 128 KiB is then mapped and unmapped afresh, and a
# recording took 10x the minor page faults and 8-9 % more CPU than in a plain process (measured
# on the sample, 400 scans: 12.7 vs 13.7 s). Unset (None), the workers use glibc's defaults as
# `forestslam run` does.
LOCAL_CONFIG = {
    "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None,
    "distributed.scheduler.allowed-failures": 1,
    "distributed.worker.profile.enabled": False,
    "distributed.admin.tick.interval": "1s",
    "distributed.admin.system-monitor.interval": "2s",
    "distributed.worker.memory.monitor-interval": "1s",
}


@dataclass
class BatchResult:
    rows: list[dict]  # one per recording, manifest order (job.COLUMNS)
    wall_s: float
    skipped: int  # recordings finished by an earlier call and kept

    @property
    def failed(self) -> list[dict]:
        return [r for r in self.rows if r["status"] != "ok"]


def default_workers() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def run_batch(
    recordings: list[Recording],
    out: str | Path,
    workers: int | None = None,
    scheduler: str | None = None,
    force: bool = False,
    progress: bool = True,
) -> BatchResult:
    """Process the recordings not finished yet (all with `force`) and write OUT/summary.*

    OUT is held like every job's output folder (forestslam.job.Job: a lock against a second
    batch into it, run.yaml with the outcome; the files of another command are refused), but the
    recording folders of an earlier batch are kept for resuming."""
    if workers is not None and workers < 1:
        raise InputError(f"--workers must be >= 1, not {workers}")
    if workers is not None and scheduler is not None:
        raise InputError("give either --workers (a local cluster) or --scheduler, not both")
    t0 = time.perf_counter()
    out = Path(out).absolute()
    meta = {"recordings": [r.name for r in recordings], "workers": workers, "force": force}
    meta["scheduler"] = scheduler
    inputs = [p for r in recordings for p in (r.input, r.truth, r.config, r.prior_map)]
    with Job("batch", out, meta, inputs=inputs, resume=True) as job:
        result = _run_batch(recordings, out, workers, scheduler, force, progress, t0)
        failed = len(result.failed)
        job.summary = {"ok": len(result.rows) - failed, "failed": failed, "kept": result.skipped}
        job.summary["wall_s"] = round(result.wall_s, 1)
    return result


def _run_batch(recordings, out: Path, workers, scheduler, force, progress, t0) -> BatchResult:
    from forestslam.batch.plot import plot_summary
    from forestslam.batch.summary import write_summary

    rows: dict[str, dict] = {}
    todo = []
    for rec in recordings:
        row = None if force else finished_row(rec, out)
        if row is None:
            todo.append(rec)
        else:
            rows[rec.name] = row
    skipped = len(recordings) - len(todo)
    if skipped:
        log.info("%d of %d recordings finished earlier: kept", skipped, len(recordings))
    if todo:
        reporter = BatchProgress(len(recordings), skipped, enabled=progress)
        try:
            with _client(workers, scheduler, len(todo)) as client:
                rows.update(_run_tasks(client, todo, out, reporter))
        finally:
            reporter.close()
    ordered = [rows[rec.name] for rec in recordings]
    wall_s = time.perf_counter() - t0
    write_summary(out, ordered, wall_s)
    plot_summary(out / "summary.png", ordered)
    return BatchResult(ordered, wall_s, skipped)


@contextlib.contextmanager
def _client(workers: int | None, scheduler: str | None, n_tasks: int) -> Iterator:
    """A Client of the given scheduler, or of a LocalCluster started (and stopped) here."""
    import dask
    from distributed import Client, LocalCluster

    if scheduler is not None:
        try:
            client = Client(scheduler, timeout="10s")
        except (OSError, TimeoutError, ValueError) as exc:
            raise InputError(f"cannot connect to the Dask scheduler {scheduler}: {exc}") from exc
        with client:
            if not client.scheduler_info().get("workers"):
                log.warning("scheduler %s has no worker yet: tasks wait for one", scheduler)
            yield client
        return
    n = min(workers or default_workers(), n_tasks)
    with dask.config.set(LOCAL_CONFIG):  # the workers get the config they start with
        cluster = LocalCluster(
            n_workers=n,
            threads_per_worker=1,
            processes=True,
            host="127.0.0.1",
            dashboard_address=None,
        )
        with cluster, Client(cluster) as client:
            yield client


def _run_tasks(client, todo: list[Recording], out: Path, reporter: BatchProgress) -> dict:
    """Submit one task per recording and collect their rows as they finish."""
    batch_id = uuid.uuid4().hex[:8]  # keys stay unique on a scheduler shared with others
    pending = {
        client.submit(
            process_recording,
            rec,
            str(out),
            key=f"forestslam-batch-{batch_id}-{rec.name}",
            retries=1,
            pure=False,
        ): rec
        for rec in todo
    }
    rows = {}
    while pending:
        for future in [f for f in pending if f.done()]:
            rec = pending.pop(future)
            rows[rec.name] = _row(future, rec)
            reporter.finished(rows[rec.name])
        if reporter.due() or not pending:
            running, assigned = _running(client, pending)
            scans = sum(_checkpointed_scans(out / rec.name) for rec in assigned)
            reporter.show(running, len(pending) - running, scans)
        if pending:
            time.sleep(POLL_S)
    return rows


def _row(future, rec: Recording) -> dict:
    """The task's row, or a failed row from the way its task ended."""
    from distributed import KilledWorker

    try:
        return future.result()
    except KilledWorker:
        return failed_row(
            rec.name,
            "its worker process died on every attempt (KilledWorker: crashed, or killed e.g. "
            "for memory)",
        )
    except Exception as exc:  # the task's own error after Dask's retry, or a cancelled task
        log.debug("%s: its task raised", rec.name, exc_info=exc)  # the worker's traceback, -v
        return failed_row(rec.name, one_line(exc))


def _running(client, pending: dict) -> tuple[int, list[Recording]]:
    """How many pending recordings run now, and those assigned to a worker (some may wait
    there: the scheduler can hand a worker more tasks than it has threads)."""
    try:
        processing = client.processing()
        threads = client.nthreads()
    except Exception:  # status only: never let the display stop the batch
        return 0, []
    running = sum(min(len(keys), threads.get(w, 1)) for w, keys in processing.items())
    keys = {k for keys in processing.values() for k in keys}
    return running, [rec for fut, rec in pending.items() if fut.key in keys]


def _checkpointed_scans(run_dir: Path) -> int:
    """Scans a running recording has checkpointed into run.yaml (every
    mapping.checkpoint_every_scans scans)."""
    import yaml

    try:
        with open(run_dir / "run.yaml") as f:
            meta = yaml.load(f, Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))
        summary = meta.get("summary", {})
        return int(summary.get("scans", 0)) if summary.get("status") == "running" else 0
    except (OSError, ValueError, AttributeError, yaml.YAMLError):
        return 0
