"""The Ray engine of `generate_dataset`: long-lived actors, each one process with one Mitsuba
variant and the scene it loaded last (Mitsuba must not share a process across threads, so an
actor runs one task at a time).

``ray.init()`` with no address starts Ray on this machine; ``address="ray://head:10001"`` or
``"auto"`` joins a cluster (the config's scene files must be readable at the same paths on every
node). Actors only render and return arrays; the driver writes the folder. An actor that dies is
restarted by Ray and its task retried (``max_restarts``, ``max_task_retries``); when the driver
itself dies, Ray ends the actors it owns, and they never held the folder anyway.
"""
from __future__ import annotations

import os

from mitsonar.jobs.dataset.config import DatasetError, task

ACTOR_RESTARTS = 3


def check_ray():
    """Ray is importable, or one line saying how to get it."""
    try:
        import ray  # noqa: F401
    except ImportError:
        raise DatasetError("--address / engine 'ray' needs Ray: pip install 'mitsonar[cluster]' (without it, "
                           "leave out --address: the same command runs in local processes)") from None


class DatasetActor:
    """A Ray actor around one `worker.SampleRenderer`."""

    def __init__(self, cfg, threads, variant):
        if variant:
            os.environ["MITSONAR_VARIANT"] = variant
        from mitsonar.jobs.dataset.worker import SampleRenderer

        import atexit

        self.renderer = SampleRenderer(cfg, threads)
        atexit.register(self.renderer.close)

    def render(self, t, want_mesh):
        return self.renderer.render(t, want_mesh)


def run_ray(cfg, coord, todo, workers, threads, address, variant):
    """Render ``todo`` on ``workers`` actors of ``threads`` CPUs each, results to ``coord``."""
    import ray

    started = False
    if not ray.is_initialized():
        ray.init(address=None if address in (None, "local") else address, log_to_driver=False,
                 include_dashboard=False)
        started = True
    try:
        remote = ray.remote(num_cpus=threads, max_restarts=ACTOR_RESTARTS,
                            max_task_retries=ACTOR_RESTARTS, max_concurrency=1)(DatasetActor)
        actors = [remote.remote(cfg, threads, variant) for _ in range(min(workers, len(todo)))]
        pending = list(todo)
        running = {}   # object ref -> (index, actor)
        idle = list(actors) * 2   # two tasks queued per actor keep it busy between results
        while pending or running:
            while pending and idle:
                i = pending.pop(0)
                actor = idle.pop(0)
                t = task(cfg, i)
                running[actor.render.remote(t, coord.want_mesh(t))] = (i, actor)
            ready, _ = ray.wait(list(running), num_returns=1)
            for ref in ready:
                i, actor = running.pop(ref)
                coord.add(ray.get(ref))
                idle.append(actor)
    finally:
        if started:
            ray.shutdown()
