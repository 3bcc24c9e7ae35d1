"""A dataset run's processes and files when it ends: the local workers (and the multiprocessing
resource tracker) die with a SIGKILLed coordinator, a finished run leaves no ``.lock``, and the
killed run's shards are kept and resumed."""
import os
import signal
import subprocess
import sys
import time

import pytest
import yaml
from conftest import ROOT

from mitsonar.jobs.dataset import generate_dataset
from mitsonar.jobs.dataset.store import LOCK, RunLock
from test_dataset import folder_bytes, small_config

# How long the workers of a killed coordinator may take to go: a bound on a poll, not a speed
# requirement (they go within about a second: a parent-death signal, a watchdog every 0.5 s);
# before the fix they were still running minutes later.
GONE_WITHIN_S = 20


def process(pid):
    """(state, ppid, start time in ticks, command line) of a running process, or None."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            stat = f.read()
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            cmdline = f.read().replace(b"\0", b" ").decode(errors="replace").strip()
    except (FileNotFoundError, ProcessLookupError):
        return None
    fields = stat[stat.rindex(")") + 2:].split()
    return fields[0], int(fields[1]), int(fields[19]), cmdline


def children(pid):
    """pid -> (start time, command line) of the live children of ``pid``."""
    out = {}
    for name in os.listdir("/proc"):
        if name.isdigit():
            p = process(int(name))
            if p is not None and p[1] == pid and p[0] != "Z":
                out[int(name)] = (p[2], p[3])
    return out


def still_running(procs):
    """The command lines of ``procs`` (pid -> (start time, command line)) still running: the
    same process (start time), not a zombie."""
    left = []
    for pid, (start, cmdline) in procs.items():
        p = process(pid)
        if p is not None and p[0] != "Z" and p[2] == start:
            left.append(f"{pid} {cmdline[:120]}")
    return left


pytestmark = pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="reads the process table in /proc (Linux)")


# Samples of the killed run, in shards of 2. A sample renders in about 0.03 s, so two workers have
# about two seconds of work left when the first shard appears, against the milliseconds the test
# takes to kill the coordinator: with 12 samples a loaded machine once let the run write all six
# shards before the kill landed (CI, 2026-11-29).
SAMPLES = 120
SHARDS = SAMPLES // 2


@pytest.fixture(scope="module")
def full(tmp_path_factory):
    """`SAMPLES` samples in shards of 2, rendered in this process: what any run must end with."""
    out = tmp_path_factory.mktemp("ds") / "full"
    generate_dataset(small_config(samples=SAMPLES), str(out), workers=0, progress=False)
    return out


def test_a_finished_run_leaves_no_lock(full):
    assert sorted(os.listdir(full)) == ["manifest.json", "meshes"] + [f"shard-{k:06d}.tar" for k in range(SHARDS)]
    assert not (full / LOCK).exists()


def test_a_killed_coordinator_takes_its_workers_along(full, tmp_path):
    """SIGKILL the coordinator alone (not its process group) of ``mitsonar dataset --workers 2``
    once it has written a shard: its two worker processes and the resource tracker end too; the
    shards written are kept, and the same command resumes to the dataset an uninterrupted run
    writes, leaving no lock file."""
    cfg_path = tmp_path / "run.yaml"
    cfg_path.write_text(yaml.safe_dump(small_config(samples=SAMPLES)))
    out = tmp_path / "killed"
    cmd = [sys.executable, "-m", "mitsonar", "dataset", str(cfg_path), "-o", str(out), "--workers", "2",
           "--threads", "1", "--engine", "local", "-q"]
    proc = subprocess.Popen(cmd, cwd=ROOT, start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 300
        while time.monotonic() < deadline and proc.poll() is None and not (out / "shard-000000.tar").exists():
            time.sleep(0.005)
        kids = children(proc.pid)
        assert proc.poll() is None, f"the command ended before it was killed: {proc.stderr.read().decode()[-500:]}"
        assert (out / "shard-000000.tar").exists(), "no shard written within 300 s"
        workers = [c for _, c in kids.values() if "spawn_main" in c]
        assert len(workers) == 2, kids
        os.kill(proc.pid, signal.SIGKILL)   # the coordinator only: no chance to stop anything
        proc.wait()
        deadline = time.monotonic() + GONE_WITHIN_S
        while still_running(kids) and time.monotonic() < deadline:
            time.sleep(0.1)
        left = still_running(kids)
        assert not left, f"still running {GONE_WITHIN_S} s after their coordinator was killed: {left}"
    finally:
        try:
            os.killpg(proc.pid, signal.SIGKILL)   # whatever the test left of the group
        except ProcessLookupError:
            pass
    shards = len(yaml.safe_load((out / "manifest.json").read_text())["shards"])
    # killed mid-run: the shards the manifest lists (shard 0 too, unless the kill fell between its
    # rename and the manifest's), and a stale lock file
    assert shards < SHARDS and (out / LOCK).exists()
    result = generate_dataset(str(cfg_path), str(out), workers=0, progress=False)
    assert result["rendered"] == SAMPLES - 2 * shards            # nothing written was lost or redone
    assert folder_bytes(out) == folder_bytes(full) and not (out / LOCK).exists()


def test_a_run_that_locked_a_removed_lock_file_takes_the_new_one(tmp_path, monkeypatch):
    """Run B opens ``.lock`` just before run A, finishing, removes it and unlocks: B's flock then
    succeeds on the removed file. B must notice and lock the file at the path, or a third run C
    would create a new ``.lock``, lock it, and write beside B."""
    from mitsonar.jobs.dataset import store

    a = RunLock(str(tmp_path))
    stale = os.open(a.path, os.O_RDWR)   # B's open, before A releases
    a.release()
    assert not os.path.exists(a.path)
    opened = []
    real_open = os.open

    def open_stale_first(path, flags, mode=0o777):
        opened.append(path)
        return os.dup(stale) if len(opened) == 1 else real_open(path, flags, mode)

    monkeypatch.setattr(store.os, "open", open_stale_first)
    b = RunLock(str(tmp_path))
    monkeypatch.setattr(store.os, "open", real_open)
    os.close(stale)
    try:
        assert len(opened) == 2 and os.path.samestat(os.fstat(b.fd), os.stat(b.path))
        with pytest.raises(Exception, match="another run is writing into this folder"):
            RunLock(str(tmp_path))
    finally:
        b.release()
    assert not os.path.exists(b.path)
