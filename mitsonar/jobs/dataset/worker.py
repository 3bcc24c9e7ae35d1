"""One dataset worker: loads a scene once, renders many samples of it, writes nothing.

A `SampleRenderer` lives in one process (a local process of the pool, or a Ray actor) with one
Mitsuba variant; it keeps the scene it loaded last and reloads only when a task names another
scene. It returns each sample as a dict of NumPy arrays to the coordinator, which alone writes the
dataset folder: a worker that is killed, or outlives its run, cannot write anything there.
"""
from __future__ import annotations

import math
import os
import shutil
import tempfile
from xml.sax.saxutils import quoteattr

import numpy as np

import mitsonar.kinds as kinds

# The standard mount of a mechanical or multibeam head on the vehicle (REP-103: x forward, y port,
# z up): boresight at bearing 0 forward, scan axis up (beam x = vehicle y, beam y = vehicle z,
# beam z = vehicle x). A side-scan head's default mount is the identity.
DEFAULT_MOUNT = np.array([[0, 0, 1, 0], [1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 0, 1]], dtype=np.float64)


def set_threads(threads):
    """Dr.Jit's render threads in this process (None: leave Dr.Jit's default, all cores)."""
    if threads:
        import drjit as dr

        dr.set_thread_count(int(threads))


def vehicle_pose(pose) -> np.ndarray:
    """4x4 vehicle pose ``T(x, y, z) Rz(yaw) Ry(pitch) Rx(roll)`` of a drawn ``pose`` (m, deg)."""
    yaw, pitch, roll = (math.radians(float(pose.get(k, 0.0))) for k in ("yaw", "pitch", "roll"))
    cz, sz, cy, sy, cx, sx = math.cos(yaw), math.sin(yaw), math.cos(pitch), math.sin(pitch), math.cos(roll), math.sin(roll)
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    m = np.eye(4)
    m[:3, :3] = rz @ ry @ rx
    m[:3, 3] = [float(pose.get(k, 0.0)) for k in ("x", "y", "z")]
    return m


