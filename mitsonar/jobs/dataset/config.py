"""Dataset configs: read a YAML or TOML file, check every key before any work, and draw each
sample's settings from its own seed.

A config (``examples/dataset_small.yaml``)::

    seed: 1                 # every random choice below comes from (seed, sample index)
    samples: 8              # how many samples (>= 1)
    shard_size: 4           # samples per shard file (default 16)
    scene_samples: 4        # consecutive samples that share one scene draw (default shard_size)
    spp: 256                # paths per row
    max_depth: 2            # surface bounces (default: the scene's integrator, else 5)
    first_return_db: -20    # a row's first return: first bin within this many dB of its peak
    scenes:                 # one is drawn per block of scene_samples samples (by weight)
      - xml: ../scenes_xml/box.xml            # relative to the config file
      - terrain: {size: [16, 16], resolution: 0.25, roughness: {uniform: [0, 0.05]}}
        material: {choice: [seabed_sand, seabed_rock]}
    sonar: {kind: mechanical, n_bins: 120, n_pings: 40}   # replaces the scene's sensor
    pose: {x: {uniform: [-1, 1]}, yaw: {uniform: [0, 360]}}   # the vehicle's pose (m, deg)
    trajectory: {type: straight, speed: {uniform: [0.2, 1]}}  # the vehicle moves during the scan
    materials: {concrete: {diffuse: {uniform: [0.05, 0.2]}}}  # by BSDF id (a terrain's: seabed_material)
    electronics: {gain: {uniform: [20, 35]}, speckle: {choice: [rayleigh, weibull]}}

A value is fixed, or drawn: ``{uniform: [lo, hi]}`` (a float), ``{randint: [lo, hi]}`` (a whole
number, both ends included) or ``{choice: [a, b, ...]}``. What makes a scene (the scene entry, its
terrain, its material preset, the sonar settings) is drawn once per block of ``scene_samples``
samples from ``numpy.random.default_rng([seed, 0, block])``, so a worker loads a scene once for
many samples; what a scene can take without being reloaded (pose, trajectory, material
parameters, electronics, the path seed) is drawn per sample from ``default_rng([seed, 1, i])``.
The scene's speckle (``speckle_seed``, `mitsonar.receiver.speckle`: which scatterers its surfaces hold)
belongs to the scene, so it is drawn once per block, from ``default_rng([seed, 2, block])``: a
whole number in 0 .. 2^32 - 1, or what ``electronics.speckle_seed`` gives (fixed, ``randint`` or
``choice``). Keys are drawn in sorted order. So a sample depends on the config and its index only: any number
of workers, on any engine, writes the same samples.
"""
from __future__ import annotations

import copy
import hashlib
import inspect
import json
import math
import os
import re

import numpy as np

from mitsonar._checks import first_line, is_number, is_whole
from mitsonar._limits import PATHS_MAX

FORMAT = "mitsonar-dataset/1"
SPECS = ("uniform", "randint", "choice")
TOP = {"seed", "samples", "shard_size", "scene_samples", "spp", "max_depth", "first_return_db", "scenes", "sonar",
       "pose", "trajectory", "materials", "electronics"}
SCENE_KEYS = {"xml", "terrain", "material", "weight"}
POSE_KEYS = {"x", "y", "z", "yaw", "pitch", "roll"}
TRAJECTORY_KEYS = {"type", "speed", "yaw_rate"}
TRAJECTORY_TYPES = ("straight", "turn")
MATERIAL_KEYS = {"diffuse", "specular", "shininess"}
SEED_MAX = 2 ** 32 - 1


class DatasetError(ValueError):
    """A config or dataset folder that cannot be used; the message is one line for the user."""


def _fail(key, value, allowed):
    raise DatasetError(f"dataset config '{key}': {value!r} is not allowed ({allowed})")


def _unknown(where, keys, allowed):
    for k in keys:
        if k not in allowed:
            raise DatasetError(f"dataset config '{where + '.' if where else ''}{k}': unknown key "
                               f"(allowed: {', '.join(sorted(allowed))})")


# ----------------------------------------------------------------------------- random values
def is_spec(value) -> bool:
    """A drawn value: a one-key dict ``{uniform|randint|choice: ...}``."""
    return isinstance(value, dict) and len(value) == 1 and next(iter(value)) in SPECS


