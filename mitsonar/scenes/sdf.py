"""A Gazebo SDF world's static models as a mitsonar scene.

    from mitsonar.scenes import scene_from_sdf
    world = scene_from_sdf("harbour.world", "harbour.xml", model_path=["models/"])
    world.skipped           # one line per thing that was not converted

or ``mitsonar scene from-sdf harbour.world --model-path models/ -o harbour.xml``
(docs/tutorials/your_world.rst).

What is placed: every static model (``<static>true</static>``, or a model nested in one) of the
world, written inline or by ``<include><uri>model://NAME</uri>`` (resolved in ``model_path``, then
the folders of ``GAZEBO_MODEL_PATH`` and ``GZ_SIM_RESOURCE_PATH``: ``NAME/model.config`` names the
model's SDF file, else ``NAME/model.sdf``), each link's visuals (its collisions when it has none)
with the geometries

* ``box`` (Mitsuba ``cube``), ``sphere`` (``sphere``), ``cylinder`` (``cylinder`` and two
  ``disk`` caps), ``plane`` (a ``rectangle`` of its ``size`` facing its ``normal``);
* ``mesh`` (STL, OBJ, DAE, glTF/GLB, PLY through `mitsonar.scenes.meshes`, times its ``<scale>``;
  STL and OBJ times ``scale`` as well), written as PLY files beside the scene
  (``<stem>_mesh_<k>.ply``, one per mesh file and ``<scale>``, placed again by
  another transform where the world uses it again; face normals);
* the first ``heightmap``: its image or DEM (read by rasterio) over ``<size>`` x, y centred at
  ``<pos>``, height ``pos.z + value * size.z`` for an image (``value`` the pixel over its type's
  largest), ``pos.z + value`` for a float DEM;

at the pose SDF composes (world, model, link, visual: ``x y z roll pitch yaw``, rotations about
the fixed x, y, z axes in that order; ``degrees="true"`` honoured). The world's z = 0 is the
water level. Each model's shapes take the material of the first pattern (fnmatch, on the
model's name) of ``materials`` (a CSV ``pattern,material`` or a YAML mapping or list of
``{pattern, material}``), else ``material`` (default ``rock``): names as in
`mitsonar.scenes.worldxml`. The sonar is ``sensor`` (an echo-sounder preset or a ``<sensor>``
XML file) at ``sensor_pose``.

Not converted, one line each in `SdfScene.skipped` (and printed by the command): lights,
sensors, plugins, actors, models that are not static (a vehicle: it carries the sonar), a
heightmap after the first, a geometry of another kind. Refused in one line naming the file, before
anything is written: a mesh file that does not exist or cannot be read, a ``model://`` URI that
no model path resolves, a pose that is not six numbers.

The world's ``<spherical_coordinates>`` (latitude, longitude, elevation) becomes the scene's
recorded origin (`mitsonar.geometry.geodesy.scene_frame`) when ``origin`` is not given, its x, y taken as offsets
in the origin's UTM grid (``crs``), which differ from Gazebo's east/north by the meridian
convergence (under a degree within a UTM zone's middle; give ``crs`` for another grid).
"""
from __future__ import annotations

import csv
import fnmatch
import math
import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field

import numpy as np

from mitsonar._checks import first_line

DEFAULT_MATERIAL = "rock"
#: World children that are settings, not things: nothing to convert, nothing to say.
SETTINGS = ("physics", "gravity", "magnetic_field", "atmosphere", "scene", "gui", "wind", "spherical_coordinates",
            "audio", "state", "frame")


class SdfError(ValueError):
    """An SDF world (or a file it names) that cannot be converted: one line naming it."""


def pose_matrix(values, degrees=False) -> np.ndarray:
    """The 4x4 transform of an SDF pose ``x y z roll pitch yaw`` (``Rz(yaw) Ry(pitch) Rx(roll)``)."""
    x, y, z, r, p, w = (float(v) for v in values)
    if degrees:
        r, p, w = (math.radians(a) for a in (r, p, w))
    cr, sr, cp, sp, cw, sw = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(w), math.sin(w)
    m = np.eye(4)
    m[:3, :3] = [[cw * cp, cw * sp * sr - sw * cr, cw * sp * cr + sw * sr],
                 [sw * cp, sw * sp * sr + cw * cr, sw * sp * cr - cw * sr],
                 [-sp, cp * sr, cp * cr]]
    m[:3, 3] = (x, y, z)
    return m


