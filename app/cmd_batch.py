"""`photoar batch JOBS --out DIR [--scheduler ADDRESS] [--workers N] [--cache DIR]`: many
composites on Dask (the jobs file: app/batchjob.py; docs/batch.md).

Runs on an in-process Dask LocalCluster (one single-threaded worker process per core, or N), or
with --scheduler on an existing Dask cluster. The jobs are grouped by room and engine parameters:
one `warm` task per group computes the room's precompute once (into the cache folder) and keeps
the engine in the worker's memory; the group's jobs depend on it, so Dask sends them to the
worker that holds it (and its work stealing to an idle one, which reads the precompute from the
cache folder: shared storage on a cluster). A worker that dies in the middle of a job has the job
retried on another (the scheduler's distributed.scheduler.allowed-failures, 3 by default); a job
that fails is one line in DIR/batch_report.json and the others go on. Outputs: DIR/<id>/ (see
app/batchjob.py), DIR/batch_report.json. Exit status 0 when every job is done or up to date, 1
when some failed, 2 on bad input (the jobs file or the scheduler).
"""
from __future__ import annotations

import argparse
import contextlib
import importlib.util
import logging
import os
import shutil
import sys
import time
import uuid
from pathlib import Path

from app import batchjob
from app.batchjob import BadJob, Job, is_partial, one_line, read_jobs, up_to_date

log = logging.getLogger("photoar")
REPORT = "batch_report.json"
WAIT_FOR_WORKERS_S = 120  # an existing cluster: how long to wait for its first worker


def _workers(s: str) -> int:
    from app.cli import _positive_int

    return _positive_int(s)


def register(sub) -> None:
    p = sub.add_parser("batch", help="composite many objects into many rooms on Dask (a JSON Lines jobs file)")
    p.add_argument("jobs", type=Path, metavar="JOBS",
                   help='JSON Lines, one composite a line: {"id": ..., "scene": ..., "options": {...}} with '
                        "composite's long option names (no dashes) and values (true for a flag); relative paths "
                        "from the file's folder")
    p.add_argument("--out", type=Path, required=True, metavar="DIR",
                   help="output folder: DIR/<id>/ per job, DIR/" + REPORT)
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="an existing Dask scheduler, e.g. tcp://HOST:8786 (default: a local cluster)")
    p.add_argument("--workers", type=_workers, default=None, metavar="N",
                   help="worker processes of the local cluster (default: one per core)")
    p.add_argument("--cache", type=Path, default=None, metavar="DIR",
                   help="precompute folder for the jobs that give none; on a cluster a folder every worker sees "
                        "(default: each worker's $PHOTOAR_CACHE or ~/.cache/photoar)")
    p.set_defaults(run=run)


def run(a: argparse.Namespace) -> int:
    if a.scheduler is not None and a.workers is not None:
        raise ValueError("--workers sizes the local cluster; an existing one (--scheduler) has its own workers")
    rep = run_batch(a.jobs, a.out, scheduler=a.scheduler, workers=a.workers, cache=a.cache, quiet=a.quiet)
    print(a.out / REPORT)
    return 1 if rep["failed"] else 0


@contextlib.contextmanager
def _client(client=None, scheduler: str | None = None, workers: int | None = None):
    """A Dask client: `client` as given, one of the cluster at `scheduler`, or of a new LocalCluster
    (single-threaded worker processes; the dashboard only when bokeh is installed; Dask's own log
    lines silenced)."""
    if client is not None:
        yield client
        return
    from distributed import Client, LocalCluster

    if scheduler is not None:
        try:
            c = Client(scheduler, timeout="10s")
        except (OSError, TimeoutError) as e:
            raise RuntimeError(f"{scheduler}: no Dask scheduler answers ({' '.join(str(e).split())})") from None
        with c:
            try:  # workers started with the scheduler may still be connecting
                c.wait_for_workers(1, timeout=WAIT_FOR_WORKERS_S)
            except TimeoutError:
                raise RuntimeError(f"{scheduler}: the Dask scheduler has no workers (waited "
                                   f"{WAIT_FOR_WORKERS_S} s)") from None
            yield c
        return
    # a free port: another batch (or a notebook's cluster) may hold 8787
    # n_workers None: Dask's count of the cores this process may use (affinity, cgroup quota)
    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                      dashboard_address=":0", silence_logs=logging.ERROR) as cluster, Client(cluster) as c:
        yield c


@contextlib.contextmanager
def _dask_quiet():
    """Dask's own log lines (cluster start and stop, a worker restarted) only when they are errors:
    the batch's progress, summary and report say what happened to the jobs."""
    lg = logging.getLogger("distributed")
    level = lg.level
    lg.setLevel(logging.ERROR)
    try:
        yield
    finally:
        lg.setLevel(level)