def check_value(key, value, value_type="number", lo=-math.inf, hi=math.inf, choices=None):
    """Check a fixed or drawn value of ``key``: every value it can take is a ``value_type`` (``number``,
    ``whole``, ``text`` or ``any``) in ``[lo, hi]`` (or one of ``choices``); ranges are ordered.
    Returns the values to check further (the ends of a range, every choice)."""
    if isinstance(value, dict) and not is_spec(value) and any(k in SPECS for k in value):
        _fail(key, value, "one of {uniform: [lo, hi]}, {randint: [lo, hi]}, {choice: [...]}")
    if is_spec(value):
        (how, arg), = value.items()
        if how == "choice":
            if not isinstance(arg, list) or not arg:
                _fail(f"{key}.choice", arg, "a non-empty list of values")
            ends = arg
        else:
            whole = how == "randint"
            ok = isinstance(arg, list) and len(arg) == 2 and all((is_whole if whole else is_number)(v) for v in arg)
            if not ok:
                _fail(f"{key}.{how}", arg, f"two {'whole numbers' if whole else 'numbers'} [lo, hi]")
            if arg[0] > arg[1]:
                _fail(f"{key}.{how}", arg, "an ordered range [lo, hi] with lo <= hi")
            if how == "randint" and value_type == "number":
                value_type = "whole"
            ends = arg
    else:
        ends = [value]
    for v in ends:
        if choices is not None:
            if v not in choices:
                _fail(key, v, "one of " + ", ".join(map(str, choices)))
        elif value_type == "text":
            if not isinstance(v, str):
                _fail(key, v, "a text value")
        elif value_type in ("number", "whole"):
            good = (is_whole if value_type == "whole" else is_number)(v) and lo <= v <= hi
            if not good:
                what = "a whole number" if value_type == "whole" else "a number"
                bounds = [f">= {lo:g}" if lo > -math.inf else "", f"<= {hi:g}" if hi < math.inf else ""]
                _fail(key, v, " ".join([what] + [b for b in bounds if b]))
    return ends


def draw(value, rng):
    """``value`` with every drawn spec replaced by a draw from ``rng`` (dict keys in sorted order)."""
    if is_spec(value):
        (how, arg), = value.items()
        if how == "uniform":
            return float(rng.uniform(arg[0], arg[1])) if arg[0] < arg[1] else float(arg[0])
        if how == "randint":
            return int(rng.integers(int(arg[0]), int(arg[1]) + 1))
        return copy.deepcopy(arg[int(rng.integers(len(arg)))])
    if isinstance(value, dict):
        return {k: draw(value[k], rng) for k in sorted(value)}
    if isinstance(value, list):
        return [draw(v, rng) for v in value]
    return value


# ----------------------------------------------------------------------------- reading
def read_config(path) -> dict:
    """The config file as a dict (YAML by ``.yaml``/``.yml``, TOML by ``.toml``), scene paths made
    absolute (relative ones are relative to the config's folder), checked (`check_config`)."""
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise DatasetError(f"dataset config {path!r} does not exist")
    ext = os.path.splitext(path)[1].lower()
    with open(path, "rb") as f:
        raw = f.read()
    try:
        if ext in (".yaml", ".yml"):
            try:
                import yaml
            except ImportError:
                raise DatasetError("reading a YAML config needs PyYAML (pip install pyyaml), or write it as TOML") from None
            cfg = yaml.safe_load(raw.decode("utf-8"))
        elif ext == ".toml":
            import tomllib

            cfg = tomllib.loads(raw.decode("utf-8"))
        else:
            raise DatasetError(f"dataset config {path!r}: the extension must be .yaml, .yml or .toml")
    except DatasetError:
        raise
    except Exception as exc:  # a syntax error of the file: where (YAML's mark) and what
        mark = getattr(exc, "problem_mark", None) or getattr(exc, "context_mark", None)
        problem = getattr(exc, "problem", None) or getattr(exc, "context", None)
        if mark is not None and problem:
            context = getattr(exc, "context", None) if getattr(exc, "problem", None) else None
            start = getattr(exc, "context_mark", None)
            if context and start is not None and start.line != mark.line:
                context += f" started at line {start.line + 1}"
            raise DatasetError(f"dataset config {path!r} line {mark.line + 1}, column {mark.column + 1}: {problem}"
                               + (f" ({context})" if context else "")) from None
        raise DatasetError(f"dataset config {path!r}: {first_line(exc)}") from None
    try:
        return check_config(cfg, base=os.path.dirname(os.path.abspath(path)))
    except DatasetError as exc:   # name the file and the key's line
        raise DatasetError(_located(str(exc), path, raw.decode("utf-8", "replace"))) from None


