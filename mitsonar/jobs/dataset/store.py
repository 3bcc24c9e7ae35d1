"""The dataset folder: WebDataset shards, the manifest, the run lock, and `open_dataset`.

Layout of ``DIR``::

    manifest.json          format, config and its hash, counts, the shards written, label names
    shard-000000.tar       samples 0 .. shard_size - 1, WebDataset style: for sample i the tar
    shard-000001.tar       members "<i:08d>.<field>.npy" (one .npy per array) and "<i:08d>.json"
    meshes/<scene>.npz     ground-truth mesh (vertices, faces) of each scene, named by samples
    .lock                  held (flock) by the run writing into DIR; removed when it ends

Why WebDataset (tar) and not Zarr: samples of one dataset differ in shape (a mechanical head's
200 x 500 rows and bins beside a multibeam's 128 x 400), which tar members hold as they are while
Zarr arrays need one shape per array; a shard is one file, written under a temporary name and
renamed when complete, which is what resuming needs (a shard is there whole or not at all); tar
shards stream sequentially from disk or object storage into training (``webdataset``, or plain
``tarfile``), and writing them needs only the standard library.

Every file is written under a temporary name and renamed; the manifest is rewritten (renamed) after
each shard, so it always lists exactly the shards that are there.
"""
from __future__ import annotations

import io
from collections.abc import Sequence
import json
import os
import tarfile

import numpy as np

from mitsonar._files import replacing
from mitsonar.jobs.dataset.config import FORMAT, DatasetError

MANIFEST = "manifest.json"
LOCK = ".lock"
SHARD = "shard-{:06d}.tar"
FIELDS = ("data", "intensity", "poses", "times", "segmentation", "first_return", "ranges", "bearings")


def sample_key(index) -> str:
    return f"{int(index):08d}"


def _npy(array) -> bytes:
    buf = io.BytesIO()
    np.save(buf, np.asarray(array), allow_pickle=False)
    return buf.getvalue()


def write_shard(path, samples) -> None:
    """Write ``samples`` (dicts ``index``, ``arrays``, ``meta``) as one tar, renamed into place."""
    with replacing(path) as tmp, tarfile.open(tmp, "w", format=tarfile.PAX_FORMAT) as tar:
        for s in samples:
            key = sample_key(s["index"])
            members = [(f"{key}.{name}.npy", _npy(s["arrays"][name])) for name in FIELDS]
            members.append((f"{key}.json", json.dumps(s["meta"], sort_keys=True).encode("utf-8")))
            for name, payload in members:
                info = tarfile.TarInfo(name)
                info.size, info.mtime, info.mode = len(payload), 0, 0o644
                tar.addfile(info, io.BytesIO(payload))


def write_json(path, obj) -> None:
    with replacing(path) as tmp, open(tmp, "w", encoding="utf-8") as f:
        json.dump(obj, f, indent=1, sort_keys=True)
        f.write("\n")


def write_mesh(path, mesh) -> None:
    os.makedirs(os.path.dirname(path), exist_ok=True)
    with replacing(path) as tmp, open(tmp, "wb") as f:
        np.savez(f, vertices=mesh[0], faces=mesh[1])


def read_manifest(folder):
    path = os.path.join(folder, MANIFEST)
    if not os.path.isfile(path):
        return None
    with open(path, encoding="utf-8") as f:
        manifest = json.load(f)
    if manifest.get("format") != FORMAT:
        raise DatasetError(f"{path}: not a mitsonar dataset manifest (format {manifest.get('format')!r}, "
                           f"expected {FORMAT!r})")
    return manifest


