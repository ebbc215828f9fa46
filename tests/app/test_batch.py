"""`photoar batch` on Dask: its composites are those of `photoar composite` run on each job alone,
and nothing is lost (a worker killed mid-job, bad jobs, an interrupted batch resumed, an existing
cluster given by --scheduler).

The composites are compared byte for byte (composite.png) and to 1e-6 relative (composite.exr,
float32): a job runs composite's own code on the same inputs with deterministic CPU kernels, so
any difference is a bug of the batch (another option, another engine state), not noise. Small
frames (--passes 4) and the session's precompute cache keep the tests short.
"""
import json
import logging
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from app.cli import main as cli
from recon.io import read_exr
from tests.conftest import ROOT, shared_scene


@pytest.fixture(scope="module")
def scenes():
    return {"w": shared_scene("window_room"), "l": shared_scene("lamps_room")}


def _jobs(scenes) -> dict[str, tuple[Path, dict, list[str]]]:
    """id -> (scene, the job's options, the same as composite's command line written by hand)."""
    w, lr = scenes["w"], scenes["l"]
    return {
        "w-own": (w, {"passes": 4}, ["--passes", "4"]),
        "w-place": (w, {"passes": 4, "place": [2.0, 0, 1.0], "yaw": 30}, ["--passes", "4", "--place", "2.0,0,1.0",
                                                                        "--yaw", "30"]),
        "w-sphere": (w, {"passes": 4, "object": str(lr / "object_sphere.ply"), "place": "3.2,0,2.6"},
                     ["--passes", "4", "--object", str(lr / "object_sphere.ply"), "--place", "3.2,0,2.6"]),
        "l-own": (lr, {"passes": 4}, ["--passes", "4"]),
        "l-chair": (lr, {"passes": 4, "object": str(w / "object_chair.ply"), "place": [1.2, 0, 2.4], "yaw": -20},
                    ["--passes", "4", "--object", str(w / "object_chair.ply"), "--place", "1.2,0,2.4", "--yaw",
                     "-20"]),
        # other engine parameters: a second engine of the room (the same precompute)
        "l-ldr": (lr, {"passes": 4, "mode": "ldr", "no-second-order": True}, ["--passes", "4", "--mode", "ldr",
                                                                             "--no-second-order"]),
    }


def _write_jobs(path: Path, jobs: dict, ids=None, extra_lines=()) -> Path:
    lines = [json.dumps({"id": i, "scene": str(s), "options": o}) for i, (s, o, _) in jobs.items()
             if ids is None or i in ids]
    path.write_text("\n".join([*lines, *extra_lines]) + "\n")
    return path


@pytest.fixture(scope="module")
def batch_run(scenes, shared_scenes_cache, tmp_path_factory):
    """The six jobs through the command line on a 2-worker local cluster."""
    tmp = tmp_path_factory.mktemp("batch")
    jobs = _jobs(scenes)
    path = _write_jobs(tmp / "jobs.jsonl", jobs)
    code = cli(["-q", "batch", str(path), "--out", str(tmp / "out"), "--workers", "2", "--cache",
                str(shared_scenes_cache)])
    return code, tmp / "out", jobs


@pytest.fixture(scope="module")
def refs(batch_run, shared_scenes_cache, tmp_path_factory):
    """`photoar composite` on each job alone."""
    tmp = tmp_path_factory.mktemp("refs")
    for jid, (scene, _, argv) in batch_run[2].items():
        assert cli(["-q", "composite", str(scene), "--out", str(tmp / jid), "--cache", str(shared_scenes_cache),
                    *argv]) == 0, jid
    return tmp


@pytest.fixture(scope="module")
def client():
    """A 2-worker local cluster the tests drive run_batch on (the fault test kills one worker)."""
    from distributed import Client, LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0",
                      silence_logs=logging.ERROR) as cluster, Client(cluster) as c:
        yield c


