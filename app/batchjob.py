"""The jobs of `photoar batch`: reading the JSON Lines file, input keys, and the work each Dask
worker runs (app/cmd_batch.py submits it).

A job line is `{"id": ..., "scene": ..., "options": {...}}`: the keys of `options` are
`photoar composite`'s long option names without the leading dashes, the values what the command
line takes (a number, a string, a list for an "X,Y,Z" value, `true` for a flag). Relative paths
(scene, object, placement, cache) are taken from the JOBS file's folder. Each job is checked up
front against composite's own parser, so a bad option is that job's one-line error, worded as
`photoar composite` words it.

A job's outputs are DIR/<id>/composite.png, composite.exr, report.json (those of `photoar
composite`) and batch_job.json (the job and its input key: a hash of the options, the sizes and
modification times of the scene folder's and the mesh's files, and the source of photoar itself).
A folder whose batch_job.json holds the same key is up to date and not computed again.

On a worker, one engine per room and engine parameters is kept in memory (the last ENGINES_KEPT),
so the jobs of a room after the first composite without reloading its precompute; one lock runs
the jobs of a worker process one at a time (an engine is not shared between threads: give
workers one thread each, more processes instead).
"""
from __future__ import annotations

import argparse
import collections
import contextlib
import dataclasses
import hashlib
import io
import json
import logging
import os
import threading
import time
from pathlib import Path

log = logging.getLogger("photoar")

JOB_FILE = "batch_job.json"  # the job and its input key, in DIR/<id>/
OUTPUTS = ("composite.png", "composite.exr", "report.json", JOB_FILE)


def is_partial(name: str) -> bool:
    """A folder of DIR that a job being written uses (recon.io.AtomicFolder / AtomicOutput's
    hidden `.<id>.partial-*`, `.<id>.old-*`): what a killed job leaves behind."""
    return name.startswith(".") and (".partial-" in name or ".old-" in name)
ENGINES_KEPT = 2  # engines a worker keeps in memory (each holds a room's precompute: ~100s of MB)
_RESERVED = {"out": "the output folder is DIR/<id>, set by photoar batch",
             "help": "not a composite option", "quiet": "set by photoar batch", "verbose": "set by photoar batch"}
_CODE_DIRS = ("app", "lighting", "recon", "kernels")


@dataclasses.dataclass(frozen=True)
class Job:
    """One valid job line: composite's arguments (paths absolute) and its keys."""

    id: str
    line: int
    scene: Path  # absolute scene folder
    options: dict  # as in the file
    argv: tuple[str, ...]  # composite's options (no scene, no --out)
    engine_key: str  # room + engine parameters: the jobs with one key share a precompute and an engine
    input_key: str  # what the outputs depend on (options, input files, code)


@dataclasses.dataclass(frozen=True)
class BadJob:
    """A job line refused up front, with its one-line error."""

    id: str
    line: int
    error: str


def one_line(e: BaseException) -> str:
    """An exception as one line: photoar's own errors as their message (it names the file),
    anything else with its type."""
    from recon.io import SceneError

    msg = " ".join(str(e).split())
    if isinstance(e, (SceneError, FileNotFoundError, RuntimeError, ValueError)) and msg:
        return msg
    return f"{type(e).__name__}: {msg}" if msg else type(e).__name__


_PARSER = None


def composite_parser() -> argparse.ArgumentParser:
    """`photoar`'s parser (composite's options, their types and checks), built once per process."""
    global _PARSER
    if _PARSER is None:
        from app.cli import build_parser

        _PARSER = build_parser()
    return _PARSER


def _composite_actions() -> dict[str, argparse.Action]:
    """composite's long options by name without dashes ('work-res' -> its action)."""
    sub = next(a for a in composite_parser()._actions if isinstance(a, argparse._SubParsersAction))
    comp = sub.choices["composite"]
    return {s[2:]: act for s, act in comp._option_string_actions.items() if s.startswith("--")}


def parse_composite(scene: Path, out: Path, argv) -> argparse.Namespace:
    """composite's arguments parsed by its own parser; ValueError with the parser's one-line
    message (`photoar composite: error: ...`) when it refuses them."""
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err):
            a = composite_parser().parse_args(["-q", "composite", str(scene), "--out", str(out), *argv])
    except SystemExit:
        raise ValueError(" ".join(err.getvalue().split()) or "photoar composite refused the options") from None
    return a


def _option_argv(options: dict, base: Path) -> list[str]:
    """composite's command line of a job's `options`; ValueError naming the option otherwise."""
    actions = _composite_actions()
    argv: list[str] = []
    for key, value in options.items():
        if key in _RESERVED:
            raise ValueError(f"option {key!r}: {_RESERVED[key]}")
        act = actions.get(key)
        if act is None:
            raise ValueError(f"option {key!r}: not an option of photoar composite (keys are its long option names "
                             f"without the dashes, e.g. 'object', 'place', 'work-res')")
        flag = "--" + key
        if act.nargs == 0:  # a flag: true or false
            if not isinstance(value, bool):
                raise ValueError(f"option {key!r} is a flag: give true or false, got {json.dumps(value)}")
            if value:
                argv.append(flag)
            continue
        if isinstance(value, bool) or value is None or isinstance(value, dict):
            raise ValueError(f"option {key!r} takes a value, got {json.dumps(value)}")
        if isinstance(value, list):
            if not value or any(isinstance(v, (bool, list, dict)) or v is None for v in value):
                raise ValueError(f"option {key!r}: a list must hold numbers or strings, got {json.dumps(value)}")
            text = ",".join(str(v) for v in value)
        else:
            text = str(value)
        if act.type is Path and text and not Path(text).expanduser().is_absolute():
            text = str((base / text).resolve())
        argv += [flag, text]
    return argv


