"""How a batch on Ray hands its assets to its workers (``warp_stokes.batch.distributed._bind_on_workers``), against
a fake Ray whose calls finish in any order a generator draws: workers that never start, workers that die while
binding (and are started again), clusters of any size. Whatever happens, every asset gets exactly one result, in
manifest order; an asset fails only when its own worker died while binding it ``TASK_RETRIES`` + 1 times; no asset
goes to a worker that has not answered (since it was started again); a worker holds one asset at a time; every
worker is ended. (The real Ray runs in tests/test_batch_ray.py.)"""

from __future__ import annotations

import os
from collections import Counter, deque
from types import SimpleNamespace

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from warp_stokes.batch import distributed
from warp_stokes.batch.asset import Result
from warp_stokes.batch.manifest import Asset


class Died(Exception):
    """What a call to a worker whose process died raises (Ray's ActorUnavailableError and kin)."""


class Call:
    """A Ray object reference: the call's value or error."""

    def __init__(self, actor, kind: str, value=None, error=None):
        self.actor, self.kind, self.value, self.error = actor, kind, value, error


class Method:
    def __init__(self, call):
        self.remote = call

    def options(self, **options):
        return self


class Actor:
    def __init__(self, ray, index: int, starts: bool):
        self.ray, self.index, self.starts = ray, index, starts
        self.answered = False  # its latest greeting read by the driver (since it was last started)
        self.holding = 0  # assets handed to it and not yet finished
        self.killed = False
        self.where, self.bind = Method(self._where), Method(self._bind)

    def _where(self):
        return Call(self, "where", value=("host", 1000 + self.index),
                    error=None if self.starts else Died("the worker could not start"))

    def _bind(self, asset, folder, started, k, inputs, unreadable, digest):
        assert self.answered, "an asset was handed to a worker that had not answered"
        assert os.path.isabs(folder), "a worker got a folder relative to the driver's working folder"
        self.holding += 1
        assert self.holding == 1, "a worker held two assets at once"
        self.ray.handed[k] += 1
        if self.ray.handed[k] <= self.ray.deaths.get(k, 0):  # this asset kills its worker this time
            self.answered = False  # started again by Ray: it answers again before it gets more
            return Call(self, "bind", error=Died("its worker died"))
        result = Result(asset.name, "ok", resolution=asset.resolution, outputs=[os.path.join(folder, "x")],
                        host="host", pid=1000 + self.index, seconds=0.1)
        return Call(self, "bind", value=result)


class FakeRay:
    """As much of Ray as the dispatcher uses; ``wait`` returns a drawn set of the calls (one at least unless the
    timeout is 0)."""

    exceptions = SimpleNamespace(WorkerCrashedError=Died, NodeDiedError=Died, RayActorError=Died,
                                 ActorUnavailableError=Died)

    def __init__(self, data, cpus: int, gpus: int, starting: list[bool], deaths: dict[int, int]):
        self.data, self.cpus, self.gpus, self.starting, self.deaths = data, cpus, gpus, starting, deaths
        self.actors: list[Actor] = []
        self.handed = Counter()

    def cluster_resources(self):
        return {"CPU": float(self.cpus), "GPU": float(self.gpus)}

    def remote(self, cls):
        assert cls is distributed.BindWorker
        ray = self

        class Options:
            def options(self, **options):
                return self

            def remote(self, device, threads, harmonic):
                index = len(ray.actors)
                ray.actors.append(Actor(ray, index, ray.starting[index % len(ray.starting)]))
                return ray.actors[-1]

        return Options()

    def wait(self, calls, num_returns=1, timeout=None):
        finished = self.data.draw(st.lists(st.sampled_from(calls), min_size=0 if timeout == 0 else 1, unique_by=id),
                                  label="finished")
        for call in finished:
            if call.kind == "bind":
                call.actor.holding -= 1
        return finished, [c for c in calls if all(c is not f for f in finished)]

    def get(self, call):
        if call.kind == "where" and call.error is None:
            call.actor.answered = True
        if call.error is not None:
            raise call.error
        return call.value

    def kill(self, actor):
        actor.killed = True


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data(), n_assets=st.integers(1, 12), cpus=st.integers(1, 4), gpus=st.integers(0, 2),
       workers=st.one_of(st.none(), st.integers(1, 5)),
       starting=st.lists(st.booleans(), min_size=1, max_size=5))
def test_every_asset_gets_one_result_whatever_the_workers_do(data, n_assets, cpus, gpus, workers, starting):
    # asset k kills its worker the first deaths[k] times it is bound
    deaths = data.draw(st.dictionaries(st.integers(0, n_assets - 1), st.integers(1, distributed.TASK_RETRIES + 1)),
                       label="deaths")
    ray = FakeRay(data, cpus, gpus, starting, deaths)
    assets = [Asset(f"asset_{k}", "mesh.obj", "cage.obj", resolution=16) for k in range(n_assets)]
    results = [None] * n_assets
    said = distributed._Progress(assets, results, None)
    distributed._bind_on_workers(ray, assets, "out", said, deque(range(n_assets)), workers,
                                 "cpu" if gpus == 0 else None, local=True, inputs={}, unreadable={},
                                 digests=[None] * n_assets)

    assert all(r is not None for r in results) and [r.name for r in results] == [a.name for a in assets]
    count = (gpus if workers is None else workers) if gpus else cpus
    assert len(ray.actors) == min(count, n_assets)
    assert all(actor.killed for actor in ray.actors)
    assert all(times <= distributed.TASK_RETRIES + 1 for times in ray.handed.values())
    anyone = any(actor.starts for actor in ray.actors)
    for k, result in enumerate(results):
        if not anyone:
            assert result.status == "failed" and result.error == "no Ray worker could start"
        elif deaths.get(k, 0) > distributed.TASK_RETRIES:
            assert result.status == "failed" and result.error == f"its worker died ({distributed.TASK_RETRIES + 1} tries)"
        else:  # also when it was queued behind an asset that killed its worker, or its own worker died before
            assert result.status == "ok", (k, result.error)
            assert result.outputs == [os.path.join("out", f"asset_{k}.npz")]
            assert ray.handed[k] == deaths.get(k, 0) + 1
    assert said.done == n_assets and said.failed == sum(r.status == "failed" for r in results)


@given(gpus=st.integers(1, 8), workers=st.one_of(st.none(), st.integers(1, 40)))
def test_gpu_workers_all_fit_on_the_gpus(gpus, workers):
    """Each GPU worker's share of a GPU is such that all of them fit, each on one GPU (Ray places a fractional share
    on one GPU, counting in ten-thousandths): 3 workers on 2 GPUs, or 6 on one, all start."""
    count, options, device, threads = distributed._slots(FakeRay(None, 4, gpus, [True], {}), workers, None, local=True)
    assert count == (gpus if workers is None else workers) and device == "cuda:0" and threads is None
    share = options["num_gpus"]
    assert 0 < share <= 1 and share == round(share, 4)
    per_gpu = int(1 / share + 1e-9)  # workers that fit on one GPU
    assert per_gpu * gpus >= count
