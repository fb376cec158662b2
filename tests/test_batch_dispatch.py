"""How a batch on Ray hands its assets to its workers (``warp_stokes.batch.distributed._bind_on_workers``), against
a fake Ray whose calls finish in any order a generator draws: workers that never start, workers that die mid-asset,
clusters of any size. Whatever happens, every asset gets exactly one result, in manifest order; no asset goes to a
worker before it has answered, or to one that could not start; a worker never holds more than ``QUEUED`` assets;
every worker is ended. (The real Ray runs in tests/test_batch_ray.py.)"""

from __future__ import annotations

import os
from collections import deque
from types import SimpleNamespace

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from warp_stokes.batch import distributed
from warp_stokes.batch.asset import Result
from warp_stokes.batch.manifest import Asset


class Died(Exception):
    """What a call of a worker that died every time raises (Ray's RayActorError)."""


class Call:
    """A Ray object reference: the call's value or error, and what the fake keeps track of."""

    def __init__(self, actor, kind: str, value=None, error=None, asset: int | None = None):
        self.actor, self.kind, self.value, self.error, self.asset = actor, kind, value, error, asset


class Actor:
    def __init__(self, ray, index: int, answers: bool):
        self.ray, self.index, self.answers = ray, index, answers
        self.answered = False  # its greeting read by the driver
        self.holding = 0  # bind calls handed to it and not yet finished
        self.killed = False
        self.where = SimpleNamespace(remote=self._where)
        self.bind = SimpleNamespace(remote=self._bind)

    def _where(self):
        error = None if self.answers else Died("the worker could not start")
        return Call(self, "where", value=("host", 1000 + self.index), error=error)

    def _bind(self, asset, folder, started, k, inputs, unreadable, digest):
        assert self.answered, "an asset was handed to a worker that had not answered"
        assert os.path.isabs(folder), "a worker got a folder relative to the driver's working folder"
        self.holding += 1
        assert self.holding <= distributed.QUEUED, "a worker held more than QUEUED assets"
        self.ray.handed.append(k)
        if k in self.ray.dies:
            return Call(self, "bind", error=Died("its worker died"), asset=k)
        result = Result(asset.name, "ok", resolution=asset.resolution, outputs=[os.path.join(folder, "x")],
                        host="host", pid=1000 + self.index, seconds=0.1)
        return Call(self, "bind", value=result, asset=k)


class FakeRay:
    """As much of Ray as the dispatcher uses; ``wait`` returns a drawn, non-empty set of the calls."""

    exceptions = SimpleNamespace(WorkerCrashedError=Died, NodeDiedError=Died, RayActorError=Died)

    def __init__(self, data, cpus: int, gpus: int, answering: list[bool], dies: set[int]):
        self.data, self.cpus, self.gpus, self.answering, self.dies = data, cpus, gpus, answering, dies
        self.actors: list[Actor] = []
        self.handed: list[int] = []

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
                ray.actors.append(Actor(ray, index, ray.answering[index % len(ray.answering)]))
                return ray.actors[-1]

        return Options()

    def wait(self, calls, num_returns=1, timeout=None):
        finished = self.data.draw(st.lists(st.sampled_from(calls), min_size=1, unique_by=id), label="finished")
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
       answering=st.lists(st.booleans(), min_size=1, max_size=5))
def test_every_asset_gets_one_result_whatever_the_workers_do(data, n_assets, cpus, gpus, workers, answering):
    dies = set(data.draw(st.sets(st.integers(0, n_assets - 1)), label="dies"))
    ray = FakeRay(data, cpus, gpus, answering, dies)
    assets = [Asset(f"asset_{k}", "mesh.obj", "cage.obj", resolution=16) for k in range(n_assets)]
    results = [None] * n_assets
    said = distributed._Progress(assets, results, None)
    waiting = deque(range(n_assets))
    distributed._bind_on_workers(ray, assets, "out", said, waiting, workers, "cpu" if gpus == 0 else None,
                                 local=True, inputs={}, unreadable={}, digests=[None] * n_assets)

    assert not waiting and all(r is not None for r in results)
    assert [r.name for r in results] == [a.name for a in assets]
    assert sorted(ray.handed) == sorted(set(ray.handed)), "an asset was handed out twice"
    count = (gpus if workers is None else workers) if gpus else cpus
    assert len(ray.actors) == min(count, n_assets)
    assert all(actor.killed for actor in ray.actors)
    anyone = any(actor.answered for actor in ray.actors)
    for k, result in enumerate(results):
        if not anyone:
            assert result.status == "failed" and result.error == "no Ray worker could start"
        elif k in dies:
            assert result.status == "failed" and "its worker died" in result.error
        else:
            assert result.status == "ok" and result.outputs == [os.path.join("out", f"asset_{k}.npz")]
    assert said.done == n_assets and said.failed == sum(r.status == "failed" for r in results)