def _files_fingerprint(root: Path) -> list:
    """(relative path, size, mtime ns) of every file under `root` (or of `root` itself)."""
    if root.is_file():
        st = root.stat()
        return [[root.name, st.st_size, st.st_mtime_ns]]
    rows = []
    for dirpath, dirnames, filenames in os.walk(root):
        dirnames.sort()
        for name in sorted(filenames):
            p = Path(dirpath) / name
            with contextlib.suppress(OSError):
                st = p.stat()
                rows.append([str(p.relative_to(root)), st.st_size, st.st_mtime_ns])
    return rows


_CODE_VERSION: str | None = None


def code_version() -> str:
    """Hash of photoar's own source (its packages' .py files): other code, other outputs."""
    global _CODE_VERSION
    if _CODE_VERSION is None:
        h = hashlib.sha256()
        root = Path(__file__).resolve().parents[1]
        for d in _CODE_DIRS:
            for p in sorted((root / d).rglob("*.py")):
                h.update(str(p.relative_to(root)).encode() + b"\0" + p.read_bytes() + b"\0")
        _CODE_VERSION = h.hexdigest()
    return _CODE_VERSION


def _digest(data) -> str:
    return hashlib.sha256(json.dumps(data, sort_keys=True, default=str).encode()).hexdigest()


def read_jobs(path: str | os.PathLike, cache: Path | None = None) -> list[Job | BadJob]:
    """The jobs of a JSON Lines file, in order: each a Job, or a BadJob with its one-line error
    (`<file>:<line>: <problem>`). `cache`: the precompute folder of jobs that give none.
    FileNotFoundError / ValueError naming the file when it is missing or holds no job."""
    from app.cli import _params

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: jobs file not found")
    base = path.resolve().parent
    jobs: list[Job | BadJob] = []
    seen: dict[str, int] = {}
    fingerprints: dict[Path, list] = {}
    for n, text in enumerate(path.read_text().splitlines(), 1):
        if not text.strip():
            continue
        where = f"{path}:{n}"
        try:
            d = json.loads(text)
        except json.JSONDecodeError as e:
            jobs.append(BadJob(f"line {n}", n, f"{where}: not a JSON object: {e.msg}"))
            continue
        jid = d.get("id") if isinstance(d, dict) else None
        if not isinstance(d, dict):
            jobs.append(BadJob(f"line {n}", n, f"{where}: expected an object with id, scene and options"))
            continue
        if not isinstance(jid, str) or not jid or jid in (".", "..") or jid.startswith(".") \
                or "/" in jid or "\\" in jid or "\0" in jid:
            jobs.append(BadJob(f"line {n}", n, f"{where}: 'id' must be a non-empty folder name (no '/', not "
                                               f"starting with '.'), got {json.dumps(jid)}"))
            continue
        if jid in seen:
            jobs.append(BadJob(f"line {n}", n, f"{where}: id {jid!r} repeats line {seen[jid]}"))
            continue
        seen[jid] = n
        try:
            extra = sorted(set(d) - {"id", "scene", "options"})
            if extra:
                raise ValueError(f"unknown field {extra[0]!r} (a job has id, scene and options)")
            scene, options = d.get("scene"), d.get("options", {})
            if not isinstance(scene, str) or not scene:
                raise ValueError(f"'scene' must be a scene folder, got {json.dumps(scene)}")
            if not isinstance(options, dict):
                raise ValueError(f"'options' must be an object, got {json.dumps(options)}")
            scene_dir = (base / Path(scene).expanduser()).resolve()
            if not (scene_dir / "scene.json").is_file():
                raise ValueError(f"{scene_dir}: scene folder not found" if not scene_dir.is_dir()
                                 else f"{scene_dir / 'scene.json'}: file not found")
            argv = _option_argv(options, base)
            if cache is not None and "cache" not in options:
                argv += ["--cache", str(Path(cache).resolve())]
            a = parse_composite(scene_dir, Path("out"), argv)
            params = _params(a)
        except ValueError as e:
            jobs.append(BadJob(jid, n, f"{where}: {one_line(e)}"))
            continue
        if scene_dir not in fingerprints:
            fingerprints[scene_dir] = _files_fingerprint(scene_dir)
        files = {k: _files_fingerprint(Path(getattr(a, k))) for k in ("object", "placement")
                 if getattr(a, k, None) is not None and Path(getattr(a, k)).exists()}
        engine_key = _digest([str(scene_dir), fingerprints[scene_dir], repr(params), a.work_res,
                              None if a.cache is None else str(a.cache), a.device])
        input_key = _digest({"scene": str(scene_dir), "argv": argv, "scene_files": fingerprints[scene_dir],
                             "files": files, "code": code_version()})
        jobs.append(Job(jid, n, scene_dir, options, tuple(argv), engine_key, input_key))
    if not jobs:
        raise ValueError(f"{path}: no jobs (one JSON object a line)")
    return jobs


