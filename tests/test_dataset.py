"""Datasets at scale (issue 27): the same samples whatever renders them, resumable after an
interrupt or a kill, labels that name the right shape in the right bins, bad configs refused in
one line before any worker starts."""
import json
import os
import re
import signal
import subprocess
import sys
import tarfile
import time

import numpy as np
import pytest
from conftest import ROOT, SCENES

from mitsonar.cli import main
from mitsonar.jobs.dataset import DatasetError, check_config, generate_dataset, open_dataset, read_config
from mitsonar.jobs.dataset.config import config_hash

BOX = os.path.join(SCENES, "box.xml")


def small_config(**over):
    """The box, twelve 30-degree pings of 60 bins, drawn poses, moving or not, materials, noise."""
    cfg = {"seed": 5, "samples": 6, "shard_size": 2, "scene_samples": 3, "spp": 64, "max_depth": 2,
           "scenes": [{"xml": BOX}],
           "sonar": {"kind": "mechanical", "n_bins": 60, "n_pings": 12, "bearing_step": 30.0, "range_max": 8.0},
           "pose": {"x": {"uniform": [-1, 1]}, "yaw": {"uniform": [0, 360]}},
           "trajectory": {"type": {"choice": ["straight", "turn"]}, "speed": {"uniform": [0, 0.5]},
                          "yaw_rate": {"uniform": [-5, 5]}},
           "materials": {"concrete": {"diffuse": {"uniform": [0.05, 0.15]}}},
           "electronics": {"gain": {"uniform": [20, 35]}, "speckle": {"choice": ["rayleigh", "weibull"]}}}
    cfg.update(over)
    return cfg


def folder_bytes(folder):
    """Every file of a dataset folder but its lock, name -> bytes."""
    out = {}
    for root, _, files in os.walk(folder):
        for f in files:
            if f != ".lock":
                path = os.path.join(root, f)
                with open(path, "rb") as fh:
                    out[os.path.relpath(path, folder)] = fh.read()
    return out


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """The small dataset written by one local worker process."""
    out = tmp_path_factory.mktemp("ds") / "one"
    result = generate_dataset(small_config(), str(out), workers=1, engine="local", progress=False)
    assert result == {"rendered": 6, "samples": 6, "seconds": result["seconds"]}
    return out


def test_two_workers_write_what_one_writes(reference, tmp_path):
    generate_dataset(small_config(), str(tmp_path / "two"), workers=2, engine="local", progress=False)
    one, two = folder_bytes(reference), folder_bytes(tmp_path / "two")
    assert sorted(one) == ["manifest.json", "meshes/" + sorted(os.listdir(reference / "meshes"))[0],
                           "shard-000000.tar", "shard-000001.tar", "shard-000002.tar"]
    assert one == two


def test_open_dataset_reads_samples_in_order(reference):
    import mitsonar

    ds = mitsonar.open_dataset(reference)
    assert len(ds) == 6 and ds.complete
    samples = list(ds)
    assert [int(s["index"]) for s in samples] == list(range(6))
    s = ds[-1]
    assert int(s["index"]) == 5
    assert s["data"].dtype == np.uint8 and s["data"].shape == (12, 60)
    assert s["intensity"].dtype == np.float32 and s["segmentation"].shape == (12, 60)
    assert s["poses"].shape == (12, 4, 4) and s["times"].shape == (12,) and s["first_return"].shape == (12,)
    for k in ("data", "intensity", "poses", "segmentation"):
        np.testing.assert_array_equal(s[k], samples[5][k])
    # every bin with echo energy is labelled with a shape of the box, the others 0
    for s in samples:
        np.testing.assert_array_equal(s["segmentation"] > 0, s["intensity"] > 0)
        assert {ds.labels[v] for v in np.unique(s["segmentation"])} <= {"none", "floor", "wall_xpos", "wall_xneg",
                                                                        "wall_ypos", "wall_yneg"}
    mesh = np.load(reference / str(s["mesh"]))
    assert mesh["faces"].shape == (10, 3)          # five rectangles
    # per-sample draws differ (seeds per sample), the scene block is shared
    assert not np.array_equal(samples[0]["poses"], samples[1]["poses"])
    meta = [json.loads(str(s["meta"])) for s in samples]
    assert len({m["scene"] for m in meta}) == 1