class RunLock:
    """An exclusive lock on ``DIR/.lock`` for the run writing into ``DIR`` (released by the OS
    when the process ends, killed or not); a second run is refused with one sentence.

    `release` removes the file (a finished run leaves no ``.lock`` behind): it is unlinked while
    still locked, and a run that opened the old file just before, and got its lock once released,
    sees that the path no longer names the file it locked and takes the lock again on the new one
    (without that check two runs could each hold a lock: one on the removed file, one on a new)."""

    def __init__(self, folder):
        import fcntl   # POSIX only: imported here, so that `import mitsonar` works everywhere

        self.path = os.path.join(folder, LOCK)
        while True:
            self.fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
            try:
                fcntl.flock(self.fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                os.close(self.fd)
                raise DatasetError(f"-o {folder!r}: another run is writing into this folder (it holds {self.path}); "
                                   "wait for it or stop it") from None
            try:
                same = os.path.samestat(os.fstat(self.fd), os.stat(self.path))
            except FileNotFoundError:
                same = False
            if same:
                break
            os.close(self.fd)   # locked a file the run before removed on release: try the new one
        os.ftruncate(self.fd, 0)
        os.write(self.fd, f"{os.getpid()}\n".encode())

    def release(self):
        if self.fd is not None:
            import fcntl

            try:
                os.remove(self.path)   # still locked: nobody can take it in between
            except FileNotFoundError:
                pass
            fcntl.flock(self.fd, fcntl.LOCK_UN)
            os.close(self.fd)
            self.fd = None


def remove_partials(folder) -> None:
    """Remove temporary files a killed run left (``.name.*.partial.ext``), under the lock."""
    for root in (folder, os.path.join(folder, "meshes")):
        if os.path.isdir(root):
            for name in os.listdir(root):
                if name.startswith(".") and ".partial" in name:
                    os.remove(os.path.join(root, name))


# ----------------------------------------------------------------------------- reading
def _load_npy(payload):
    return np.load(io.BytesIO(payload), allow_pickle=False)


class SonarDataset(Sequence):
    """The samples of a dataset folder in sample order: ``len(ds)``, ``ds[i]``, ``for s in ds``.

    Each sample is a dict of NumPy arrays: ``data`` (uint8, rows x bins; uint16, uint32 for a
    16-, 32-bit A/D), ``intensity`` (float32),
    ``poses`` (rows x 4 x 4), ``times`` (rows), ``segmentation`` (int32 label per bin, names in
    ``ds.labels``), ``first_return`` (float32 m per row, NaN without echo), ``ranges``,
    ``bearings``, ``mesh`` (the ground-truth mesh file, relative to the folder, as a str array),
    ``index`` and ``meta`` (a str array of the sample's settings as JSON). A dataset still being
    written (or interrupted) shows the shards complete so far (``ds.complete`` is False).
    """

    def __init__(self, folder):
        self.folder = os.fspath(folder)
        manifest = read_manifest(self.folder)
        if manifest is None:
            raise DatasetError(f"{self.folder!r}: no {MANIFEST}: not a mitsonar dataset folder")
        self.manifest = manifest
        self.labels = manifest["labels"]
        self.shard_size = manifest["shard_size"]
        self.shards = manifest["shards"]
        self.n = sum(s["count"] for s in self.shards)
        self.complete = self.n == manifest["samples"]
        self._open = (None, None)
        self._pid = os.getpid()

    def __len__(self):
        return self.n

    def __getstate__(self):
        """Pickled (a DataLoader's worker processes, Ray) without the open shard: a copy opens its own."""
        state = dict(self.__dict__)
        state["_open"] = (None, None)
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)
        self._pid = os.getpid()

    def _tar(self, shard):
        if self._pid != os.getpid():
            # A forked copy (a DataLoader worker) shares the open file's read position with its
            # parent: it drops its copy of the handle and opens the shard itself.
            if self._open[1] is not None:
                self._open[1][0].close()   # this process's descriptor only
            self._open, self._pid = (None, None), os.getpid()
        if self._open[0] != shard:
            if self._open[1] is not None:
                self._open[1][0].close()
            tar = tarfile.open(os.path.join(self.folder, self.shards[shard]["name"]), "r")
            self._open = (shard, (tar, {m.name: m for m in tar.getmembers()}))
        return self._open[1]

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self[j] for j in range(*i.indices(self.n))]
        i = int(i)
        if i < 0:
            i += self.n
        if not 0 <= i < self.n:
            raise IndexError(f"sample {i} of a dataset of {self.n}")
        tar, members = self._tar(i // self.shard_size)
        key = sample_key(i)
        out = {name: _load_npy(tar.extractfile(members[f"{key}.{name}.npy"]).read()) for name in FIELDS}
        meta = json.loads(tar.extractfile(members[f"{key}.json"]).read())
        out["index"] = np.asarray(i)
        out["mesh"] = np.asarray(meta.get("mesh", ""))
        out["meta"] = np.asarray(json.dumps(meta, sort_keys=True))
        return out

    def _indices(self):
        try:
            from torch.utils.data import get_worker_info
        except ImportError:
            return range(self.n)
        info = get_worker_info()   # a torch DataLoader worker reads every num_workers-th sample
        return range(self.n) if info is None else range(info.id, self.n, info.num_workers)

    def __iter__(self):
        for i in self._indices():
            yield self[i]

    def __repr__(self):
        return f"SonarDataset({self.folder!r}, {self.n} samples{'' if self.complete else ', incomplete'})"


_TORCH_CLASS = None


def _torch_class():
    """`SonarDataset` that is also a ``torch.utils.data.IterableDataset``, built on first use (so
    torch is imported only then) and bound to this module as ``TorchSonarDataset``: pickle finds
    it by that name (DataLoader workers, spawn), through the module's ``__getattr__``."""
    global _TORCH_CLASS
    if _TORCH_CLASS is None:
        from torch.utils.data import IterableDataset

        _TORCH_CLASS = type("TorchSonarDataset", (SonarDataset, IterableDataset),
                            {"__module__": __name__, "__qualname__": "TorchSonarDataset",
                             "__doc__": SonarDataset.__doc__})
    return _TORCH_CLASS


def __getattr__(name):
    if name == "TorchSonarDataset":
        return _torch_class()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def open_dataset(path):
    """Open a dataset folder written by ``mitsonar dataset``: a `SonarDataset` (a sequence of dicts
    of NumPy arrays, in sample order). When PyTorch is installed it is also a
    ``torch.utils.data.IterableDataset`` (import torch is not needed otherwise); it can be pickled
    and used by a ``DataLoader`` with worker processes (each opens its own shard files)."""
    import importlib.util

    if importlib.util.find_spec("torch") is not None:
        return _torch_class()(path)
    return SonarDataset(path)