class SampleRenderer:
    """Renders dataset samples from tasks (`config.task`); see the module docstring.

    ``cfg`` is the checked config; ``threads`` the Dr.Jit threads of this process."""

    def __init__(self, cfg, threads=None):
        set_threads(threads)
        from mitsonar.sim.variant import ensure_variant

        ensure_variant()   # selects the variant (MITSONAR_VARIANT) and registers the plugins

        self.cfg = cfg
        self.key = None
        self.scene = self.sensor = self.integrator = self.params = None
        self.names = []
        self.tmp = None   # a folder for terrain meshes, made when the first one is

    def close(self):
        if self.tmp is not None:
            shutil.rmtree(self.tmp, ignore_errors=True)

    # ------------------------------------------------------------------ scenes
    def _load(self, draw):
        import mitsuba as mi

        from mitsonar.sim.scene import load_scene
        from mitsonar.jobs.dataset.config import TERRAIN_BSDF, sonar_xml
        from mitsonar.jobs.dataset.labels import labelling_integrator, shape_names

        entry = self.cfg["scenes"][draw["entry"]]
        sonar = dict(draw["sonar"])
        if "xml" in entry:
            folder = os.path.dirname(os.path.abspath(entry["xml"]))
            body = f'<include filename={quoteattr(os.path.abspath(entry["xml"]))}/>'
        else:
            from mitsonar.scenes.terrain import Terrain

            if self.tmp is None:
                self.tmp = tempfile.mkdtemp(prefix="mitsonar-dataset-")
            folder = self.tmp
            terrain = Terrain(**draw["terrain"])
            ply = os.path.join(self.tmp, f"{draw['key']}.ply")   # removed once loaded (Mitsuba reads it whole)
            terrain.write_ply(ply)
            body = (f'<bsdf type="acoustic" id="{TERRAIN_BSDF}"><string name="preset" value="{draw["material"]}"/>'
                    f'</bsdf><shape type="ply" id="seabed"><string name="filename" value="{ply}"/>'
                    f'<ref id="{TERRAIN_BSDF}"/></shape>')
        if sonar:   # a side-scan head's to_world is the head frame itself (x forward, y port, z up)
            kind = kinds.lookup(sonar.get("kind"))
            mount = np.eye(4) if kind is not None and kind.head_frame_mount else DEFAULT_MOUNT
            sonar.setdefault("mount", mount.ravel().tolist())
            body += sonar_xml(sonar)
        # The included scene's own files (PLY meshes, nested includes) resolve from its folder,
        # first, for this load only: Mitsuba's file resolver is process-wide, and a folder left in
        # it by an earlier load would let a same-named file there win (a worker's history would
        # choose the scene). The resolver is put back as it was after the load.
        resolver = mi.file_resolver()
        saved = [str(p) for p in resolver]
        resolver.prepend(folder)
        # optimize=False: Mitsuba would merge the shapes sharing a BSDF into one mesh, and the
        # labels need each shape as itself.
        try:
            scene = load_scene(f'<scene version="3.0.0">{body}</scene>', optimize=False)
        finally:
            resolver.clear()
            for p in saved:
                resolver.append(p)
            if "terrain" in draw:
                os.remove(ply)
        from mitsonar.sim.variant import ensure_variant

        ensure_variant()
        from mitsonar.plugins.sensors.sonar import SonarSensor

        sonars = [s for s in scene.sensors() if isinstance(s, SonarSensor)]
        if not sonars:
            from mitsonar.jobs.dataset.config import DatasetError

            raise DatasetError(f"dataset config 'scenes[{draw['entry']}]': the scene has no sonar sensor; give 'sonar'")
        self.sensor = sonars[-1]   # ours comes last (after the included scene's)
        integ = scene.integrator()
        depth = self.cfg.get("max_depth") or getattr(integ, "max_depth", 5)
        self.integrator = labelling_integrator(depth, getattr(integ, "sampling", "sobol"))
        self.scene, self.key, self.names = scene, draw["key"], shape_names(scene)
        self.params = mi.traverse(scene)
        self.defaults = {k: float(self.params[k][0]) for k in self.params.keys()
                         if k.rsplit(".", 1)[-1] in ("diffuse", "specular", "shininess")}

    def _materials(self, materials):
        """Set the drawn material parameters (and every other one back to its scene value). A BSDF
        id this scene does not have is left out (another scene of the config has it); a BSDF
        wrapped in another (``twosided``) is reached by the outer id."""
        values = dict(self.defaults)
        for bsdf, fields in materials.items():
            for field, v in fields.items():
                for key in self.defaults:
                    prefix, name = key.rsplit(".", 1)
                    if name == field and (prefix == bsdf or prefix.startswith(bsdf + ".")):
                        values[key] = float(v)
        changed = False
        for k, v in values.items():
            if float(self.params[k][0]) != v:
                self.params[k] = v
                changed = True
        if changed:
            self.params.update()

    # ------------------------------------------------------------------ samples
    def render(self, task, want_mesh=False) -> dict:
        """Sample ``task['index']``: a dict of arrays (``data``, ``intensity``, ``poses``, ``times``,
        ``segmentation`` with this scene's labels, ``first_return``, ``ranges``, ``bearings``), its
        ``shape_names``, ``scene`` key and, when ``want_mesh``, the scene's ground-truth ``mesh``."""
        from mitsonar.sim.groundtruth import scene_mesh
        from mitsonar.sim.render import render_scan
        from mitsonar.geometry.trajectory import Trajectory
        from mitsonar.jobs.dataset.labels import first_return, segmentation

        if task["scene"]["key"] != self.key:
            self._load(task["scene"])
        s = task["sample"]
        self._materials(s["materials"])
        vehicle = vehicle_pose(s["pose"])
        mount = self.sensor.to_world_np
        kwargs = {}
        if s["trajectory"]:
            t = s["trajectory"]
            duration = float(self.sensor.ping_times()[-1]) + float(self.sensor.ping_period) + 0.2
            rate = float(t.get("yaw_rate", 0.0)) if t["type"] == "turn" else 0.0
            kwargs.update(trajectory=Trajectory.turn(duration, float(t["speed"]), rate, start=vehicle, dt=0.1),
                          pose=mount)
        else:
            kwargs["pose"] = vehicle @ mount
        scan = render_scan(self.scene, spp=self.cfg["spp"], seed=s["seed"], integrator=self.integrator,
                           sensor=self.sensor, electronics=s["electronics"] or None,
                           electronics_seed=s["electronics_seed"], speckle_seed=s["speckle_seed"], **kwargs)
        energy = self.integrator.last_energy
        out = {"index": task["index"], "scene": self.key, "shape_names": list(self.names),
               "arrays": {"data": scan.data, "intensity": scan.intensity, "poses": scan.poses, "times": scan.times,
                          "segmentation": segmentation(energy),
                          "first_return": first_return(scan.intensity, scan.ranges, self.cfg["first_return_db"]),
                          "ranges": scan.ranges, "bearings": scan.bearings},
               "meta": {"kind": scan.kind, "seed": s["seed"], "speckle_seed": s["speckle_seed"],
                        "electronics": scan.electronics.to_dict(),
                        "pose": s["pose"], "trajectory": s["trajectory"], "materials": s["materials"],
                        "range_min": scan.range_min, "range_max": scan.range_max}}
        if want_mesh:
            out["mesh"] = scene_mesh(self.scene)
        return out


# ----------------------------------------------------------------------------- process pool
_renderer = None


def init_process(cfg, threads, variant):
    """Initializer of a local worker process (spawned): its variant, threads and renderer."""
    global _renderer
    from multiprocessing.util import Finalize

    if variant:
        os.environ["MITSONAR_VARIANT"] = variant
    _renderer = SampleRenderer(cfg, threads)
    Finalize(_renderer, _renderer.close, exitpriority=10)   # runs when the pool's process exits


def render_in_process(task, want_mesh=False):
    """A pool task: the process's renderer renders ``task``."""
    return _renderer.render(task, want_mesh)