def _same_as(reference, folder):
    manifest = json.loads((folder / "manifest.json").read_text())
    tars = sorted(n for n in os.listdir(folder) if n.endswith(".tar"))
    assert [s["name"] for s in manifest["shards"]] == tars       # the manifest and the shards agree
    assert folder_bytes(folder) == folder_bytes(reference)


def test_interrupted_run_resumes_to_the_same_dataset(reference, tmp_path, monkeypatch):
    from mitsonar.jobs.dataset import worker

    render = worker.SampleRenderer.render

    def interrupt_at_3(self, task, want_mesh=False):
        if task["index"] == 3:
            raise KeyboardInterrupt
        return render(self, task, want_mesh)

    out = tmp_path / "resumed"
    monkeypatch.setattr(worker.SampleRenderer, "render", interrupt_at_3)
    with pytest.raises(KeyboardInterrupt):
        generate_dataset(small_config(), str(out), workers=0, progress=False)
    manifest = json.loads((out / "manifest.json").read_text())
    assert [s["name"] for s in manifest["shards"]] == ["shard-000000.tar"]   # samples 0, 1; 2 had no shard yet
    with tarfile.open(out / "shard-000000.tar") as tar:
        assert sorted({n.split(".")[0] for n in tar.getnames()}) == ["00000000", "00000001"]
    (out / ".shard-000001.x.partial.tar").write_bytes(b"left by a killed run")
    monkeypatch.setattr(worker.SampleRenderer, "render", render)
    result = generate_dataset(small_config(), str(out), workers=0, progress=False)
    assert result["rendered"] == 4 and result["samples"] == 6                # only what was missing
    _same_as(reference, out)
    assert generate_dataset(small_config(), str(out), workers=0, progress=False)["rendered"] == 0