def _scale(sx, sy, sz):
    return np.diag([sx, sy, sz, 1.0])


def _translate(x, y, z):
    m = np.eye(4)
    m[:3, 3] = (x, y, z)
    return m


def _text(el, tag, default=None):
    child = el.find(tag)
    return default if child is None or child.text is None else child.text.strip()


def _floats(text, n, where):
    try:
        values = [float(v) for v in str(text).split()]
    except ValueError:
        values = []
    if len(values) != n or not all(math.isfinite(v) for v in values):
        raise SdfError(f"{where}: {text!r} is not {n} numbers")
    return values


@dataclass
class SdfScene:
    """What `scene_from_sdf` wrote: the scene, its meshes, one line per thing not converted."""

    scene: str
    meshes: list
    models: list
    skipped: list = field(default_factory=list)
    frame: object = None

    def line(self) -> str:
        where = "" if self.frame is None else f", origin recorded in {self.frame.crs}"
        return (f"wrote {self.scene}: {len(self.models)} static models ({', '.join(self.models) or 'none'}), "
                f"{len(self.meshes)} mesh files{where}; {len(self.skipped)} things not converted")


def read_materials(path):
    """``[(pattern, material)]`` of a CSV ``pattern,material`` or a YAML mapping/list."""
    from mitsonar.scenes.worldxml import check_material

    if not os.path.isfile(path):
        raise SdfError(f"--materials {path}: no such file (CSV pattern,material or YAML)")
    pairs = []
    if path.lower().endswith((".yaml", ".yml")):
        import yaml

        with open(path, encoding="utf-8") as f:
            try:
                data = yaml.safe_load(f)
            except yaml.YAMLError as exc:
                raise SdfError(f"--materials {path}: not readable YAML ({first_line(exc)})") from None
        if isinstance(data, dict):
            pairs = [(str(k), str(v)) for k, v in data.items()]
        elif isinstance(data, list) and all(isinstance(d, dict) and {"pattern", "material"} <= set(d) for d in data):
            pairs = [(str(d["pattern"]), str(d["material"])) for d in data]
        else:
            raise SdfError(f"--materials {path}: expected a mapping pattern: material, or a list of "
                           "{pattern, material}")
    else:
        with open(path, newline="", encoding="utf-8") as f:
            for i, row in enumerate(csv.reader(f), start=1):
                if not row or not "".join(row).strip() or row[0].strip().startswith("#"):
                    continue
                if len(row) < 2:
                    raise SdfError(f"--materials {path}: line {i}: expected pattern,material")
                if i == 1 and [c.strip().lower() for c in row[:2]] == ["pattern", "material"]:
                    continue
                pairs.append((row[0].strip(), row[1].strip()))
    try:
        return [(p, check_material(m, f"--materials {path}: pattern {p!r}: material")) for p, m in pairs]
    except ValueError as exc:
        raise SdfError(str(exc)) from None