def up_to_date(out: Path, job: Job) -> bool:
    """DIR/<id> holds the job's complete outputs made with the same input key."""
    folder = out / job.id
    try:
        key = json.loads((folder / JOB_FILE).read_text()).get("input_key")
    except (OSError, ValueError, AttributeError):
        return False
    return key == job.input_key and all((folder / f).is_file() for f in OUTPUTS)


# ------------------------------------------------------------------------------ on the workers

_ENGINES: "collections.OrderedDict[str, object]" = collections.OrderedDict()
_LOCK = threading.RLock()  # one job at a time per worker process (engines are not thread-safe)


def _worker_name() -> str:
    try:
        from distributed import get_worker

        return get_worker().address
    except (ImportError, ValueError):
        return f"pid {os.getpid()}"


def _engine_for(key: str, work, params, **kw):
    """The engine of `key` from this process's memory, else built (Engine: its precompute read
    from the cache folder or computed and written there) and kept, the oldest dropped."""
    from app.engine import Engine

    if key in _ENGINES:
        _ENGINES.move_to_end(key)
        return _ENGINES[key]
    while len(_ENGINES) >= ENGINES_KEPT:
        _ENGINES.popitem(last=False)
    engine = Engine(work, params, **kw)
    _ENGINES[key] = engine
    return engine


class _Warnings(logging.Handler):
    """The photoar warnings of one job, kept for batch_report.json (workers write no log lines)."""

    def __init__(self):
        super().__init__(logging.WARNING)
        self.lines: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.lines.append(" ".join(record.getMessage().split()))


@contextlib.contextmanager
def _captured_warnings():
    h = _Warnings()
    log.addHandler(h)
    try:
        yield h.lines
    finally:
        log.removeHandler(h)


def warm(scene: str, argv: list[str], engine_key: str) -> dict:
    """Dask task: the room's engine (its precompute computed once and written to the cache folder,
    or read from it), kept in this worker's memory for the room's jobs. Returns its timings, or
    {"error": line}."""
    from app.cli import _params
    from app.composite import default_cache_dir
    from app.workres import DEFAULT_WORK_RES, working_scene
    from kernels import runtime
    from recon.scene import load_scene

    t0 = time.perf_counter()
    with _LOCK, _captured_warnings() as warnings:
        try:
            a = parse_composite(Path(scene), Path("out"), argv)
            runtime.device(a.device)
            new = engine_key not in _ENGINES
            work = working_scene(load_scene(a.scene), DEFAULT_WORK_RES if a.work_res is None else a.work_res)
            engine = _engine_for(engine_key, work, _params(a), cache_dir=a.cache if a.cache is not None
                                 else default_cache_dir(), device=a.device, quiet=True)
        except Exception as e:  # recorded for the room's jobs; the batch goes on
            return {"error": one_line(e), "worker": _worker_name()}
    return {"worker": _worker_name(), "seconds": time.perf_counter() - t0, "built": new,
            "precompute_s": engine.precompute_s, "precompute_cache_hit": bool(engine.cache_hit),
            "precompute_uncached_s": engine.pre.seconds, "warnings": warnings}


def run_job(job: Job, out: str, room: dict) -> dict:
    """Dask task: composite `job` as `photoar composite` does (its parser, app.cli.run_composite)
    with this worker's engine of the room, into a folder beside DIR/<id> renamed to it when complete.
    Returns {"status": "done", ...} or {"status": "failed", "error": line}."""
    from app.cli import run_composite
    from kernels import runtime
    from recon.io import AtomicFolder, write_json

    t0 = time.perf_counter()
    base = {"worker": _worker_name()}
    if "error" in room:
        return {**base, "status": "failed", "error": room["error"]}
    final = Path(out) / job.id
    with _LOCK, _captured_warnings() as warnings:
        try:
            # staged beside DIR/<id> and renamed to it whole (an older version replaced whole)
            with AtomicFolder(final, ours=lambda name: True) as stage:
                a = parse_composite(job.scene, stage, list(job.argv))
                runtime.device(a.device)
                report = run_composite(a, make_engine=lambda work, params, **kw: _engine_for(job.engine_key, work,
                                                                                              params, **kw))
                write_json(stage / JOB_FILE, {"id": job.id, "scene": str(job.scene), "options": job.options,
                                              "argv": list(job.argv), "input_key": job.input_key})
        except Exception as e:  # one line in batch_report.json; the batch goes on
            return {**base, "status": "failed", "error": one_line(e), "warnings": warnings}
    return {**base, "status": "done", "seconds": time.perf_counter() - t0, "frame_s": report.get("frame_s"),
            "full_resolution_s": report.get("full_resolution_s"), "warnings": warnings}