def test_killed_command_resumes_to_the_same_dataset(tmp_path):
    """SIGKILL the whole command (coordinator and workers) once a shard is written, run it again.
    60 samples (a sample renders in about 0.03 s): seconds of work are left when the first shard
    appears, so the kill lands mid-run even on a loaded machine (with 6, four samples were left)."""
    cfg_path = tmp_path / "small.json.yaml"
    import yaml

    cfg_path.write_text(yaml.safe_dump(small_config(samples=60)))
    reference = tmp_path / "reference"
    generate_dataset(small_config(samples=60), str(reference), workers=0, progress=False)
    out = tmp_path / "killed"
    cmd = [sys.executable, "-m", "mitsonar", "dataset", str(cfg_path), "-o", str(out), "--workers", "1", "--engine", "local", "-q"]
    proc = subprocess.Popen(cmd, cwd=ROOT, start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.time() + 120
    while time.time() < deadline and proc.poll() is None and not (out / "shard-000000.tar").exists():
        time.sleep(0.01)
    assert proc.poll() is None, f"the command ended before it was killed: {proc.stderr.read().decode()[-500:]}"
    assert (out / "shard-000000.tar").exists(), "no shard written within 120 s"
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    assert proc.returncode == -signal.SIGKILL
    shards = json.loads((out / "manifest.json").read_text())["shards"]
    assert len(shards) < 30                                  # killed with the dataset incomplete
    result = generate_dataset(str(cfg_path), str(out), workers=1, engine="local", progress=False)
    assert result["rendered"] == 60 - 2 * len(shards) > 0   # the resumed run rendered what was missing
    _same_as(reference, out)
    assert main(["dataset", str(cfg_path), "-o", str(out), "--workers", "1", "--engine", "local", "-q"]) == 0


def test_a_killed_worker_process_loses_nothing(reference, tmp_path):
    """SIGKILL one of the two worker processes when the second sample comes back: the pool is
    started again, the samples it held are rendered again, the dataset is the same."""
    import multiprocessing

    class KillOne:
        def __init__(self):
            self.n, self.killed = 0, []

        def update(self, k=1):
            self.n += k
            if self.n == 2:
                child = multiprocessing.active_children()[0]
                os.kill(child.pid, signal.SIGKILL)
                self.killed.append(child.pid)

    spy = KillOne()
    out = tmp_path / "worker_killed"
    generate_dataset(small_config(), str(out), workers=2, engine="local", progress=spy)
    assert len(spy.killed) == 1 and spy.n >= 6
    _same_as(reference, out)


def test_a_pool_broken_at_submit_loses_nothing(reference, tmp_path, monkeypatch):
    """A worker that dies between two waits breaks the pool, and the next submit raises: the sample
    being handed out stays pending (it was once dropped: 5 samples of 6 came back)."""
    import concurrent.futures
    from concurrent.futures.process import BrokenProcessPool

    class Breaking(concurrent.futures.ProcessPoolExecutor):
        calls = 0

        def submit(self, *args, **kwargs):
            Breaking.calls += 1
            if Breaking.calls == 3:
                raise BrokenProcessPool("a worker died")
            return super().submit(*args, **kwargs)

    monkeypatch.setattr(concurrent.futures, "ProcessPoolExecutor", Breaking)
    out = tmp_path / "broken_at_submit"
    result = generate_dataset(small_config(), str(out), workers=2, engine="local", progress=False)
    assert Breaking.calls > 6 and result["samples"] == 6
    _same_as(reference, out)


def test_segmentation_names_the_shape_in_each_bin(tmp_path):
    """Two walls facing the head, 'near' 4 m away along +x and 'far' 7 m away along -x: pings towards
    +x are labelled near from 4 m on, pings towards -x far from 7 m on, sideways pings nothing; the
    first return is the wall's distance."""
    xml = tmp_path / "two.xml"
    xml.write_text("""<scene version="3.0.0">
      <bsdf type="acoustic" id="mat"><float name="diffuse" value="0.5"/><float name="specular" value="0"/></bsdf>
      <shape type="rectangle" id="near"><transform name="to_world"><scale x="2" y="2"/>
        <rotate y="1" angle="-90"/><translate x="4"/></transform><ref id="mat"/></shape>
      <shape type="rectangle" id="far"><transform name="to_world"><scale x="2" y="2"/>
        <rotate y="1" angle="90"/><translate x="-7"/></transform><ref id="mat"/></shape>
    </scene>""")
    cfg = {"samples": 1, "spp": 512, "max_depth": 1, "scenes": [{"xml": str(xml)}],
           "sonar": {"kind": "mechanical", "n_bins": 100, "n_pings": 8, "bearing_step": 45.0, "range_max": 10.0}}
    generate_dataset(cfg, str(tmp_path / "ds"), workers=0, progress=False)
    ds = open_dataset(tmp_path / "ds")
    s = ds[0]
    names = np.array(ds.labels)[s["segmentation"]]
    ranges = s["ranges"]
    bearings = np.degrees(s["bearings"]) % 360
    walls = {0: ("near", 4.0), 180: ("far", 7.0)}
    for row, b in enumerate(bearings):
        hit = names[row] != "none"
        if b in walls:
            # the wall (+-2 m about the boresight) spans ranges d .. sqrt(d^2 + 2^2) within the 35 deg beam
            name, d = walls[b]
            assert hit.sum() >= 2 and set(names[row][hit]) == {name}
            assert d - 0.1 <= ranges[hit].min() and ranges[hit].max() <= np.hypot(d, 2.0) + 0.1   # 0.1 m bins
            assert abs(s["first_return"][row] - d) <= 0.1
        elif b in (90, 270):
            assert not hit.any() and np.isnan(s["first_return"][row])
    assert {"near", "far"} <= set(ds.labels)
    # the labelling pass is sonar_tof's: render_scan with the plain integrator, the same paths
    # (seed, spp, pose), gives the same intensity up to the order of the float64 sums
    import mitsonar
    from mitsonar.jobs.dataset.config import sonar_xml
    from mitsonar.jobs.dataset.worker import DEFAULT_MOUNT

    text = xml.read_text().replace("</scene>", sonar_xml({**cfg["sonar"], "mount": DEFAULT_MOUNT.ravel()}) + "</scene>")
    scene = mitsonar.load_scene(text, optimize=False)
    scan = mitsonar.render_scan(scene, spp=512, seed=json.loads(str(s["meta"]))["seed"], integrator="sonar_tof",
                                max_depth=1, pose=DEFAULT_MOUNT)
    assert scan.intensity.max() > 0
    np.testing.assert_allclose(s["intensity"], scan.intensity, rtol=1e-6, atol=0)


# ----------------------------------------------------------------------------- bad input
@pytest.mark.parametrize("change, words", [
    ({"sampels": 3}, "'sampels': unknown key (allowed: "),
    ({"samples": 0}, "'samples': 0 is not allowed (a whole number from 1 to"),
    ({"shard_size": 0}, "'shard_size': 0 is not allowed"),
    ({"scenes": [{"xml": "/nowhere/scene.xml"}]}, "'scenes[0].xml': scene file '/nowhere/scene.xml' does not exist"),
    ({"scenes": []}, "'scenes': [] is not allowed (a non-empty list"),
    ({"pose": {"x": {"uniform": [2, 1]}}}, "'pose.x.uniform': [2, 1] is not allowed (an ordered range [lo, hi]"),
    ({"pose": {"heading": 3}}, "'pose.heading': unknown key (allowed: pitch, roll, x, y, yaw, z)"),
    ({"electronics": {"gain": {"uniform": [10, 120]}}}, "'gain': 120 is not allowed"),
    ({"electronics": {"speckel": "off"}}, "'electronics.speckel': unknown key"),
    ({"sonar": {"n_bins": 0}}, "'sonar.n_bins': 0 is not allowed"),
    ({"scenes": [{"terrain": {"resolution": {"uniform": [-0.1, 0.2]}}}]},
     "'scenes[0].terrain': terrain 'resolution': -0.1 is not allowed (a number > 0)"),
    ({"scenes": [{"terrain": {"size": [10, 10]}, "material": "mud"}]}, "'scenes[0].material': 'mud' is not allowed (one of"),
    ({"trajectory": {"type": "spiral", "speed": 1}}, "'trajectory.type': 'spiral' is not allowed (one of straight, turn)"),
    ({"materials": {"concrete": {"diffuse": {"choice": []}}}}, "'materials.concrete.diffuse.choice': [] is not allowed"),
    ({"materials": {"steel": {"diffuse": 0.1}}}, "'materials.steel': no scene has a BSDF of that id (their BSDFs: concrete)"),
])
def test_bad_config_is_one_line_naming_the_key(change, words):
    with pytest.raises(DatasetError) as err:
        check_config(small_config(**change))
    assert words in str(err.value) and "\n" not in str(err.value)


def test_bad_config_on_the_command_line_writes_nothing(tmp_path, capsys):
    cfg = tmp_path / "bad.yaml"
    cfg.write_text("samples: 4\nscenes: [{xml: missing.xml}]\n")
    out = tmp_path / "out"
    assert main(["dataset", str(cfg), "-o", str(out), "-q"]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"mitsonar: error: dataset config 'scenes[0].xml' ({cfg} line 2): scene file") and "\n" not in err
    assert not out.exists()


def test_toml_and_yaml_configs_are_the_same_dataset(tmp_path):
    (tmp_path / "c.toml").write_text(f'samples = 2\nspp = 16\n[[scenes]]\nxml = "{BOX}"\n[pose.x]\nuniform = [0, 1]\n')
    (tmp_path / "c.yaml").write_text(f"samples: 2\nspp: 16\nscenes: [{{xml: {BOX}}}]\npose: {{x: {{uniform: [0, 1]}}}}\n")
    a, b = read_config(tmp_path / "c.toml"), read_config(tmp_path / "c.yaml")
    assert a == b and config_hash(a) == config_hash(b)


def test_a_folder_of_another_config_is_not_resumed(reference, tmp_path):
    import shutil

    copy = tmp_path / "copy"
    shutil.copytree(reference, copy)
    with pytest.raises(DatasetError, match=r"holds a dataset of another config \('spp': 64 there, 32 now\)"):
        generate_dataset(small_config(spp=32), str(copy), workers=0, progress=False)
    scene = tmp_path / "box.xml"
    scene.write_text(open(BOX).read())
    generate_dataset(small_config(samples=2, scenes=[{"xml": str(scene)}]), str(tmp_path / "edited"), workers=0,
                     progress=False)
    scene.write_text(open(BOX).read().replace("concrete_good", "concrete_poor"))
    with pytest.raises(DatasetError, match="box.xml changed since this dataset was begun"):
        generate_dataset(small_config(samples=2, scenes=[{"xml": str(scene)}]), str(tmp_path / "edited"), workers=0,
                         progress=False)
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "notes.txt").write_text("mine")
    with pytest.raises(DatasetError, match="holds files but no manifest.json"):
        generate_dataset(small_config(), str(tmp_path / "other"), workers=0, progress=False)


