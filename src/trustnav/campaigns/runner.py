"""Run a campaign on dask.distributed: a LocalCluster over loopback by default, or any scheduler.

Episodes go out as Dask tasks (``batch`` episodes each, :func:`auto_batch` by default), results are appended to
``records.jsonl`` as they complete, a rerun skips every episode whose key is already recorded,
a failing episode is a record with its error (never the end of the campaign), and a task lost
with its worker (Dask retries it elsewhere first) becomes failed records of its episodes.
"""

from __future__ import annotations

import json
import logging
import os
import signal
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from trustnav.campaigns.episodes import OUTCOME_FIELDS, record_head, run_batch
from trustnav.campaigns.records import RecordStore
from trustnav.campaigns.spec import CampaignSpec, EpisodeTask
from trustnav.progress import Progress

__all__ = ["CAMPAIGN_FILES", "CampaignFolderError", "RunReport", "auto_batch", "check_campaign_folder", "dask_client",
           "run_campaign"]  # fmt: skip

#: What a campaign folder holds (``spec.json`` names its campaign).
CAMPAIGN_FILES = ("spec.json", "spec.json.part", "records.jsonl", "runs.jsonl", "summary.json", "summary.md", "figures")

#: Environment of LocalCluster worker processes: one BLAS / numba thread each (no oversubscription).
WORKER_ENV = {
    "OMP_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
    "NUMBA_NUM_THREADS": "1",
    "MPLBACKEND": "Agg",
}


@dataclass(frozen=True)
class RunReport:
    """What one invocation did: episodes in the spec, already recorded, run now, failed now, wall time."""

    episodes: int
    skipped: int
    ran: int
    failed: int
    wall_s: float
    workers: int
    scheduler: str

    def __post_init__(self) -> None:
        if min(self.episodes, self.skipped, self.ran, self.failed, self.workers) < 0:
            raise ValueError("RunReport counts must be >= 0")


def _default_workers() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


@contextmanager
def _sigint_held() -> Iterator[None]:
    """Ctrl-C held back while a LocalCluster starts (main thread; elsewhere nothing changes).

    SIGINT is blocked in this thread, so the event-loop thread the cluster starts, and every worker
    process started from it (restarts included), inherit the block: a Ctrl-C at the terminal reaches
    the whole process group, and only this process acts on it (cancels, closes the cluster) instead
    of every worker printing a traceback. A Ctrl-C meanwhile is not lost: it is raised (as
    KeyboardInterrupt) when the cluster is up.
    """
    if threading.current_thread() is not threading.main_thread() or not hasattr(signal, "pthread_sigmask"):
        yield
        return
    from multiprocessing import resource_tracker

    # started now, not from the cluster's event-loop thread: starting it unblocks SIGINT in its thread
    resource_tracker.ensure_running()
    caught: list[int] = []
    old_handler = signal.signal(signal.SIGINT, lambda signum, frame: caught.append(signum))
    old_mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        # the mask first, while our handler is still in place: a Ctrl-C that the kernel gave to
        # another thread (one with SIGINT unblocked) can reach Python's handler at any bytecode; were
        # the default handler back first, its KeyboardInterrupt could cut this block short and leave
        # SIGINT blocked in the main thread for good
        try:
            signal.pthread_sigmask(signal.SIG_SETMASK, old_mask)  # a pending Ctrl-C is delivered here
        finally:
            signal.signal(signal.SIGINT, old_handler)
    if caught:
        raise KeyboardInterrupt


@contextmanager
def dask_client(scheduler: str | None = None, workers: int | None = None) -> Iterator[Any]:
    """A connected :class:`distributed.Client`; closes it (and the LocalCluster it made) on exit.

    ``scheduler``: address of a running scheduler (``tcp://host:8786``). Otherwise a LocalCluster
    of ``workers`` single-threaded worker processes (default: the cores this process may use) on
    127.0.0.1 with free ports, no dashboard.
    """
    from distributed import Client, LocalCluster

    cluster = client = None
    try:
        if scheduler:
            client = Client(scheduler)
        else:
            n = workers or _default_workers()
            # the worker processes never see a Ctrl-C meant for this command (see _sigint_held)
            with _sigint_held():
                cluster = LocalCluster(
                    n_workers=n,
                    threads_per_worker=1,
                    processes=True,
                    host="127.0.0.1",
                    dashboard_address=None,
                    # no dashboard; the scheduler's small HTTP server on a free loopback port (not 8787)
                    scheduler_kwargs={"dashboard": False, "dashboard_address": "127.0.0.1:0"},
                    # quiet workers: an episode's error is in its record, a lost task's in its failed records;
                    # what Dask itself logs as errors are the heartbeats of busy workers cut off by a close
                    silence_logs=logging.CRITICAL,
                    env=WORKER_ENV,
                )
            client = Client(cluster)
        yield client
    finally:
        if client is not None:
            client.close()
        if cluster is not None:
            cluster.close()