def _dashboard(client, local: bool) -> str | None:
    """The dashboard's address when the scheduler runs one (a local cluster only has it with bokeh
    installed; without it the scheduler's web server has no dashboard to show)."""
    if local and importlib.util.find_spec("bokeh") is None:
        return None
    try:
        if "dashboard" in client.scheduler_info().get("services", {}):
            return client.dashboard_link
    except Exception:  # no dashboard to show: say nothing
        pass
    return None


def _clean_partial(out: Path) -> None:
    """Remove what killed or interrupted jobs left in DIR (one batch per DIR at a time)."""
    for p in out.iterdir():
        if p.is_dir() and is_partial(p.name):
            shutil.rmtree(p, ignore_errors=True)


def run_batch(jobs_path: str | os.PathLike, out: str | os.PathLike, client=None, scheduler: str | None = None,
              workers: int | None = None, cache: str | os.PathLike | None = None, quiet: bool = False) -> dict:
    """Run the jobs of `jobs_path` into `out` (module docstring); returns the report, also written
    as out/batch_report.json (also when interrupted: the jobs not run say so)."""
    from distributed import as_completed
    from tqdm import tqdm

    from recon.io import write_json

    t0 = time.perf_counter()
    out = Path(out)
    jobs = read_jobs(jobs_path, None if cache is None else Path(cache))
    out.mkdir(parents=True, exist_ok=True)
    _clean_partial(out)
    entries: dict[str, dict] = {}
    rooms: dict[str, dict] = {}
    todo: list[Job] = []
    for j in jobs:
        if isinstance(j, BadJob):
            entries[j.id] = {"id": j.id, "line": j.line, "status": "failed", "error": j.error}
        elif up_to_date(out, j):
            entries[j.id] = {"id": j.id, "line": j.line, "status": "skipped", "reason": "up to date"}
        else:
            entries[j.id] = {"id": j.id, "line": j.line, "status": "not run"}
            todo.append(j)
    report = {"jobs_file": str(jobs_path), "out": str(out), "scheduler": scheduler or "local", "jobs": entries,
              "rooms": rooms}

    def counts() -> dict:
        c = {s: 0 for s in ("done", "skipped", "failed", "not run")}
        for e in entries.values():
            c[e["status"]] += 1
        return c

    bar = tqdm(total=len(entries), initial=len(entries) - len(todo), desc="batch", unit="job",
               disable=quiet or None, file=sys.stderr, leave=False)

    def show() -> None:
        c = counts()
        bar.set_postfix_str(f"done {c['done'] + c['skipped']}, failed {c['failed']}, left {c['not run']}")

    show()
    try:
        if todo:
            with _dask_quiet(), _client(client, scheduler, workers) as cl:
                report["workers"] = len(cl.scheduler_info().get("workers", {}))
                link = _dashboard(cl, local=client is None and scheduler is None)
                if link and not quiet:
                    log.info("batch: Dask dashboard at %s", link)
                run_id = uuid.uuid4().hex[:8]
                groups: dict[str, list[Job]] = {}
                for j in todo:
                    groups.setdefault(j.engine_key, []).append(j)
                warms, futures = {}, {}
                for key, group in groups.items():  # one precompute per room and engine parameters, first
                    warms[key] = cl.submit(batchjob.warm, str(group[0].scene), list(group[0].argv), key,
                                          key=f"warm-{key[:12]}-{run_id}", pure=False)
                    rooms[key[:12]] = {"scene": str(group[0].scene), "jobs": [j.id for j in group]}
                for key, group in groups.items():
                    for j in group:
                        futures[cl.submit(batchjob.run_job, j, str(out), warms[key], key=f"job-{j.id}-{run_id}",
                                         pure=False)] = j
                for fut in as_completed(futures):
                    j = futures[fut]
                    try:
                        res = fut.result()
                    except Exception as e:  # the job's worker died too often (KilledWorker), or Dask failed
                        res = {"status": "failed", "error": f"{j.id}: {one_line(e)}"}
                    entries[j.id] = {"id": j.id, "line": j.line, **{k: v for k, v in res.items() if v != []}}
                    bar.update(1)
                    show()
                for key, fut in warms.items():
                    with contextlib.suppress(Exception):  # a room whose worker died: its jobs say so
                        rooms[key[:12]].update(fut.result())
    finally:
        bar.close()
        _clean_partial(out)
        c = counts()
        report.update(total=len(entries), **{k.replace(" ", "_"): v for k, v in c.items()},
                      seconds=time.perf_counter() - t0)
        report["jobs"] = list(entries.values())
        report["rooms"] = list(rooms.values())
        write_json(out / REPORT, report)
        log.info("batch: %d jobs: %d done, %d up to date, %d failed, %d not run, in %.0f s", len(entries), c["done"],
                 c["skipped"], c["failed"], c["not run"], time.perf_counter() - t0)
    return report