def test_a_second_run_on_the_same_folder_is_refused(reference):
    from mitsonar.jobs.dataset.store import RunLock

    lock = RunLock(str(reference))
    try:
        with pytest.raises(DatasetError, match="another run is writing into this folder"):
            generate_dataset(small_config(), str(reference), workers=0, progress=False)
    finally:
        lock.release()


def test_torch_sees_an_iterable_dataset(reference):
    torch = pytest.importorskip("torch")
    ds = open_dataset(reference)
    assert isinstance(ds, torch.utils.data.IterableDataset)
    batches = list(torch.utils.data.DataLoader(ds, batch_size=None))
    assert len(batches) == 6


def test_ray_actors_write_what_local_workers_write(reference, tmp_path, ray_env):
    pytest.importorskip("ray")
    generate_dataset(small_config(), str(tmp_path / "ray"), workers=2, engine="ray", progress=False)
    assert folder_bytes(tmp_path / "ray") == folder_bytes(reference)


# ----------------------------------------------------------------------------- review fixes
def _scene_folder(root, name, shape_id, corner):
    """``root/name/s.xml``: one OBJ triangle ``m.obj`` (relative name) with the given id and a
    vertex at ``corner``; two folders hold same-named files of different content."""
    folder = root / name
    folder.mkdir()
    (folder / "m.obj").write_text(f"v 0 0 0\nv {corner} 0 0\nv 0 1 0\nf 1 2 3\n")
    (folder / "s.xml").write_text(f"""<scene version="3.0.0">
      <bsdf type="acoustic" id="mat"><float name="diffuse" value="0.5"/><float name="specular" value="0"/></bsdf>
      <shape type="obj" id="{shape_id}"><string name="filename" value="m.obj"/><ref id="mat"/></shape>
    </scene>""")
    return str(folder / "s.xml")


