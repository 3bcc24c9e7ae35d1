"""`mitsonar dataset --address HOST:PORT` on a Ray cluster: a head started the documented way
(``ray start --head --node-ip-address 127.0.0.1 --port PORT``, token authentication on as recent
Ray turns it on when a token exists) on this machine's loopback only; the command joins it and
writes byte for byte what the local engine writes; the actors of a SIGKILLed command end; an
address where no head runs is one line and no output folder."""
import os
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest
import yaml
from conftest import ROOT, drjit_cache_dir, ray_sandbox

from mitsonar.jobs.dataset import generate_dataset
from test_dataset import folder_bytes, small_config
from test_dataset_lifetime import GONE_WITHIN_S, children, process, still_running

ray = pytest.importorskip("ray", reason="the cluster extra (Ray) is not installed")

pytestmark = pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="reads the process table in /proc (Linux)")

HEAD_START_S = 180   # bound on waiting for `ray start --head` (it takes seconds)


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def descendants(pid):
    """pid -> (start time, command line) of every live descendant of ``pid``."""
    out, todo = {}, [pid]
    while todo:
        for child, info in children(todo.pop()).items():
            if child not in out:
                out[child] = info
                todo.append(child)
    return out


@pytest.fixture(scope="module")
def ray_head():
    """A Ray head on 127.0.0.1 only, in a `ray_sandbox` whose ~/.ray/auth_token turns token
    authentication on (as any earlier local ray.init() does); ``env`` is the environment a
    command joining it runs in. Stopped at the end by killing the processes it started (``ray
    stop`` would stop every Ray instance of this user on the machine)."""
    with ray_sandbox() as (env, home):
        yield from _head(env, Path(home))


def _head(env, home):
    """`ray_head`'s head, started in ``env`` (HOME ``home``)."""
    (home / ".ray").mkdir()
    (home / ".ray" / "auth_token").write_text(secrets.token_hex(32))
    temp = env["RAY_TMPDIR"]
    port = free_port()
    log_path = home / "head.log"
    cmd = [sys.executable, "-m", "ray.scripts.scripts", "start", "--head", "--node-ip-address", "127.0.0.1",
           "--port", str(port), "--temp-dir", temp, "--num-cpus", "2", "--include-dashboard", "false",
           "--disable-usage-stats", "--block"]
    with open(log_path, "w") as log:
        proc = subprocess.Popen(cmd, env=env, cwd=ROOT, start_new_session=True, stdout=log, stderr=subprocess.STDOUT)
    try:
        deadline = time.monotonic() + HEAD_START_S
        while time.monotonic() < deadline and proc.poll() is None and "Ray runtime started" not in log_path.read_text():
            time.sleep(0.2)
        text = log_path.read_text()
        assert "Ray runtime started" in text, f"ray start --head did not start: {text[-1500:]}"
        try:
            from ray._private.authentication import authentication_token_setup  # noqa: F401
        except ImportError:
            pass   # a Ray without token authentication
        else:
            assert "Token authentication is enabled" in text, text[-1500:]
        yield {"address": f"127.0.0.1:{port}", "env": env, "pid": proc.pid}
    finally:
        kids = descendants(proc.pid)
        for pid in [proc.pid] + list(kids):
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        proc.wait()
        deadline = time.monotonic() + GONE_WITHIN_S
        while still_running(kids) and time.monotonic() < deadline:
            time.sleep(0.1)


@pytest.fixture(scope="module")
def local(tmp_path_factory):
    out = tmp_path_factory.mktemp("ds") / "local"
    generate_dataset(small_config(), str(out), workers=0, progress=False)
    return out


def dataset_command(cfg_path, out, address, *extra):
    return [sys.executable, "-m", "mitsonar", "dataset", str(cfg_path), "-o", str(out), "--address", address,
            "--workers", "2", "--threads", "1", "-q", *extra]


def test_the_command_on_a_loopback_head_writes_what_the_local_engine_writes(ray_head, local, tmp_path):
    cfg_path = tmp_path / "small.yaml"
    cfg_path.write_text(yaml.safe_dump(small_config()))
    out = tmp_path / "cluster"
    run = subprocess.run(dataset_command(cfg_path, out, ray_head["address"]), cwd=ROOT, env=ray_head["env"],
                         capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-1500:]
    assert f"{out}: 6 samples (6 rendered now" in run.stdout
    assert folder_bytes(out) == folder_bytes(local)
    assert not (out / ".lock").exists()