def _same_outputs(out: Path, ref: Path, jid: str) -> None:
    assert (out / jid / "composite.png").read_bytes() == (ref / jid / "composite.png").read_bytes(), jid
    a, b = read_exr(out / jid / "composite.exr"), read_exr(ref / jid / "composite.exr")
    np.testing.assert_allclose(a, b, rtol=1e-6, atol=0, err_msg=jid)


def _entries(out: Path) -> dict:
    rep = json.loads((out / "batch_report.json").read_text())
    return {e["id"]: e for e in rep["jobs"]}


def test_batch_equals_composite(batch_run, refs):
    code, out, jobs = batch_run
    assert code == 0
    entries = _entries(out)
    assert {i: e["status"] for i, e in entries.items()} == {i: "done" for i in jobs}
    for jid in jobs:
        _same_outputs(out, refs, jid)
        key = json.loads((out / jid / "batch_job.json").read_text())
        assert key["id"] == jid and len(key["input_key"]) == 64
        assert json.loads((out / jid / "report.json").read_text())["passes"] == 4
    # one warm per room and engine parameters: window_room once, lamps_room twice (l-ldr's params)
    rooms = json.loads((out / "batch_report.json").read_text())["rooms"]
    assert sorted(Path(r["scene"]).name for r in rooms) == ["lamps_room", "lamps_room", "window_room"]
    assert not [p.name for p in out.iterdir() if ".partial-" in p.name or ".old-" in p.name]


def _executing(dask_worker) -> list[str]:
    return [str(ts.key) for ts in dask_worker.state.executing]


def test_worker_killed_mid_job(batch_run, refs, client, shared_scenes_cache, tmp_path):
    from app.cmd_batch import run_batch

    ids = ["w-own", "w-place", "l-own", "l-chair"]
    path = _write_jobs(tmp_path / "jobs.jsonl", batch_run[2], ids)
    out = tmp_path / "out"
    result: dict = {}
    t = threading.Thread(target=lambda: result.update(run_batch(path, out, client=client, cache=shared_scenes_cache,
                                                                quiet=True)))
    t.start()
    killed = None
    deadline = time.monotonic() + 300
    while killed is None and t.is_alive() and time.monotonic() < deadline:
        for addr, keys in client.run(_executing).items():
            jobs = [k.split("-", 1)[1].rsplit("-", 1)[0] for k in keys if k.startswith("job-")]
            started = [j for j in jobs if out.is_dir() and any(p.name.startswith(f".{j}.partial-")
                                                               for p in out.iterdir())]
            if started:  # the job is writing its outputs: kill its worker process now
                os.kill(client.run(os.getpid)[addr], signal.SIGKILL)
                killed = (addr, started[0])
                break
        time.sleep(0.1)
    t.join(timeout=600)
    assert killed is not None, "no job was seen running"
    assert not t.is_alive()
    entries = _entries(out)
    assert {i: e["status"] for i, e in entries.items()} == {i: "done" for i in ids}
    assert entries[killed[1]]["worker"] != killed[0]  # retried on another worker (or its restarted process)
    for jid in ids:
        _same_outputs(out, refs, jid)
    assert not [p.name for p in out.iterdir() if ".partial-" in p.name or ".old-" in p.name]