def test_a_worker_loads_the_named_scene_whatever_it_loaded_before(tmp_path):
    """Scenes a/s.xml and b/s.xml (each with its own m.obj) loaded in the order a, b, a by one
    worker are a, b, a: neither the scene file nor its mesh is taken from the other folder."""
    from mitsonar.jobs.dataset.worker import SampleRenderer
    from mitsonar.sim.groundtruth import scene_mesh

    a = _scene_folder(tmp_path, "a", "alpha", 2.0)
    b = _scene_folder(tmp_path, "b", "beta", 5.0)
    cfg = check_config({"samples": 3, "scenes": [{"xml": a}, {"xml": b}],
                        "sonar": {"kind": "mechanical", "n_bins": 10, "n_pings": 2}})
    renderer = SampleRenderer(cfg)
    seen = []
    for entry in (0, 1, 0):
        renderer._load({"entry": entry, "sonar": dict(cfg["sonar"]), "key": f"scene{entry}-{len(seen)}"})
        vertices = scene_mesh(renderer.scene)[0]
        seen.append((renderer.names, float(vertices[:, 0].max())))
    renderer.close()
    assert seen == [(["alpha"], 2.0), (["beta"], 5.0), (["alpha"], 2.0)]


def _same_sample(a, b):
    assert sorted(a) == sorted(b)
    for k in a:
        np.testing.assert_array_equal(a[k], b[k])