def auto_batch(episodes: int, workers: int) -> int:
    """Episodes per task when the spec says ``auto``: about 50 tasks per worker (load balance and a
    small loss when a worker dies) but at most 16 episodes per task; 1 for small campaigns."""
    return max(1, min(16, episodes // (50 * max(1, workers))))


def _lost(task: EpisodeTask, exc: BaseException) -> dict[str, Any]:
    """The record of an episode whose task never returned (worker lost, unpicklable result...)."""
    rec: dict[str, Any] = {
        **record_head(task),
        "status": "failed",
        "error": f"{type(exc).__name__}: {exc}",
        "traceback": None,
        "wall_s": None,
    }
    rec.update(dict.fromkeys(OUTCOME_FIELDS))
    return rec


class CampaignFolderError(ValueError):
    """An output folder that holds another campaign or files that are not a campaign's."""


def _listing(names: list[str], most: int = 3) -> str:
    return ", ".join(names[:most]) + (f" and {len(names) - most} more" if len(names) > most else "")


def check_campaign_folder(spec: CampaignSpec, out: str | Path) -> None:
    """Refuse (:class:`CampaignFolderError`, one line naming the folder and what it holds) a campaign
    folder ``out`` that is a file, holds another campaign (its ``spec.json`` names another campaign) or
    holds files that are not a campaign's. New, empty and ``spec``'s own folders pass: a campaign
    resumes only into its own folder (same name; a grown spec counts as the same campaign)."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise CampaignFolderError(f"--out {out} is a file, expected a folder for campaign {spec.name!r}")
    if not out.is_dir():
        return
    names = sorted(p.name for p in out.iterdir())
    if not names:
        return
    spec_file = out / "spec.json"
    if spec_file.is_file():
        try:
            doc = json.loads(spec_file.read_text())
            theirs = doc.get("name") if isinstance(doc, dict) else None
        except (OSError, UnicodeDecodeError, json.JSONDecodeError):
            theirs = None
        if not isinstance(theirs, str):
            raise CampaignFolderError(
                f"--out {out} holds a spec.json that is not a trustnav campaign's: choose another folder "
                f"for campaign {spec.name!r}"
            )
        if theirs != spec.name:
            n = sum(1 for _ in RecordStore(out / "records.jsonl"))
            raise CampaignFolderError(
                f"--out {out} holds campaign {theirs!r} ({n} records), not {spec.name!r}: a folder resumes only "
                "its own campaign; choose another folder"
            )
        return
    foreign = [n for n in names if n not in CAMPAIGN_FILES]
    if foreign:
        raise CampaignFolderError(
            f"--out {out} holds {len(foreign)} files that are not a campaign's ({_listing(foreign)}): choose a "
            f"new or empty folder for campaign {spec.name!r}"
        )
    raise CampaignFolderError(
        f"--out {out} holds campaign files ({_listing(names)}) but no spec.json naming their campaign: choose a "
        f"new or empty folder for campaign {spec.name!r}"
    )


def _write_spec(spec: CampaignSpec, out: Path) -> None:
    doc = {
        "name": spec.name,
        "source": spec.source,
        "points": [
            {"sweep": p.sweep, "point": p.index, "point_id": p.point_id, "family": p.family, "params": dict(p.params)}
            for p in spec.points()
        ],
    }
    tmp = out / "spec.json.part"
    tmp.write_text(json.dumps(doc, indent=2, default=str) + "\n")
    tmp.replace(out / "spec.json")  # whole or not at all: it names the campaign of the folder


def run_campaign(
    spec: CampaignSpec,
    out: str | Path,
    scheduler: str | None = None,
    workers: int | None = None,
    progress: bool = True,
    retry_failed: bool = False,
    batch: int | None = None,
    on_record: Callable[[dict[str, Any]], None] | None = None,
) -> RunReport:
    """Run every episode of ``spec`` not yet recorded in ``out/records.jsonl`` (see the module doc).

    ``retry_failed`` runs failed episodes again (their new record replaces the old); ``batch``
    overrides the spec's episodes per task. Writes ``spec.json`` (the spec and its points) and
    appends to ``records.jsonl``; the summary is :func:`trustnav.campaigns.summary.write_outputs`.
    A folder of another campaign or of other files is refused first (:func:`check_campaign_folder`).
    """
    out = Path(out)
    check_campaign_folder(spec, out)
    out.mkdir(parents=True, exist_ok=True)
    _write_spec(spec, out)
    store = RecordStore(out / "records.jsonl")
    done = store.latest()
    tasks = spec.tasks()
    todo = [t for t in tasks if t.key not in done or (retry_failed and done[t.key].get("status") == "failed")]
    size = batch or spec.batch
    n_workers = 0
    failed = 0
    t0 = time.perf_counter()
    if todo:
        from distributed import as_completed

        run_id = uuid.uuid4().hex[:8]

        bar = Progress(len(todo), spec.name, "ep", enabled=progress)  # a log line every few s off a terminal
        with dask_client(scheduler, workers) as client, store:
            n_workers = len(client.scheduler_info().get("workers", {}))
            size = size or auto_batch(len(todo), n_workers)
            batches = [todo[i : i + size] for i in range(0, len(todo), size)]
            futures = client.map(
                run_batch, batches, pure=False, key=[f"{spec.name}-{run_id}-{i}" for i in range(len(batches))]
            )
            of = dict(zip((f.key for f in futures), batches, strict=True))
            try:
                for fut in as_completed(futures):
                    try:
                        recs = fut.result()
                    except Exception as exc:  # the task itself was lost: its episodes are failed records
                        recs = [_lost(t, exc) for t in of[fut.key]]
                    for rec in recs:
                        store.append(rec)
                        failed += rec["status"] == "failed"
                        if on_record is not None:
                            on_record(rec)
                    bar.update(len(recs))
                    bar.note(failed=failed)
                    fut.release()
            finally:
                bar.close(finished=bar.n >= len(todo))
                client.cancel(futures)
    return RunReport(
        episodes=len(tasks),
        skipped=len(tasks) - len(todo),
        ran=len(todo),
        failed=failed,
        wall_s=time.perf_counter() - t0,
        workers=n_workers,
        scheduler=scheduler or "local",
    )