def test_bad_jobs_reported(batch_run, refs, client, scenes, shared_scenes_cache, tmp_path):
    from app.cmd_batch import run_batch

    broken = tmp_path / "broken.ply"
    broken.write_text("ply\nformat ascii 1.0\nelement vertex 3\nend_header\n0 0\n")
    w = str(scenes["w"])
    bad = [
        json.dumps({"id": "no-room", "scene": str(tmp_path / "no_such_room"), "options": {"passes": 4}}),
        json.dumps({"id": "bad-value", "scene": w, "options": {"passes": 4, "yaw": "north"}}),
        json.dumps({"id": "bad-name", "scene": w, "options": {"passes": 4, "colour": "red"}}),
        json.dumps({"id": "bad-mesh", "scene": w, "options": {"passes": 4, "object": "broken.ply",
                                                              "place": [2.0, 0, 1.0]}}),
        json.dumps({"id": "w-place", "scene": w, "options": {}}),
        "{not json",
    ]
    path = _write_jobs(tmp_path / "jobs.jsonl", batch_run[2], ["w-place"], bad)
    out = tmp_path / "out"
    rep = run_batch(path, out, client=client, cache=shared_scenes_cache, quiet=True)
    entries = _entries(out)
    assert rep["done"] == 1 and rep["failed"] == 6
    assert entries["w-place"]["status"] == "done"
    _same_outputs(out, refs, "w-place")
    needles = {"no-room": ["no_such_room", "scene folder not found"],
               "bad-value": ["--yaw", "'north'"],
               "bad-name": ["'colour'", "not an option of photoar composite"],
               "bad-mesh": [str(broken)],
               "line 6": [f"{path}:6", "'w-place' repeats line 1"],  # the first w-place is kept
               "line 7": [f"{path}:7", "not a JSON object"]}
    errors = {e["id"]: e["error"] for e in rep["jobs"] if e["status"] == "failed"}
    assert set(errors) == set(needles), errors
    for jid, words in needles.items():
        assert len(errors[jid].splitlines()) == 1
        for word in words:
            assert word in errors[jid], (jid, errors[jid])
    assert sorted(p.name for p in out.iterdir()) == ["batch_report.json", "w-place"]


def test_resume_computes_only_what_is_missing(batch_run, refs, client, shared_scenes_cache, tmp_path):
    from app.cmd_batch import run_batch

    _, done_out, jobs = batch_run
    ids = ["w-own", "w-place", "l-own", "l-chair"]
    path = _write_jobs(tmp_path / "jobs.jsonl", jobs, ids)
    out = tmp_path / "out"
    out.mkdir()
    for jid in ids:  # a batch interrupted after some jobs: the same outputs, the same keys
        shutil.copytree(done_out / jid, out / jid)
    shutil.rmtree(out / "w-place")  # never finished
    (out / "l-own" / "composite.exr").unlink()  # incomplete
    (out / ".l-chair.partial-dead").mkdir()  # what a killed job leaves
    (out / ".l-chair.partial-dead" / "composite.png").write_bytes(b"half")
    kept = {jid: (out / jid / "composite.png").stat().st_mtime_ns for jid in ("w-own", "l-chair")}
    rep = run_batch(path, out, client=client, cache=shared_scenes_cache, quiet=True)
    status = {e["id"]: e["status"] for e in rep["jobs"]}
    assert status == {"w-own": "skipped", "w-place": "done", "l-own": "done", "l-chair": "skipped"}
    for jid in ids:
        _same_outputs(out, refs, jid)
    assert {jid: (out / jid / "composite.png").stat().st_mtime_ns for jid in kept} == kept
    assert not [p.name for p in out.iterdir() if ".partial-" in p.name or ".old-" in p.name]
    # another option is another input key: that job runs again, the rest stay
    _write_jobs(path, {**{i: jobs[i] for i in ids}, "w-own": (jobs["w-own"][0], {"passes": 4, "yaw": 0}, [])})
    rep = run_batch(path, out, client=client, cache=shared_scenes_cache, quiet=True)
    assert {e["id"]: e["status"] for e in rep["jobs"]} == {"w-own": "done", "w-place": "skipped",
                                                           "l-own": "skipped", "l-chair": "skipped"}


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_existing_cluster_via_scheduler(batch_run, refs, shared_scenes_cache, tmp_path, capsys):
    port = _free_port()
    addr = f"tcp://127.0.0.1:{port}"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    procs = [subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_scheduler", "--host", "127.0.0.1",
                               "--port", str(port), "--no-dashboard"], env=env, stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL, cwd=tmp_path)]
    try:
        procs.append(subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_worker", addr, "--nthreads", "1",
                                       "--host", "127.0.0.1", "--no-dashboard"], env=env,
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=tmp_path))
        ids = ["w-place", "l-own"]
        path = _write_jobs(tmp_path / "jobs.jsonl", batch_run[2], ids)
        out = tmp_path / "out"
        code = cli(["-q", "batch", str(path), "--out", str(out), "--scheduler", addr, "--cache",
                    str(shared_scenes_cache)])
        assert code == 0, capsys.readouterr().err
        rep = json.loads((out / "batch_report.json").read_text())
        assert rep["scheduler"] == addr and rep["workers"] == 1
        for jid in ids:
            assert _entries(out)[jid]["status"] == "done"
            _same_outputs(out, refs, jid)
    finally:
        for p in reversed(procs):
            p.terminate()
        for p in procs:
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()


