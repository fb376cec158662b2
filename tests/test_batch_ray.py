"""Batches on Ray (the optional extra): a local cluster the command starts, a simulated multi-node cluster (the
session's, tests/conftest.py: ray_cluster), a worker killed mid-asset, and the one-line error without Ray. Few and
small: each start of Ray takes seconds on 2 cores."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

import warp_stokes as ws
from conftest import EXAMPLE, cli, write_obj

ray = pytest.importorskip("ray")


def manifest(folder, names=("arm_a", "arm_b"), broken=True, made=False):
    """Arm assets at n = 16 (the second with poses); with ``broken``, one whose cage is open; with ``made``, one
    whose cage is made for it (``cage = "auto"``)."""
    cage = ws.load_surface(EXAMPLE / "arm_cage.obj")
    np.save(folder / "grow.npy", np.stack([cage.vertices * (1 + 0.05 * k) for k in range(3)]))
    write_obj(folder / "open_cage.obj", cage.vertices, cage.faces[1:])
    arm, arm_cage = EXAMPLE / "arm.obj", EXAMPLE / "arm_cage.obj"
    text = "[defaults]\nresolution = 16\n"
    for k, name in enumerate(names):
        text += f'\n[[asset]]\nname = "{name}"\nmesh = "{arm}"\ncage = "{arm_cage}"\n'
        text += f'poses = "{folder / "grow.npy"}"\n' if k == 1 else ""
    if made:
        text += f'\n[[asset]]\nname = "arm_made"\nmesh = "{arm}"\ncage = "auto"\n'
    if broken:
        text += f'\n[[asset]]\nname = "broken"\nmesh = "{arm}"\ncage = "{folder / "open_cage.obj"}"\n'
    path = folder / "batch.toml"
    path.write_text(text)
    return path


def batch(*args, env=None):
    return subprocess.run([sys.executable, "-m", "warp_stokes.cli", "batch", *map(str, args)], capture_output=True,
                          text=True, env={**os.environ, **(env or {})}, timeout=600)


def summary(folder):
    return {a["name"]: a for a in json.loads((folder / "summary.json").read_text())["assets"]}


def test_workers_give_the_serial_batch_s_files_and_weights(tmp_path):
    path = manifest(tmp_path, made=True)
    serial = cli("batch", path, "-o", tmp_path / "serial", "--device", "cpu")  # in process: no Ray
    parallel = batch(path, "-o", tmp_path / "ray", "--device", "cpu", "--workers", "2")
    assert serial.returncode == parallel.returncode == 1, parallel.stderr  # the broken asset fails in both
    assert sorted(os.listdir(tmp_path / "ray")) == sorted(os.listdir(tmp_path / "serial"))
    # a made cage: the same in the workers (deterministic), written beside its binding
    made = [(tmp_path / run / "arm_made.cage.obj").read_bytes() for run in ("serial", "ray")]
    assert made[0] == made[1]
    for name in ("arm_a", "arm_b", "arm_made"):
        a = ws.load_binding(tmp_path / "serial" / f"{name}.npz", device="cpu")
        b = ws.load_binding(tmp_path / "ray" / f"{name}.npz", device="cpu")
        np.testing.assert_allclose(b.weights, a.weights, atol=1e-6)
        # the cores shared out: a serial bind takes them all, each of 2 workers its half
        assert a.stats.solver.threads == min(ws.threads.cpu_threads(), a.n_handles)
        assert b.stats.solver.threads == max(1, ws.threads.cpu_threads() // 2)
    got, expected = summary(tmp_path / "ray"), summary(tmp_path / "serial")
    assert {k: v["status"] for k, v in got.items()} == {k: v["status"] for k, v in expected.items()}
    assert "not closed" in got["broken"]["error"]
    for name in ("arm_a", "arm_b"):
        assert got[name]["host"] and got[name]["device"] == "cpu" and got[name]["pid"] not in (None, os.getpid())
    assert "done, " in parallel.stderr and "running" in parallel.stderr and "arm_b: ok" in parallel.stderr
    # each asset is said as it starts, on its worker, before it is said done
    lines = parallel.stderr.splitlines()
    for name in ("arm_a", "arm_b", "broken"):
        start = next(k for k, line in enumerate(lines) if f"] {name}: started (" in line)
        end = next(k for k, line in enumerate(lines) if f"] {name}: " in line and ": started" not in line)
        assert start < end and f"pid {got[name]['pid']}" in lines[start], parallel.stderr


def test_a_multi_node_cluster_retries_a_worker_killed_mid_asset(tmp_path, monkeypatch, ray_cluster):
    """A batch that joins a simulated two-node cluster (the session's: one start of Ray for the tests that run on a
    cluster), one of whose workers is killed mid-asset (the first task to find the marker file removes it and kills
    its own process, as a crash would): Ray runs that task again, the batch completes and nothing half-written is
    left. The workers get the marker's variable from this process through the batch's runtime environment. The output
    folder is given relative to this process's working folder, which the cluster's workers do not share."""
    import io

    path = manifest(tmp_path, names=("arm_a", "arm_b"), broken=False)
    marker = tmp_path / "kill-once"
    marker.write_text("")
    monkeypatch.setenv("WARP_STOKES_KILL_WORKER_ONCE", str(marker))
    progress = io.StringIO()
    monkeypatch.chdir(tmp_path)
    results = ws.run_batch(path, "out", device="cpu", ray_address=ray_cluster, progress=progress)
    assert not ray.is_initialized()  # the batch left the cluster it joined
    assert [r.status for r in results] == ["ok", "ok"]
    assert all(r.pid not in (None, os.getpid()) for r in results)
    assert (tmp_path / "out" / "arm_b.usd").exists() and results[1].outputs == ["out/arm_b.npz", "out/arm_b.usd"]
    assert not marker.exists()  # a worker found it and killed itself; Ray ran the task again
    text = progress.getvalue()
    assert "arm_a: started (" in text and "arm_b: started (" in text and "started again (" in text, text
    assert sorted(os.listdir(tmp_path / "out")) == ["arm_a.npz", "arm_b.npz", "arm_b.usd", "summary.json"]


def test_without_ray_workers_is_one_line_and_exit_2(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # as where Ray is not installed: `import ray` fails
    path = manifest(tmp_path, names=("arm_a",), broken=False)
    result = cli("batch", path, "-o", tmp_path / "out", "--workers", "2")  # in process
    assert result.returncode == 2
    assert result.stderr.count("\n") == 1 and 'pip install "warp-stokes[ray]"' in result.stderr
    assert not (tmp_path / "out").exists()


def test_a_local_cluster_is_a_new_one_and_nothing_to_do_starts_none(tmp_path, monkeypatch):
    """``--workers`` starts a new local cluster in a child process (``address="local"``: ``ray.init()`` alone joins a
    cluster that happens to run on the machine, whose slots and shutdown are not the batch's), and ends it whatever
    happens; when it cannot start, the assets left fail saying why; a batch whose assets are all up to date starts
    none."""
    import warp_stokes.batch.distributed as distributed

    assert 'ray.init(address="local"' in distributed._HEAD
    heads = []

    class Head:  # a cluster that never starts
        def __init__(self, cpus, gpus):
            heads.append({"cpus": cpus, "gpus": gpus, "closed": False})

        def address(self, wait=0.0):
            raise ws.WarpStokesError("not started in this test")

        def close(self):
            heads[-1]["closed"] = True

    monkeypatch.setattr(distributed, "LocalHead", Head)
    path = manifest(tmp_path, broken=False)
    # the assets not bound yet fail saying why; what was done stays (none here), the summary is written
    results = ws.run_batch(path, tmp_path / "out", device="cpu", workers=2, progress=None)
    assert [(r.status, r.error) for r in results] == [("failed", "not started in this test")] * 2
    assert summary(tmp_path / "out")["arm_a"]["error"] == "not started in this test"
    assert heads == [{"cpus": 2, "gpus": 0, "closed": True}]
    assert [r.status for r in ws.run_batch(path, tmp_path / "out", device="cpu", progress=None)] == ["ok", "ok"]
    again = ws.run_batch(path, tmp_path / "out", device="cpu", workers=2, progress=None)
    assert [r.status for r in again] == ["skipped", "skipped"] and len(heads) == 1


_SLOW_HEAD_BATCH = """
import json, os, sys
import warp_stokes as ws
import warp_stokes.batch.distributed as distributed

class SlowHead(distributed.LocalHead):  # up only after the second asset
    polls = 0

    def address(self, wait=0.0):
        SlowHead.polls += 1
        return None if SlowHead.polls <= 2 else super().address(wait=None)

distributed.LocalHead = SlowHead
results = ws.run_batch(sys.argv[1], sys.argv[2], device="cpu", workers=1, progress=sys.stderr)
print(json.dumps({"pid": os.getpid(), "results": [r.__dict__ for r in results]}))
"""


def test_the_batch_binds_while_its_cluster_starts(tmp_path):
    """A local cluster starts in a child process while the batch binds in its own (a fork of this process in a
    BLAS call could hang it); what is left when the cluster is up goes to its workers. Here the cluster comes up
    after two assets: they are bound here, the third by a worker; the weights are those of a batch in process. (In
    a process of its own: joining a new local cluster puts a process in Ray's token mode, as ``ray.init`` does, and
    this session's cluster has none.)"""
    path = manifest(tmp_path, names=("arm_a", "arm_b", "arm_c"), broken=False)
    run = subprocess.run([sys.executable, "-c", _SLOW_HEAD_BATCH, str(path), str(tmp_path / "ray")],
                         capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    out = json.loads(run.stdout.strip().splitlines()[-1])
    results, here = out["results"], out["pid"]
    assert [r["status"] for r in results] == ["ok"] * 3, run.stderr
    assert [r["pid"] == here for r in results] == [True, True, False], run.stderr
    serial = ws.run_batch(path, tmp_path / "serial", device="cpu", progress=None)
    for r, s in zip(results, serial):  # (a worker's BLAS runs on one thread: not bit for bit on every machine)
        a = ws.load_binding(r["outputs"][0], device="cpu")
        b = ws.load_binding(s.outputs[0], device="cpu")
        np.testing.assert_allclose(a.weights, b.weights, atol=1e-6)
    assert f"arm_a: started ({results[0]['host']} pid {here})" in run.stderr
    assert f"arm_c: started ({results[2]['host']} pid {results[2]['pid']})" in run.stderr