def test_an_open_dataset_pickles_and_a_forked_copy_opens_its_own_shard(reference, monkeypatch):
    """What a DataLoader with worker processes does: pickle the dataset after it has read a sample
    (spawn), or use it in a forked process (a new pid: it must not read through the parent's file)."""
    import pickle

    from mitsonar.jobs.dataset import store

    ds = store.SonarDataset(reference)
    first = ds[1]
    copy = pickle.loads(pickle.dumps(ds))
    assert len(copy) == 6 and copy.labels == ds.labels
    _same_sample(copy[1], first)
    parent_tar = ds._tar(0)[0]
    monkeypatch.setattr(store.os, "getpid", lambda: -1)      # as in a forked child
    _same_sample(ds[0], copy[0])
    assert ds._tar(0)[0] is not parent_tar and parent_tar.closed


def test_the_torch_flavoured_dataset_pickles_by_name(reference, monkeypatch):
    """open_dataset's torch subclass (built here on a stand-in torch.utils.data, so the test needs no
    torch) is a module-level class: pickle finds it by name, which DataLoader workers need."""
    import importlib.machinery
    import pickle
    import types

    from mitsonar.jobs.dataset import store

    class IterableDataset:   # torch's: a plain base class
        pass

    for name in ("torch", "torch.utils", "torch.utils.data"):
        mod = types.ModuleType(name)
        mod.__spec__ = importlib.machinery.ModuleSpec(name, None)
        monkeypatch.setitem(sys.modules, name, mod)
    sys.modules["torch.utils.data"].IterableDataset = IterableDataset
    monkeypatch.setattr(store, "_TORCH_CLASS", None, raising=False)
    ds = open_dataset(reference)
    assert isinstance(ds, IterableDataset) and type(ds).__module__ == "mitsonar.jobs.dataset.store"
    ds[0]
    copy = pickle.loads(pickle.dumps(ds))
    assert type(copy) is type(ds)
    _same_sample(copy[4], ds[4])


def test_import_mitsonar_needs_no_posix_fcntl():
    """Windows has no fcntl: only taking the run lock may need it, not ``import mitsonar``."""
    code = "import sys; sys.modules['fcntl'] = None; import mitsonar; print(mitsonar.open_dataset.__name__)"
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True)
    assert out.returncode == 0 and out.stdout.strip() == "open_dataset", out.stderr[-500:]


def test_the_manifest_is_read_under_the_lock(reference, tmp_path, monkeypatch):
    """Another run finishes the dataset while this one waits for the lock: this one must see its
    manifest (nothing to render), not the empty folder it saw before taking the lock."""
    import shutil

    from mitsonar.jobs.dataset import runner
    from mitsonar.jobs.dataset.store import RunLock

    out = tmp_path / "raced"

    class FinishedMeanwhile(RunLock):
        def __init__(self, folder):
            for name in os.listdir(reference):
                src = reference / name
                (shutil.copytree if src.is_dir() else shutil.copy)(src, out / name)
            super().__init__(folder)

    monkeypatch.setattr(runner, "RunLock", FinishedMeanwhile)
    assert generate_dataset(small_config(), str(out), workers=0, progress=False)["rendered"] == 0
    _same_as(reference, out)


