"""The Ray engine of `generate_dataset`: long-lived actors, each one process with one Mitsuba
variant and the scene it loaded last (Mitsuba must not share a process across threads, so an
actor runs one task at a time).

Without an address a new Ray instance is started on this machine (``ray.init(address="local")``:
never a cluster left running here, which ``ray.init()`` alone would join through
``/tmp/ray/ray_current_cluster`` or ``RAY_ADDRESS``). ``address="HOST:PORT"`` (the head's GCS
port, ``ray start --head --port PORT``; this machine must be a node of the cluster), ``"auto"``
(the cluster this node belongs to) or ``"ray://HOST:10001"`` (Ray Client, needs ``ray[client]``)
joins a cluster; the config's scene files must be readable at the same paths on every node.

Token authentication (on by default in recent Ray: ``ray start --head`` turns it on when a token
exists, e.g. the ``~/.ray/auth_token`` any local ``ray.init()`` writes) is the reason a head
started the documented way refused ``--address HOST:PORT``: Ray's driver picks up the token by
itself only for ``address=None`` or ``"auto"``, never for an explicit address, so it connected
without one ("Authentication token is missing or incorrect") and gave up after retries ("Failed to
connect to Ray cluster"). `_token_auth` does what Ray does for ``"auto"``: with ``RAY_AUTH_MODE``
unset and a token at hand (``RAY_AUTH_TOKEN``, ``RAY_AUTH_TOKEN_PATH`` or ``~/.ray/auth_token``)
the driver sends it; a head without authentication accepts a driver that sends a token.

Actors only render and return arrays; the driver writes the folder. An actor that dies is
restarted by Ray and its task retried (``max_restarts``, ``max_task_retries``); when the driver
itself dies, Ray ends the actors it owns (a job's actors end with its driver), and they never held
the folder anyway.
"""
from __future__ import annotations

import os

from mitsonar._checks import first_line
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


def _token_auth(address):
    """Send the cluster's token when connecting to an explicit ``address``, as Ray itself does for
    ``"auto"`` (see the module docstring). Ray before token authentication has nothing to do."""
    if address in (None, "local", "auto") or os.environ.get("RAY_AUTH_MODE") is not None:
        return
    try:
        from ray._private.authentication.authentication_token_setup import (
            maybe_enable_token_auth_if_token_available,
        )
    except ImportError:
        return
    maybe_enable_token_auth_if_token_available(warn_if_disabled=False)


def _probe(address, timeout=10.0):
    """A ``HOST:PORT`` or ``ray://HOST:PORT`` address where nothing accepts a TCP connection is one
    `DatasetError` line at once (``ray.init`` would retry for many minutes)."""
    if address == "auto":
        return
    hostport = address[len("ray://"):] if address.startswith("ray://") else address
    host, _, port = hostport.rpartition(":")
    host = host.strip("[]")
    if not host or not port.isdigit():
        raise DatasetError(f"--address {address!r} is not allowed (HOST:PORT of a Ray head, ray://HOST:PORT, or auto)")
    import socket

    try:
        socket.create_connection((host, int(port)), timeout=timeout).close()
    except OSError as e:
        raise DatasetError(f"--address {address!r}: nothing answers there ({e.strerror or e}); start the head with "
                           f"ray start --head --port {port}, or give its address") from None


def connect(address):
    """``ray.init`` on this machine (``address`` None) or on the cluster at ``address``, unless
    Ray is initialised already; True when this call initialised it (the caller shuts it down).
    A cluster that cannot be reached is one `DatasetError` line saying what to check."""
    import ray

    if ray.is_initialized():
        return False
    if address in (None, "local"):
        ray.init(address="local", log_to_driver=False, include_dashboard=False)
        return True
    _probe(address)
    _token_auth(address)
    try:
        ray.init(address=address, log_to_driver=False)
    except (ConnectionError, RuntimeError, ValueError) as e:
        raise DatasetError(f"--address {address!r}: {first_line(e)}. Check that a Ray head runs there (ray start --head "
                           "--port PORT gives HOST:PORT; run this command on a node of the cluster), that this "
                           "Ray's version is the head's, and with token authentication that the head's token is "
                           "here (ray get-auth-token on the head; RAY_AUTH_TOKEN or ~/.ray/auth_token)") from None
    return True


def run_ray(cfg, coord, todo, workers, threads, address, variant):
    """Render ``todo`` on ``workers`` actors of ``threads`` CPUs each, results to ``coord``."""
    import ray

    started = connect(address)
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