def test_no_scheduler_answers(tmp_path, scenes, capsys):
    path = _write_jobs(tmp_path / "jobs.jsonl", {"w-own": (scenes["w"], {"passes": 4}, [])})
    addr = f"tcp://127.0.0.1:{_free_port()}"
    assert cli(["-q", "batch", str(path), "--out", str(tmp_path / "out"), "--scheduler", addr]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith(f"photoar: error: {addr}: no Dask scheduler answers"), err


def test_jobs_file_to_composite_command_lines(tmp_path):
    # options -> composite's command line: flags, lists, relative paths from the jobs file's folder;
    # the keys: another pose is another input key on the same engine, a touched scene file both
    from app.batchjob import BadJob, read_jobs
    from app.cli import demo_scene_dir

    shutil.copytree(demo_scene_dir(), tmp_path / "rooms" / "demo")
    (tmp_path / "chair.ply").write_bytes((tmp_path / "rooms" / "demo" / "object_chair.ply").read_bytes())
    lines = [{"id": "a", "scene": "rooms/demo", "options": {"object": "chair.ply", "place": [1, 0, 1.5], "yaw": 30,
                                                           "no-object-light": True, "no-second-order": False}},
             {"id": "b", "scene": "rooms/demo", "options": {"object": "chair.ply", "place": "1,0,2",
                                                           "no-object-light": True}},
             {"id": "c", "scene": "rooms/demo", "options": {"out": "x"}},
             {"id": "d", "scene": "rooms/demo", "options": {"place": True}},
             {"id": "e", "scene": "rooms/demo", "options": {"no-object-light": "yes"}},
             {"id": "../f", "scene": "rooms/demo"}]
    path = tmp_path / "jobs.jsonl"
    path.write_text("\n".join(json.dumps(d) for d in lines) + "\n\n")
    jobs = read_jobs(path)
    a, b = jobs[0], jobs[1]
    assert a.scene == (tmp_path / "rooms" / "demo").resolve()
    assert list(a.argv) == ["--object", str((tmp_path / "chair.ply").resolve()), "--place", "1,0,1.5", "--yaw", "30",
                            "--no-object-light"]
    assert a.engine_key == b.engine_key and a.input_key != b.input_key
    errors = {j.id: j.error for j in jobs[2:]}
    assert all(isinstance(j, BadJob) for j in jobs[2:])
    assert errors["c"] == f"{path}:3: option 'out': the output folder is DIR/<id>, set by photoar batch"
    assert errors["d"] == f"{path}:4: option 'place' takes a value, got true"
    assert errors["e"] == f"{path}:5: option 'no-object-light' is a flag: give true or false, got \"yes\""
    assert errors["line 6"].startswith(f"{path}:6: 'id' must be a non-empty folder name")
    photo = tmp_path / "rooms" / "demo" / "background.png"
    os.utime(photo, ns=(photo.stat().st_atime_ns, photo.stat().st_mtime_ns + 10**9))
    a2 = read_jobs(path)[0]
    assert a2.input_key != a.input_key and a2.engine_key != a.engine_key