def _located(message, path, text) -> str:
    """``dataset config 'a.b[0].c': ...`` with the file and the line of the key in ``text``:
    ``dataset config 'a.b[0].c' (FILE line N): ...`` (the top-level key's line, or the first line
    after it naming the innermost key); the message as is when the key is not found."""
    m = re.match(r"dataset config '([^']+)'", message)
    if not m:
        return message
    parts = [p for p in re.split(r"[.\[\]]", m.group(1)) if p and not p.isdigit()]
    lines = text.splitlines()
    found = None
    for i, line in enumerate(lines):
        if re.match(rf"\s*\[?{re.escape(parts[0])}\s*[:=\]]", line.split("#", 1)[0]):
            found = i
            break
    if found is None:
        return message
    if len(parts) > 1:
        for j in range(found, len(lines)):
            if re.search(rf"(^|[\s{{,\[]){re.escape(parts[-1])}\s*[:=]", lines[j].split("#", 1)[0]):
                found = j
                break
    return f"{m.group(0)} ({path} line {found + 1}){message[m.end():]}"


def _terrain_keys():
    from mitsonar.scenes.terrain import Terrain

    return set(inspect.signature(Terrain.__init__).parameters) - {"self", "seed"}


def check_config(cfg, base=".") -> dict:
    """Check a config dict (see the module docstring) and return it normalised: defaults filled
    in, scene XML paths absolute. Every problem is one `DatasetError` naming the key and what is
    allowed, raised before anything is rendered or written."""
    if not isinstance(cfg, dict):
        raise DatasetError(f"dataset config: expected a mapping of keys ({', '.join(sorted(TOP))}), "
                           f"got {type(cfg).__name__}")
    _unknown("", cfg, TOP)
    cfg = copy.deepcopy(cfg)
    if "samples" not in cfg:
        raise DatasetError("dataset config 'samples': missing (a whole number of samples >= 1)")
    if "scenes" not in cfg:
        raise DatasetError("dataset config 'scenes': missing (a list of scenes: {xml: FILE} or {terrain: {...}})")
    for key, lo, hi, default in (("seed", 0, SEED_MAX, 0), ("samples", 1, 10 ** 12, None),
                                 ("shard_size", 1, 10 ** 6, 16), ("spp", 1, PATHS_MAX, 1024)):
        cfg.setdefault(key, default)
        if not (is_whole(cfg[key]) and lo <= cfg[key] <= hi):
            _fail(key, cfg[key], f"a whole number from {lo} to {hi}")
        cfg[key] = int(cfg[key])
    cfg.setdefault("scene_samples", cfg["shard_size"])
    if not (is_whole(cfg["scene_samples"]) and cfg["scene_samples"] >= 1):
        _fail("scene_samples", cfg["scene_samples"], "a whole number >= 1")
    cfg["scene_samples"] = int(cfg["scene_samples"])
    if cfg.get("max_depth") is not None and not (is_whole(cfg["max_depth"]) and 1 <= cfg["max_depth"] <= 64):
        _fail("max_depth", cfg["max_depth"], "a whole number of surface bounces from 1 to 64")
    cfg.setdefault("first_return_db", -20.0)
    if not (is_number(cfg["first_return_db"]) and cfg["first_return_db"] <= 0):
        _fail("first_return_db", cfg["first_return_db"], "a number of dB <= 0, relative to the row's peak")
    _check_scenes(cfg, base)
    for key in ("sonar", "pose", "trajectory", "materials", "electronics"):
        cfg.setdefault(key, {})
        if not isinstance(cfg[key], dict):
            _fail(key, cfg[key], "a mapping of keys")
    _check_sonar(cfg["sonar"])
    if not cfg["sonar"] and any("terrain" in s for s in cfg["scenes"]):
        raise DatasetError("dataset config 'sonar': missing (a terrain scene has no sensor of its own: give the "
                           "sonar's settings, e.g. {kind: mechanical})")
    _unknown("pose", cfg["pose"], POSE_KEYS)
    for k, v in cfg["pose"].items():
        check_value(f"pose.{k}", v)
    if cfg["trajectory"]:
        t = cfg["trajectory"]
        _unknown("trajectory", t, TRAJECTORY_KEYS)
        t.setdefault("type", "straight")
        check_value("trajectory.type", t["type"], choices=TRAJECTORY_TYPES)
        if "speed" not in t:
            raise DatasetError("dataset config 'trajectory.speed': missing (the vehicle's speed in m/s)")
        check_value("trajectory.speed", t["speed"])
        check_value("trajectory.yaw_rate", t.setdefault("yaw_rate", 0.0))
    for bsdf, params in cfg["materials"].items():
        if not isinstance(params, dict):
            _fail(f"materials.{bsdf}", params, "a mapping of diffuse, specular, shininess")
        _unknown(f"materials.{bsdf}", params, MATERIAL_KEYS)
        for k, v in params.items():
            check_value(f"materials.{bsdf}.{k}", v, lo=0, hi=1 if k != "shininess" else math.inf)
    _check_material_ids(cfg)
    _check_electronics(cfg["electronics"])
    return cfg