class _World:
    def __init__(self, path, model_path, scale, materials, material):
        self.path = path
        self.folders = [os.fspath(p) for p in model_path or ()]
        for var in ("GAZEBO_MODEL_PATH", "GZ_SIM_RESOURCE_PATH"):
            self.folders += [p for p in os.environ.get(var, "").split(os.pathsep) if p]
        self.scale = scale
        self.materials, self.material = materials, material
        self.shapes, self.meshes, self.models, self.skipped = [], [], [], []
        self.heightmaps = 0
        self.bsdfs = set()
        self.mesh_index = {}     # (file, scale) -> its index in meshes

    # ------------------------------------------------------------------ files
    def resolve(self, uri, base, where):
        """The file (or folder) of a URI: ``model://NAME/rest`` in the model paths, ``file://``,
        or a path relative to ``base`` (the SDF file's folder)."""
        uri = uri.strip()
        if uri.startswith("model://"):
            name, _, rest = uri[len("model://"):].partition("/")
            for folder in self.folders:
                cand = os.path.join(folder, name)
                if os.path.isdir(cand):
                    return os.path.join(cand, rest) if rest else cand
            searched = ", ".join(self.folders) or "none"
            raise SdfError(f"{where}: {uri} cannot be resolved: no model folder {name!r} in the model paths "
                           f"(searched: {searched}); give --model-path DIR, DIR holding {name}/")
        if uri.startswith("file://"):
            uri = uri[len("file://"):]
        if "://" in uri:
            raise SdfError(f"{where}: {uri}: only model://, file:// and file paths are read (download it and "
                           "give its path)")
        return uri if os.path.isabs(uri) else os.path.join(base, uri)

    def model_file(self, folder, where):
        config = os.path.join(folder, "model.config")
        if os.path.isfile(config):
            try:
                root = ET.parse(config).getroot()
            except ET.ParseError as exc:
                raise SdfError(f"{config}: not readable XML ({exc})") from None
            name = _text(root, "sdf")
            if name:
                return os.path.join(folder, name)
        cand = os.path.join(folder, "model.sdf")
        if os.path.isfile(cand):
            return cand
        raise SdfError(f"{where}: {folder} has neither a model.config naming its SDF nor a model.sdf")

    # ------------------------------------------------------------------ poses
    def pose(self, el, where):
        p = el.find("pose")
        if p is None or not (p.text or "").strip():
            return np.eye(4)
        rel = p.get("relative_to")
        if rel not in (None, "", "__model__"):
            raise SdfError(f"{self.path}: {where}: <pose relative_to=\"{rel}\"> is not read; give the pose relative "
                           "to its parent element")
        return pose_matrix(_floats(p.text, 6, f"{self.path}: {where}: <pose>"),
                           str(p.get("degrees", "false")).lower() in ("true", "1"))

    # ------------------------------------------------------------------ world
    def world(self, root):
        world = root.find("world")
        top = world if world is not None else root
        for el in top:
            tag = el.tag
            if tag == "model":
                self.model(el, np.eye(4), os.path.dirname(os.path.abspath(self.path)), None)
            elif tag == "include":
                self.include(el, np.eye(4))
            elif tag in SETTINGS:
                continue
            else:
                self.skip(f"<{tag}> {el.get('name', '')!r}".replace(" ''", ""), "")

    def skip(self, what, why):
        self.skipped.append(f"{what}: {why}" if why else f"{what}: no acoustic counterpart")

    def include(self, el, parent, static=None):
        uri = _text(el, "uri")
        if not uri:
            raise SdfError(f"{self.path}: <include> without a <uri>")
        folder = self.resolve(uri, os.path.dirname(os.path.abspath(self.path)), self.path)
        file = folder if os.path.isfile(folder) else self.model_file(folder, f"{self.path}: {uri}")
        try:
            root = ET.parse(file).getroot()
        except (ET.ParseError, OSError) as exc:
            raise SdfError(f"{file}: not a readable SDF file ({exc})") from None
        model = root.find("model") if root.tag != "model" else root
        if model is None:
            raise SdfError(f"{file}: holds no <model>")
        name = _text(el, "name") or model.get("name", os.path.basename(folder))
        override = None if _text(el, "static") is None else _text(el, "static").lower() in ("true", "1")
        pose = self.pose(el, f"include {name!r}") if el.find("pose") is not None else \
            self.pose(model, f"model {name!r}")
        saved = self.path
        self.path = file
        try:
            self.model(model, parent, os.path.dirname(os.path.abspath(file)), static, name=name, pose=pose,
                       override=override)
        finally:
            self.path = saved

    def model(self, el, parent, base, static, name=None, pose=None, top=None, override=None):
        """Place a model (``static``: its parent's; ``override``: an <include>'s <static>)."""
        name = name or el.get("name", "model")
        own = _text(el, "static")
        is_static = (own.lower() in ("true", "1")) if own is not None else bool(static)
        if override is not None:
            is_static = override
        if not is_static:
            self.skip(f"model {name!r}", "not static (a vehicle or a moving part; the sonar is placed by --sensor)")
            return
        T = parent @ (self.pose(el, f"model {name!r}") if pose is None else pose)
        top = top or name
        if top == name:
            self.models.append(name)
        mat = next((m for p, m in self.materials if fnmatch.fnmatchcase(top, p)), self.material)
        for child in el:
            if child.tag == "link":
                self.link(child, T, base, f"{name}::{child.get('name', 'link')}", mat)
            elif child.tag == "model":
                self.model(child, T, base, True, top=top)
            elif child.tag == "include":
                self.include(child, T, static=True)
            elif child.tag in ("plugin",):
                self.skip(f"plugin {child.get('name', child.get('filename', ''))!r} of model {name!r}", "")
            elif child.tag in ("joint", "static", "pose", "self_collide", "allow_auto_disable", "enable_wind",
                               "frame", "gripper"):
                continue
            else:
                self.skip(f"<{child.tag}> of model {name!r}", "")

    def link(self, el, T, base, where, mat):
        T = T @ self.pose(el, f"link {where!r}")
        visuals = el.findall("visual") or el.findall("collision")
        for v in visuals:
            geom = v.find("geometry")
            if geom is None:
                continue
            self.geometry(geom, T @ self.pose(v, f"{v.tag} {where}::{v.get('name', '')}"), base,
                          f"{where}::{v.get('name', v.tag)}", mat)
        for s in el.findall("sensor"):
            self.skip(f"sensor {s.get('name', '')!r} ({s.get('type', '?')}) of {where}",
                      "not converted (place mitsonar's sonar with --sensor)")
        for s in el.findall("light"):
            self.skip(f"light {s.get('name', '')!r} of {where}", "")

    def geometry(self, geom, T, base, where, mat):
        geometries = [g for g in geom]
        if not geometries:
            return
        g = geometries[0]
        bsdf = self.bsdf_id(mat)
        if g.tag == "box":
            sx, sy, sz = _floats(_text(g, "size", "1 1 1"), 3, f"{self.path}: {where}: <box><size>")
            self.add("cube", T @ _scale(sx / 2, sy / 2, sz / 2), bsdf)
        elif g.tag == "sphere":
            r = _floats(_text(g, "radius", "1"), 1, f"{self.path}: {where}: <sphere><radius>")[0]
            self.add("sphere", T, bsdf, f'<float name="radius" value="{r:.17g}"/>')
        elif g.tag == "cylinder":
            r = _floats(_text(g, "radius", "1"), 1, f"{self.path}: {where}: <cylinder><radius>")[0]
            h = _floats(_text(g, "length", "1"), 1, f"{self.path}: {where}: <cylinder><length>")[0]
            self.add("cylinder", T, bsdf, f'<point name="p0" x="0" y="0" z="{-h / 2:.17g}"/>'
                     f'<point name="p1" x="0" y="0" z="{h / 2:.17g}"/><float name="radius" value="{r:.17g}"/>')
            self.add("disk", T @ _translate(0, 0, h / 2) @ _scale(r, r, 1), bsdf)
            self.add("disk", T @ _translate(0, 0, -h / 2) @ np.diag([1.0, -1.0, -1.0, 1.0]) @ _scale(r, r, 1), bsdf)
        elif g.tag == "plane":
            n = np.array(_floats(_text(g, "normal", "0 0 1"), 3, f"{self.path}: {where}: <plane><normal>"))
            w, h = _floats(_text(g, "size", "1 1"), 2, f"{self.path}: {where}: <plane><size>")
            self.add("rectangle", T @ _towards(n) @ _scale(w / 2, h / 2, 1), bsdf)
        elif g.tag == "mesh":
            from mitsonar.scenes.meshes import MeshError, load_mesh

            uri = _text(g, "uri")
            if not uri:
                raise SdfError(f"{self.path}: {where}: <mesh> without a <uri>")
            file = self.resolve(uri, base, f"{self.path}: {where}")
            if not os.path.isfile(file):
                raise SdfError(f"{self.path}: {where}: mesh {uri} ({file}) does not exist; fix the URI or give "
                               "--model-path")
            s = _floats(_text(g, "scale", "1 1 1"), 3, f"{self.path}: {where}: <mesh><scale>")
            if g.find("submesh") is not None:
                self.skip(f"<submesh> of {where}", "the whole mesh is placed")
            key = (os.path.realpath(file), tuple(s))
            if key in self.mesh_index:          # a mesh placed again: one PLY, another transform
                self.bsdfs.add(bsdf)
                self.shapes.append(("mesh", self.mesh_index[key], T, bsdf))
                return
            try:
                v, f = load_mesh(file, self.scale)
            except MeshError as exc:
                raise SdfError(f"{self.path}: {where}: {exc}") from None
            self.add_mesh(v * s, f, T, bsdf)
            self.mesh_index[key] = len(self.meshes) - 1
        elif g.tag == "heightmap":
            self.heightmaps += 1
            if self.heightmaps > 1:
                self.skip(f"heightmap of {where}", "not converted (only the first heightmap is)")
                return
            self.heightmap(g, T, base, where, bsdf)
        else:
            self.skip(f"<{g.tag}> geometry of {where}", "not converted (box, sphere, cylinder, plane, mesh and "
                      "heightmap are)")

    def heightmap(self, g, T, base, where, bsdf):
        from mitsonar.scenes.terrain import height_field_faces

        uri = _text(g, "uri")
        file = self.resolve(uri or "", base, f"{self.path}: {where}")
        if not uri or not os.path.isfile(file):
            raise SdfError(f"{self.path}: {where}: heightmap {uri} ({file}) does not exist")
        sx, sy, sz = _floats(_text(g, "size", "1 1 1"), 3, f"{self.path}: {where}: <heightmap><size>")
        px, py, pz = _floats(_text(g, "pos", "0 0 0"), 3, f"{self.path}: {where}: <heightmap><pos>")
        try:
            import rasterio
        except ImportError:
            raise SdfError(f"{self.path}: {where}: a heightmap needs rasterio: pip install 'mitsonar[world]'") from None
        try:
            with rasterio.open(file) as src:
                img = src.read(1)
        except rasterio.errors.RasterioError as exc:
            raise SdfError(f"{file}: not an image or DEM GDAL reads ({first_line(exc)})") from None
        if np.issubdtype(img.dtype, np.integer):
            z = pz + img.astype(np.float64) / np.iinfo(img.dtype).max * sz
        else:
            z = pz + img.astype(np.float64)
        z = z[::-1]                                  # image rows go south; mesh rows north
        ny, nx = z.shape
        X, Y = np.meshgrid(px + np.linspace(-sx / 2, sx / 2, nx), py + np.linspace(-sy / 2, sy / 2, ny))
        self.add_mesh(np.stack([X.ravel(), Y.ravel(), z.ravel()], 1), height_field_faces(ny, nx), T, bsdf)

    # ------------------------------------------------------------------ output
    def bsdf_id(self, mat):
        from mitsonar.scenes.worldxml import safe_id

        return f"mat_{safe_id(mat)}"

    def add(self, shape_type, to_world, bsdf, extra=""):
        """A Mitsuba shape (rigid ``to_world`` for the sphere and the cylinder, which take no
        non-uniform scale: their sizes are their own properties)."""
        m = " ".join(f"{v:.17g}" for v in to_world.ravel())
        self.bsdfs.add(bsdf)
        self.shapes.append(f'<shape type="{shape_type}">{extra}<transform name="to_world"><matrix value="{m}"/></transform>'
                           f'<ref id="{bsdf}"/></shape>')

    def add_mesh(self, v, f, to_world, bsdf):
        self.bsdfs.add(bsdf)
        self.meshes.append((v, f))
        self.shapes.append(("mesh", len(self.meshes) - 1, to_world, bsdf))


