"""`generate_dataset`: render a config's samples on workers and write them, resumably.

The coordinator (this process) hands sample indices to workers, in order, a few ahead per
worker; workers (local spawned processes, or Ray actors) render and return arrays; the
coordinator alone writes the folder. Shards are committed in order: shard k is written (tar
renamed into place), then the manifest (renamed), once all its samples are back and every shard
before it is written. A run interrupted or killed at any point leaves whole shards and a manifest
listing exactly them; running the same command again holds the folder's lock, removes the
temporary files of the dead run, and renders only the samples of the missing shards. Since every
sample is drawn from its own seed (`config.task`), the result is the uninterrupted run's, byte for
byte, whatever the number or kind of workers.
"""
from __future__ import annotations

import os
import sys
import time

import numpy as np

from mitsonar._files import check_output_folder, make_output_folder
from mitsonar.jobs.dataset.config import FORMAT, DatasetError, config_difference, config_hash, task
from mitsonar.jobs.dataset.store import MANIFEST, SHARD, RunLock, read_manifest, remove_partials, write_json, write_mesh, write_shard

MAX_RESTARTS = 3   # a local pool whose worker died is started again this many times


def _cores():
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:
        return os.cpu_count() or 1


class _Coordinator:
    """Collects results, commits shards in order, keeps the manifest."""

    def __init__(self, cfg, folder, manifest, progress):
        self.cfg, self.folder, self.manifest = cfg, folder, manifest
        self.size = cfg["shard_size"]
        self.n_shards = -(-cfg["samples"] // self.size)
        self.next_shard = len(manifest["shards"])
        self.done = {}            # index -> result, waiting for its shard
        self.labels = {name: i for i, name in enumerate(manifest["labels"])}
        self.meshes = set(manifest["meshes"])
        self.mesh_asked = set()
        self.progress = progress
        self.rendered = 0

    def todo(self):
        return list(range(self.next_shard * self.size, self.cfg["samples"]))

    def want_mesh(self, t):
        key = t["scene"]["key"]
        if key in self.meshes or key in self.mesh_asked:
            return False
        self.mesh_asked.add(key)
        return True

    def add(self, result):
        if "mesh" in result:
            key = result["scene"]
            write_mesh(os.path.join(self.folder, "meshes", f"{key}.npz"), result.pop("mesh"))
            self.meshes.add(key)
            self.manifest["meshes"] = sorted(self.meshes)
        self.done[result["index"]] = result
        self.rendered += 1
        if self.progress is not None:
            self.progress.update(1)
        while self.next_shard < self.n_shards:
            lo = self.next_shard * self.size
            hi = min(lo + self.size, self.cfg["samples"])
            if not all(i in self.done for i in range(lo, hi)):
                break
            self._commit([self.done.pop(i) for i in range(lo, hi)])

    def _commit(self, results):
        for r in results:   # the scene's own labels -> the dataset's, in order of first appearance
            ids = []
            for name in r["shape_names"]:
                if name not in self.labels:
                    self.labels[name] = len(self.labels)
                ids.append(self.labels[name])
            lut = np.array([0] + ids, dtype=np.int32)
            r["arrays"]["segmentation"] = lut[r["arrays"]["segmentation"]]
            r["meta"].update(scene=r["scene"], mesh=f"meshes/{r['scene']}.npz")
        name = SHARD.format(self.next_shard)
        write_shard(os.path.join(self.folder, name), results)
        self.manifest["shards"].append({"name": name, "first": results[0]["index"], "count": len(results)})
        self.manifest["labels"] = list(self.labels)
        write_json(os.path.join(self.folder, MANIFEST), self.manifest)
        self.next_shard += 1


def prepare_folder(cfg, folder):
    """The folder's lock and manifest: a new one, or the one to resume (same config), else a
    `DatasetError` saying why not. The manifest is read and checked under the lock (a run that
    finished meanwhile has written its last one), and the lock is released if anything fails."""
    check_output_folder(folder, DatasetError)
    make_output_folder(folder, DatasetError)
    _refuse_foreign(folder)   # before the lock: no lock file is left in a folder that is not ours
    lock = RunLock(folder)
    try:
        manifest = read_manifest(folder)
        _refuse_foreign(folder)
        digest = config_hash(cfg)
        if manifest is not None and manifest["config_hash"] != digest:
            diff = config_difference(manifest["config"], cfg) or "the format differs"
            raise DatasetError(f"-o {folder!r} holds a dataset of another config ({diff}); it cannot be resumed "
                               "with this one: choose a new folder, or delete that one")
        inputs, version = _inputs(cfg), _version()
        if manifest is not None:
            for path, digest_then in manifest.get("inputs", {}).items():
                if inputs.get(path) != digest_then:
                    raise DatasetError(f"-o {folder!r}: scene file {path} changed since this dataset was begun; "
                                       "resuming would mix two scenes: choose a new folder, or delete that one")
            if manifest.get("mitsonar_version") != version:
                raise DatasetError(f"-o {folder!r} was begun by mitsonar {manifest.get('mitsonar_version')}, this "
                                   f"is {version}: its samples may render differently; choose a new folder, or "
                                   "delete that one")
        remove_partials(folder)
        if manifest is None:
            manifest = {"format": FORMAT, "config_hash": digest, "config": cfg, "samples": cfg["samples"],
                        "shard_size": cfg["shard_size"], "shards": [], "labels": ["none"], "meshes": [],
                        "inputs": inputs, "mitsonar_version": version}
            write_json(os.path.join(folder, MANIFEST), manifest)
    except BaseException:
        lock.release()
        raise
    return lock, manifest


def _refuse_foreign(folder):
    """A folder holding files but no manifest is not a dataset this command wrote."""
    if not os.path.isfile(os.path.join(folder, MANIFEST)):
        stray = sorted(n for n in os.listdir(folder) if not n.startswith("."))
        if stray:
            raise DatasetError(f"-o {folder!r} holds files but no {MANIFEST} ({stray[0]}, ...): not a dataset this "
                               "command wrote; choose a new or empty folder")


def _inputs(cfg):
    """sha256 of every scene file the config names: a resumed run must see the same scenes."""
    import hashlib

    out = {}
    for s in cfg["scenes"]:
        if "xml" in s:
            with open(s["xml"], "rb") as f:
                out[s["xml"]] = hashlib.sha256(f.read()).hexdigest()
    return out


def _version():
    from mitsonar._version import __version__

    return __version__


def _init_local(parent, cfg, threads, variant):
    """Initializer of a local worker process: it ends with the coordinator ``parent`` however that
    ends (`lifetime.die_with_parent`; a SIGKILLed coordinator once left its workers and the
    resource tracker running), then sets up its renderer (`worker.init_process`)."""
    from mitsonar.jobs.dataset.lifetime import die_with_parent
    from mitsonar.jobs.dataset.worker import init_process

    die_with_parent(parent)
    init_process(cfg, threads, variant)


def _local(cfg, coord, todo, workers, threads, variant):
    """Render ``todo`` on ``workers`` spawned processes; a dead worker's pool is restarted and its
    samples handed out again (at most `MAX_RESTARTS` times)."""
    import multiprocessing as mp
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
    from concurrent.futures.process import BrokenProcessPool

    from mitsonar.jobs.dataset.worker import render_in_process

    pending = list(todo)
    restarts = 0
    while pending:
        pool = ProcessPoolExecutor(workers, mp_context=mp.get_context("spawn"), initializer=_init_local,
                                   initargs=(os.getpid(), cfg, threads, variant))
        running = {}
        try:
            while pending or running:
                while pending and len(running) < 2 * workers:
                    # taken off `pending` only once submitted: a pool broken since the last wait
                    # raises in submit, and the sample must stay pending (it was lost: 5 of 6)
                    i = pending[0]
                    t = task(cfg, i)
                    running[pool.submit(render_in_process, t, coord.want_mesh(t))] = i
                    pending.pop(0)
                finished, _ = wait(running, return_when=FIRST_COMPLETED)
                for f in sorted(finished, key=running.get):
                    result = f.result()   # a dead worker raises here; its index stays in running
                    running.pop(f)
                    coord.add(result)
        except BrokenProcessPool:
            restarts += 1
            if restarts > MAX_RESTARTS:
                raise DatasetError(f"a local worker died {restarts} times; the samples written so far are kept "
                                   "(run the same command again to resume)") from None
            pending = sorted(set(pending) | set(running.values()))
            coord.mesh_asked -= {task(cfg, i)["scene"]["key"] for i in pending}
        finally:
            pool.shutdown(wait=True, cancel_futures=True)


def _inline(cfg, coord, todo, threads):
    """Render ``todo`` in this process (``workers=0``: no process to start; tests, debugging)."""
    from mitsonar.jobs.dataset.worker import SampleRenderer

    renderer = SampleRenderer(cfg, threads)
    try:
        for i in todo:
            t = task(cfg, i)
            coord.add(renderer.render(t, coord.want_mesh(t)))
    finally:
        renderer.close()


#: What ``--workers`` (``workers``) may be on local processes (Ray takes 1 or more actors).
WORKERS_ALLOWED = "a whole number >= 1 of worker processes, or 0 to render in this process"


def generate_dataset(config, output, workers=None, address=None, threads=None, progress=True, engine=None):
    """Render the samples of ``config`` (a file or a checked dict) into the folder ``output``.

    ============ ==================================================================================
    config       a YAML/TOML file (`config.read_config`) or a dict (`config.check_config`)
    output       the dataset folder; a folder holding part of this config's dataset is resumed
    workers      worker processes or Ray actors (default: the number of cores); 0 renders in this
                 process, without worker processes (local engine only; debugging, profiling)
    address      a Ray cluster's address (``HEAD:6379``, ``auto``, ``ray://HEAD:10001``): runs there, on
                 Ray (see `ray_engine`: token authentication, this machine a node of it)
    threads      Dr.Jit render threads per worker (default cores // workers, at least 1)
    progress     show a progress bar (samples, samples/s, time left) on stderr; or an object
                 whose ``update(1)`` is called as each sample comes back
    engine       ``"ray"`` (actors; ``ray.init()`` on this machine without an address), ``"local"``
                 (spawned processes), or ``"auto"`` (default): Ray when an address is given, local
                 processes otherwise (a Ray started on this machine costs seconds and opens ports
                 beyond loopback; ``--engine ray`` asks for it)
    ============ ==================================================================================

    Returns a dict: ``rendered`` (samples rendered by this call), ``samples`` (in the folder),
    ``seconds``. The same config gives the same folder contents for any workers, threads and engine.
    """
    from mitsonar.jobs.dataset.config import check_config, read_config

    cfg = read_config(config) if isinstance(config, (str, os.PathLike)) else check_config(config)
    engine = engine or "auto"
    if engine not in ("auto", "local", "ray"):
        raise DatasetError(f"--engine {engine!r} is not allowed (auto, local or ray)")
    if address and engine == "local":
        raise DatasetError("--address runs on a Ray cluster: it cannot go with --engine local")
    if workers is None:
        workers = _cores()
    if engine == "auto":
        engine = "ray" if address else "local"
    if not (isinstance(workers, int) and not isinstance(workers, bool) and workers >= 0) or (engine == "ray" and workers < 1):
        raise DatasetError(f"--workers {workers!r} is not allowed ("
                           + ("Ray actors: a whole number >= 1)" if engine == "ray" else WORKERS_ALLOWED + ")"))
    if threads is None:
        threads = max(1, _cores() // max(1, workers))
    if engine == "ray":
        from mitsonar.jobs.dataset.ray_engine import check_ray

        check_ray()
    start = time.time()
    connected = False
    if engine == "ray" and address:
        from mitsonar.jobs.dataset.ray_engine import connect

        check_output_folder(output, DatasetError)
        connected = connect(address)   # a cluster that cannot be reached: one line, before the folder is touched
    try:
        return _generate(cfg, output, workers, address, threads, progress, engine, start)
    finally:
        if connected:
            import ray

            ray.shutdown()


def _generate(cfg, output, workers, address, threads, progress, engine, start):
    lock, manifest = prepare_folder(cfg, output)
    bar = None
    try:
        coord = _Coordinator(cfg, output, manifest, None)
        todo = coord.todo()
        if progress is not None and not isinstance(progress, bool):
            coord.progress = progress   # anything with update(n): benchmarks time each sample
        elif progress and todo:
            from tqdm import tqdm

            bar = tqdm(total=cfg["samples"], initial=cfg["samples"] - len(todo), unit="sample", desc="dataset",
                       file=sys.stderr, smoothing=0.1, dynamic_ncols=True)
            coord.progress = bar
        variant = os.environ.get("MITSONAR_VARIANT")
        if todo:
            if engine == "ray":
                from mitsonar.jobs.dataset.ray_engine import run_ray

                run_ray(cfg, coord, todo, workers, threads, address, variant)
            elif workers == 0:
                _inline(cfg, coord, todo, threads)
            else:
                _local(cfg, coord, todo, min(workers, len(todo)), threads, variant)
    finally:
        if bar is not None:
            bar.close()
        lock.release()
    n = sum(s["count"] for s in coord.manifest["shards"])
    return {"rendered": coord.rendered, "samples": n, "seconds": time.time() - start}