TERRAIN_BSDF = "seabed_material"   # the id of a terrain scene's BSDF (its preset from 'material')


def _bsdf_ids(path) -> set:
    """The ids of the ``<bsdf>`` elements of a scene file (nested ones too)."""
    import xml.etree.ElementTree as ET

    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, OSError) as exc:
        raise DatasetError(f"dataset config: scene file {path!r} is not readable XML ({exc})") from None
    return {e.get("id") for e in root.iter("bsdf") if e.get("id")}


def _check_material_ids(cfg):
    """Every BSDF id under 'materials' is in at least one scene (scenes without it ignore it)."""
    if not cfg["materials"]:
        return
    ids = set()
    for s in cfg["scenes"]:
        ids |= _bsdf_ids(s["xml"]) if "xml" in s else {TERRAIN_BSDF}
    for bsdf in cfg["materials"]:
        if bsdf not in ids:
            raise DatasetError(f"dataset config 'materials.{bsdf}': no scene has a BSDF of that id "
                               f"(their BSDFs: {', '.join(sorted(ids)) or 'none'})")


def _check_scenes(cfg, base):
    scenes = cfg["scenes"]
    if not isinstance(scenes, list) or not scenes:
        _fail("scenes", scenes, "a non-empty list of scenes: {xml: FILE} or {terrain: {...}}")
    terrain_keys = None
    for n, s in enumerate(scenes):
        where = f"scenes[{n}]"
        if isinstance(s, str):
            s = scenes[n] = {"xml": s}
        if not isinstance(s, dict):
            _fail(where, s, "a mapping {xml: FILE} or {terrain: {...}}")
        _unknown(where, s, SCENE_KEYS)
        if ("xml" in s) == ("terrain" in s):
            raise DatasetError(f"dataset config '{where}': give exactly one of 'xml' (a scene file) or 'terrain' "
                               "(seabed parameters)")
        s.setdefault("weight", 1.0)
        check_value(f"{where}.weight", s["weight"], lo=1e-300)
        if is_spec(s["weight"]):
            _fail(f"{where}.weight", s["weight"], "a fixed number > 0")
        if "xml" in s:
            if not isinstance(s["xml"], str):
                _fail(f"{where}.xml", s["xml"], "a scene file name")
            path = os.path.normpath(os.path.join(base, s["xml"]))
            if not os.path.isfile(path):
                raise DatasetError(f"dataset config '{where}.xml': scene file {path!r} does not exist")
            s["xml"] = path
            if "material" in s:
                raise DatasetError(f"dataset config '{where}.material': only for terrain scenes (use 'materials' "
                                   "with the XML's BSDF ids)")
        else:
            t = s["terrain"]
            if not isinstance(t, dict):
                _fail(f"{where}.terrain", t, "a mapping of mitsonar.scenes.terrain.Terrain arguments")
            terrain_keys = terrain_keys or _terrain_keys()
            _unknown(f"{where}.terrain", t, terrain_keys)
            for k, v in t.items():
                if is_spec(v):
                    check_value(f"{where}.terrain.{k}", v, value_type="any")
            _check_terrain(where, t)
            from mitsonar.plugins.bsdfs.materials import PRESETS

            s.setdefault("material", "seabed_sand")
            check_value(f"{where}.material", s["material"], choices=sorted(PRESETS))