def _towards(n):
    """A rotation taking +z to the unit vector along ``n``."""
    n = np.asarray(n, float)
    norm = np.linalg.norm(n)
    if norm == 0:
        raise SdfError("<plane><normal> 0 0 0 is not a direction")
    n = n / norm
    z = np.array([0.0, 0.0, 1.0])
    c = float(z @ n)
    m = np.eye(4)
    if c < -1 + 1e-12:
        m[:3, :3] = np.diag([1.0, -1.0, -1.0])
        return m
    k = np.cross(z, n)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    m[:3, :3] = np.eye(3) + K + K @ K / (1 + c)
    return m


def scene_from_sdf(world, output, *, model_path=(), materials=None, material=None, scale=1.0, sensor=None,
                   sensor_pose=None, origin=None, crs=None, force=False) -> SdfScene:
    """Write the scene (``output``, .xml) of an SDF world's static models and its meshes beside it
    (see the module docstring). Everything is read and checked before anything is written."""
    from mitsonar._files import StagedFiles, check_output_file
    from mitsonar.geometry.geodesy import GeoError, GeoFrame
    from mitsonar.scenes import worldxml

    world, output = os.fspath(world), os.fspath(output)
    check_output_file(output, SdfError, extensions=(".xml",), force=force)
    if not (isinstance(scale, (int, float)) and math.isfinite(scale) and scale > 0):
        raise SdfError(f"--scale {scale}: not allowed (a factor > 0 to metres)")
    try:
        material = worldxml.check_material(material or DEFAULT_MATERIAL, "--material")
        pose = None if sensor_pose is None else pose_matrix(_floats(" ".join(map(str, sensor_pose)), 6,
                                                                    "--sensor-pose"))
        sensor_text = worldxml.sensor_xml(sensor or "r2sonic_2024", pose)
    except ValueError as exc:
        raise SdfError(str(exc)) from None
    pairs = read_materials(materials) if materials else []
    if not os.path.isfile(world):
        raise SdfError(f"{world}: no such SDF world file")
    try:
        root = ET.parse(world).getroot()
    except ET.ParseError as exc:
        raise SdfError(f"{world}: not readable XML ({exc})") from None
    if root.tag != "sdf":
        raise SdfError(f"{world}: the root element is <{root.tag}>, not <sdf>")
    w = _World(world, model_path, float(scale), pairs, material)
    w.world(root)
    frame = None
    sph = (root.find("world") if root.find("world") is not None else root).find("spherical_coordinates")
    try:
        if origin is not None:
            frame = GeoFrame.make(origin, crs)
        elif sph is not None and _text(sph, "latitude_deg") is not None:
            frame = GeoFrame.make((_text(sph, "latitude_deg"), _text(sph, "longitude_deg", "0"),
                                   _text(sph, "elevation", "0")), crs,
                                  (f"{world}: <spherical_coordinates>", "--crs"))
        elif crs is not None:
            raise SdfError(f"--crs {crs}: needs --origin LAT LON [HEIGHT] (or the world's <spherical_coordinates>)")
    except GeoError as exc:
        raise SdfError(str(exc)) from None
    stem = os.path.splitext(os.path.basename(output))[0]
    folder = os.path.dirname(os.path.abspath(output))
    by_id = {w.bsdf_id(m): m for m in [material] + [m for _, m in pairs]}
    bsdfs = [worldxml.bsdf_xml(by_id[b], b) for b in sorted(w.bsdfs)]
    written = []
    with StagedFiles() as files:
        shapes = []
        for v, f in w.meshes:
            name = f"{stem}_mesh_{len(written)}.ply"
            worldxml.write_mesh_ply(files.temporary(os.path.join(folder, name)), v, f,
                                    comment=f"mitsonar mesh from {os.path.basename(world)}")
            written.append(os.path.join(folder, name))
        for i, s in enumerate(w.shapes):
            if isinstance(s, tuple):
                _, k, to_world, bsdf = s
                shapes.append(worldxml.ply_shape(f"mesh_{i}", os.path.basename(written[k]), bsdf, to_world))
            else:
                shapes.append(s)
        with open(files.temporary(output), "w", encoding="utf-8") as fh:
            fh.write(worldxml.scene_text(shapes, bsdfs, frame, sensor_text))
    return SdfScene(output, written, w.models, w.skipped, frame)