# Samples of the runs these tests kill (never rendered in full): a sample renders in about 0.03 s,
# so with 12 the two actors once finished them all before the test saw the first shard and both
# actors (CI, 2026-11-29: "the command ended before it was killed"); 400 leave seconds of work.
KILLED_SAMPLES = 400
def test_the_actors_of_a_killed_command_end(ray_head, tmp_path):
    """SIGKILL the command (the Ray driver) once a shard is written: the head's actors rendering
    for it end (a job's actors end with its driver); the head itself keeps running."""
    cfg_path = tmp_path / "killed.yaml"
    cfg_path.write_text(yaml.safe_dump(small_config(samples=KILLED_SAMPLES)))
    out = tmp_path / "killed"
    proc = subprocess.Popen(dataset_command(cfg_path, out, ray_head["address"]), cwd=ROOT, env=ray_head["env"],
                            start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 300
        while time.monotonic() < deadline and proc.poll() is None and not (out / "shard-000000.tar").exists():
            time.sleep(0.02)
        actors = {pid: info for pid, info in descendants(ray_head["pid"]).items() if "DatasetActor" in info[1]}
        assert proc.poll() is None, f"the command ended before it was killed: {proc.stderr.read().decode()[-500:]}"
        assert len(actors) == 2, descendants(ray_head["pid"])
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
        deadline = time.monotonic() + GONE_WITHIN_S
        while still_running(actors) and time.monotonic() < deadline:
            time.sleep(0.1)
        left = still_running(actors)
        assert not left, f"still running {GONE_WITHIN_S} s after their driver was killed: {left}"
        assert process(ray_head["pid"]) is not None
    finally:
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass


def test_the_actors_of_a_killed_command_on_its_own_ray_end(ray_env, tmp_path):
    """Without --address, ``--engine ray`` starts Ray for itself: SIGKILL the command once a shard is written, and its actors end with it. (Ray's
    own dashboard and runtime-env agents outlive it by about a minute, their GCS timeout, before
    they exit: Ray's, not this command's; the test ends them.)"""
    cfg_path = tmp_path / "killed.yaml"
    cfg_path.write_text(yaml.safe_dump(small_config(samples=KILLED_SAMPLES)))
    out = tmp_path / "killed"
    cmd = [sys.executable, "-m", "mitsonar", "dataset", str(cfg_path), "-o", str(out), "--engine", "ray",
           "--workers", "2", "--threads", "1", "-q"]
    proc = subprocess.Popen(cmd, cwd=ROOT, env=ray_env, start_new_session=True, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE)
    started = {}
    try:
        # Wait for the first shard, then until both actors show under their names: on a busy
        # machine a worker process takes its actor's title only a moment after it starts.
        deadline = time.monotonic() + 300
        actors = {}
        while time.monotonic() < deadline and proc.poll() is None and (
                not (out / "shard-000000.tar").exists() or len(actors) < 2):
            time.sleep(0.05)
            started = descendants(proc.pid)
            actors = {pid: info for pid, info in started.items() if "DatasetActor" in info[1]}
        assert proc.poll() is None, f"the command ended before it was killed: {proc.stderr.read().decode()[-500:]}"
        assert len(actors) == 2, started
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
        deadline = time.monotonic() + GONE_WITHIN_S
        while still_running(actors) and time.monotonic() < deadline:
            time.sleep(0.1)
        left = still_running(actors)
        assert not left, f"still running {GONE_WITHIN_S} s after their driver was killed: {left}"
    finally:
        for pid in [proc.pid] + list(started):   # the processes this test started, by id
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        proc.wait()


def test_an_address_without_a_head_is_one_line_and_no_folder(ray_head, tmp_path):
    cfg_path = tmp_path / "small.yaml"
    cfg_path.write_text(yaml.safe_dump(small_config()))
    out = tmp_path / "nowhere"
    address = f"127.0.0.1:{free_port()}"
    run = subprocess.run(dataset_command(cfg_path, out, address), cwd=ROOT, env=ray_head["env"],
                         capture_output=True, text=True, timeout=600)
    assert run.returncode != 0
    errors = [line for line in run.stderr.splitlines() if line.startswith("mitsonar: error:")]
    assert len(errors) == 1 and f"--address '{address}'" in errors[0] and "nothing answers there" in errors[0], run.stderr[-1500:]
    assert not out.exists()


@pytest.mark.parametrize("address", ["head", "head:port", "ray://:10001"])
def test_a_malformed_address_is_one_line_and_no_folder(address, tmp_path):
    from mitsonar.jobs.dataset import DatasetError

    with pytest.raises(DatasetError, match=r"--address .* is not allowed \(HOST:PORT of a Ray head"):
        generate_dataset(small_config(), str(tmp_path / "ds"), address=address, workers=2, progress=False)
    assert not (tmp_path / "ds").exists()


def test_the_tests_that_start_ray_leave_nothing_in_home_or_ray_tmpdir(tmp_path):
    """The tests that start Ray (marker ``starts_ray``: `ray_env`, ``ray_head``), run by a pytest
    of their own whose HOME and RAY_TMPDIR (Ray's /tmp) are empty folders: no ~/.ray (a local
    ray.init() writes ~/.ray/auth_token, which turns token authentication on for every later Ray
    head of the user) and nothing in RAY_TMPDIR (Ray's sessions, /tmp/ray/session_* by default)."""
    home = tmp_path / "home"
    home.mkdir()
    ray_tmp = tempfile.mkdtemp(prefix="mrayck", dir="/tmp")   # short, as Ray's sockets would be under it
    env = {k: v for k, v in os.environ.items() if not k.startswith("RAY_")}
    env.update(HOME=str(home), RAY_TMPDIR=ray_tmp, DRJIT_CACHE_DIR=drjit_cache_dir())
    cmd = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-m", "starts_ray",
           "tests/test_dataset.py", "tests/test_dataset_ray.py"]
    try:
        run = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=900)
        summary = [line for line in run.stdout.splitlines() if " passed" in line or " failed" in line]
        assert run.returncode == 0 and summary and "skipped" not in summary[-1], run.stdout[-3000:]
        assert not (home / ".ray").exists(), sorted(map(str, (home / ".ray").rglob("*")))
        assert os.listdir(ray_tmp) == []
    finally:
        shutil.rmtree(ray_tmp, ignore_errors=True)