def _check_terrain(where, spec):
    """The terrain's own checks at every end of every range (its heights are not made: zeros)."""
    from mitsonar.scenes.terrain import Terrain

    class Shape(Terrain):
        def _heights(self):
            return {"plane": np.zeros(self.shape)}

    for trial in _corners(spec):
        try:
            Shape(**trial)
        except ValueError as exc:
            raise DatasetError(f"dataset config '{where}.terrain': {exc}") from None
        except TypeError as exc:
            raise DatasetError(f"dataset config '{where}.terrain': {exc}") from None


def _sonar_parameters():
    from mitsonar.sim.variant import ensure_variant

    ensure_variant()
    from mitsonar.plugins.sensors.sonar import SonarSensor

    return SonarSensor.parameters()


INTEGER_SONAR = {"n_bins", "n_pings", "bit_depth"}


def _check_sonar(sonar):
    if not sonar:
        return
    allowed = set(_sonar_parameters()) - {"to_world"} | {"mount"}
    _unknown("sonar", sonar, allowed)
    for k, v in sonar.items():
        if k == "mount":
            if not (isinstance(v, list) and len(v) == 16 and all(is_number(x) for x in v)):
                _fail("sonar.mount", v, "16 numbers: the 4x4 mount in the vehicle frame, row by row")
            from mitsonar.geometry.frames import check_rigid

            try:
                check_rigid(np.reshape(np.asarray(v, float), (4, 4)), "dataset config 'sonar.mount'")
            except ValueError as exc:
                raise DatasetError(str(exc)) from None
            continue
        check_value(f"sonar.{k}", v, value_type="any")
    # Every end of every range, through the sensor's own checks: a bad value costs a sentence now.
    for trial in _corners(sonar):
        from mitsonar.sim.scene import SceneError, load_scene

        try:
            load_scene(f'<scene version="3.0.0">{sonar_xml(trial)}</scene>')
        except SceneError as exc:
            # the sensor's own reason, without Mitsuba's place in the generated XML string
            msg = re.sub(r"^(XML string: )?(At|Error while loading) string \(line \d+, col \d+\): ", "", str(exc))
            key = re.match(r"sonar '(\w+)': ", msg)
            if key:
                raise DatasetError(f"dataset config 'sonar.{key.group(1)}': {msg[key.end():]}") from None
            raise DatasetError(f"dataset config 'sonar': {msg}") from None


def _corners(spec):
    """Settings at the low ends, at the high ends, and each choice in turn (the others low)."""
    def pick(v, end):
        if not is_spec(v):
            return v
        (how, arg), = v.items()
        return arg[0] if end == 0 else arg[-1]
    out = [{k: pick(v, 0) for k, v in spec.items()}, {k: pick(v, 1) for k, v in spec.items()}]
    for k, v in spec.items():
        if is_spec(v) and "choice" in v:
            for c in v["choice"]:
                out.append({**out[0], k: c})
    return out


def sonar_xml(settings, sensor_id="dataset_sonar") -> str:
    """A ``<sensor type="sonar">`` element of ``settings`` (drawn values; ``mount`` is the to_world)."""
    from mitsonar.sim.sensor_xml import sensor_xml

    params = {k: (int(v) if k in INTEGER_SONAR and is_whole(v) else v if isinstance(v, str) else float(v))
              for k, v in sorted(settings.items()) if k != "mount"}
    return sensor_xml(params, settings.get("mount"), sensor_id)