def test_the_lock_is_released_when_preparing_the_folder_fails(tmp_path, monkeypatch):
    from mitsonar.jobs.dataset import runner
    from mitsonar.jobs.dataset.store import RunLock

    def fail(folder):
        raise PermissionError(f"{folder}: cannot remove a partial file")

    monkeypatch.setattr(runner, "remove_partials", fail)
    with pytest.raises(PermissionError):
        generate_dataset(small_config(), str(tmp_path / "ds"), workers=0, progress=False)
    RunLock(str(tmp_path / "ds")).release()     # free: a second run is not refused


def test_each_scene_block_draws_its_own_speckle_seed(reference):
    """The scene's speckle belongs to the scene: the samples of a block (scene_samples = 3) share a
    speckle seed drawn from the config's seed and the block, the two blocks differ, the render used
    it (its electronics record it) and the draw is the task's, whatever worker rendered it."""
    from mitsonar.jobs.dataset.config import task

    ds = open_dataset(reference)
    meta = [json.loads(str(s["meta"])) for s in ds]
    seeds = [m["speckle_seed"] for m in meta]
    assert seeds[0] == seeds[1] == seeds[2] != seeds[3] == seeds[4] == seeds[5]
    assert all(m["electronics"]["speckle_seed"] == m["speckle_seed"] for m in meta)
    cfg = check_config(small_config())
    assert seeds == [task(cfg, i)["sample"]["speckle_seed"] for i in range(6)]


def test_the_config_fixes_or_draws_the_speckle_seed():
    from mitsonar.jobs.dataset.config import task

    fixed = check_config(small_config(electronics={"speckle_seed": 7}))
    assert {task(fixed, i)["sample"]["speckle_seed"] for i in range(6)} == {7}
    drawn = check_config(small_config(samples=30, electronics={"speckle_seed": {"randint": [10, 12]}}))
    seeds = [task(drawn, i)["sample"]["speckle_seed"] for i in range(30)]
    assert all(seeds[i] == seeds[i - i % 3] for i in range(30))           # one per block of 3
    assert set(seeds) == {10, 11, 12}                                     # 10 blocks: P(a value missing) < 0.06
    for bad, words in (({"uniform": [0, 5]}, "'electronics.speckle_seed': {'uniform': [0, 5]} is not allowed"),
                       (-1, "'electronics.speckle_seed': -1 is not allowed (a whole number >= 0")):
        with pytest.raises(DatasetError, match=re.escape(words)):
            check_config(small_config(electronics={"speckle_seed": bad}))


@pytest.mark.parametrize("workers, engine, allowed", [
    ("-2", "local", "a whole number >= 1 of worker processes, or 0 to render in this process"),
    ("-1", "auto", "a whole number >= 1 of worker processes, or 0 to render in this process"),
    ("0", "ray", "Ray actors: a whole number >= 1"),
])
def test_workers_out_of_range_are_one_line_with_the_allowed_values(tmp_path, capsys, workers, engine, allowed):
    """``--workers 0`` renders in this process (documented); below 0 (or 0 on Ray) is refused in
    one line naming the allowed values, before the folder is made."""
    import yaml

    cfg_path = tmp_path / "small.yaml"
    cfg_path.write_text(yaml.safe_dump(small_config()))
    out = tmp_path / "ds"
    assert main(["dataset", str(cfg_path), "-o", str(out), "--workers", workers, "--engine", engine, "-q"]) == 1
    err = capsys.readouterr().err.strip()
    assert err == f"mitsonar: error: --workers {workers} is not allowed ({allowed})", err
    assert not out.exists()
    with pytest.raises(SystemExit):
        main(["dataset", "--help"])
    assert "0: render in this process" in " ".join(capsys.readouterr().out.split())