def _check_electronics(elec):
    from mitsonar.receiver.electronics import Electronics, check_head_settings

    names = [f.name for f in __import__("dataclasses").fields(Electronics)]
    _unknown("electronics", elec, set(names))
    if "speckle_seed" in elec:   # drawn per scene block: a whole number, never a float draw
        v = elec["speckle_seed"]
        if is_spec(v) and "uniform" in v:
            _fail("electronics.speckle_seed", v, f"a whole number from 0 to {SEED_MAX}, {{randint: [lo, hi]}} or "
                  "{choice: [...]}: the scene's speckle seed")
        check_value("electronics.speckle_seed", v, value_type="whole", lo=0, hi=SEED_MAX)
    for k, v in elec.items():
        for end in check_value(f"electronics.{k}", v, value_type="any"):
            try:
                check_head_settings({k: end}, "dataset config 'electronics'")
                Electronics.from_dict({k: end}, source="dataset config 'electronics'")
            except ValueError as exc:
                raise DatasetError(str(exc)) from None


# ----------------------------------------------------------------------------- identity and draws
def config_hash(cfg) -> str:
    """sha256 of the normalised config (canonical JSON) and the format: a dataset's identity."""
    text = json.dumps({"format": FORMAT, "config": cfg}, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def config_difference(a, b, prefix="") -> str:
    """The first key where two configs differ, as ``key: old vs new`` ('' when equal)."""
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b)):
            d = config_difference(a.get(k), b.get(k), f"{prefix}.{k}" if prefix else k)
            if d:
                return d
        return ""
    return "" if a == b else f"'{prefix}': {a!r} there, {b!r} now"


def scene_draw(cfg, block) -> dict:
    """What makes the scene of block ``block``: ``{entry, terrain, material, sonar, key}``; ``key``
    names the scene (same key, same scene) and its ground-truth mesh file."""
    rng = np.random.default_rng([cfg["seed"], 0, int(block)])
    weights = np.array([float(s["weight"]) for s in cfg["scenes"]])
    entry = int(rng.choice(len(weights), p=weights / weights.sum()))
    s = cfg["scenes"][entry]
    out = {"entry": entry, "sonar": draw(cfg["sonar"], rng)}
    if "terrain" in s:
        out["terrain"] = draw(s["terrain"], rng)
        out["terrain"]["seed"] = int(rng.integers(0, SEED_MAX + 1))
        out["material"] = draw(s["material"], rng)
    text = json.dumps(out, sort_keys=True)
    out["key"] = f"scene{entry:02d}-" + hashlib.sha256(text.encode()).hexdigest()[:12]
    return out


def speckle_draw(cfg, block) -> int:
    """The speckle seed of the scene of block ``block`` (shared by its samples, like the scene):
    ``electronics.speckle_seed`` drawn (or fixed), else a whole number in 0 .. 2^32 - 1, from
    ``default_rng([seed, 2, block])``."""
    rng = np.random.default_rng([cfg["seed"], 2, int(block)])
    if "speckle_seed" in cfg["electronics"]:
        return int(draw(cfg["electronics"]["speckle_seed"], rng))
    return int(rng.integers(0, SEED_MAX + 1))


def sample_draw(cfg, index) -> dict:
    """What sample ``index`` takes on top of its scene: path seed, pose, trajectory, materials,
    electronics (and its electronics seed), and its scene block's ``speckle_seed``."""
    rng = np.random.default_rng([cfg["seed"], 1, int(index)])
    electronics = {k: v for k, v in cfg["electronics"].items() if k != "speckle_seed"}
    return {"seed": int(rng.integers(0, SEED_MAX + 1)), "electronics_seed": int(rng.integers(0, SEED_MAX + 1)),
            "pose": draw(cfg["pose"], rng), "trajectory": draw(cfg["trajectory"], rng),
            "materials": draw(cfg["materials"], rng), "electronics": draw(electronics, rng),
            "speckle_seed": speckle_draw(cfg, int(index) // cfg["scene_samples"])}


def task(cfg, index) -> dict:
    """Everything a worker needs to render sample ``index`` (plain data: it travels to processes)."""
    return {"index": int(index), "scene": scene_draw(cfg, int(index) // cfg["scene_samples"]),
            "sample": sample_draw(cfg, index)}
