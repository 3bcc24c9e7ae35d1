"""A scene's multibeam sensor rendered at an Oculus's geometry: `SceneFrames`.

The virtual head (`mitsonar.devices.oculus.virtual.VirtualOculus`, ``frames=``) asks for the frame
of each fire message's settings: ``frames(mode, n_beams, range)``. `SceneFrames` renders the
scene file's multibeam ``sonar`` sensor with its XML properties set to the model's mode
(`mitsonar.presets.oculus.Mode`): ``n_beams`` receive beams evenly spaced across the
mode's aperture at the head's own bearing table (the sensor's ``bearings``:
`mitsonar.presets.oculus.bearing_table`, even in sine, in place of the XML's ``n_pings``,
``bearing_start`` and ``bearing_step``), the mode's beam widths (``beamwidth_h``,
``beamwidth_v``), a transmit fan as wide as the aperture (``tx_beamwidth_h``, ``tx_beamwidth_v``),
its ``frequency``, and the range window ``0 .. range`` in bins of the given width: row k of the
frame is beam k of the ping result. Frames are cached by settings (a new setting loads and renders
the scene again).
"""
from __future__ import annotations

import threading
import xml.etree.ElementTree as ET

__all__ = ["SceneFrames"]

_ID = "oculus_head"


class SceneFrames:
    """``SceneFrames(path, sensor=None, bin_width=..., spp=..., seed=...)(mode, n_beams, range)``
    -> the multibeam `mitsonar.scan.Scan` of that geometry.

    ``sensor``: the XML id (or index) of the sonar to render (default: the first ``sonar`` sensor);
    ``bin_width``: metres per range line (at most 4096 lines); ``spp``, ``seed``: the render's.
    ``renders`` counts the renders made.
    """

    def __init__(self, path, sensor=None, *, bin_width: float, spp: int = 64, seed: int = 0, max_cached: int = 8):
        if not (isinstance(bin_width, (int, float)) and bin_width > 0):
            raise ValueError(f"SceneFrames: bin_width {bin_width!r} is not allowed (> 0 m)")
        self.path = str(path)
        self.sensor = sensor
        self.bin_width = float(bin_width)
        self.spp = int(spp)
        self.seed = int(seed)
        self.max_cached = int(max_cached)
        self.renders = 0
        self._cache: dict = {}
        self._lock = threading.Lock()

    def __call__(self, mode, n_beams: int, range_m: float):
        return self._cached("frame", self._render, mode, n_beams, range_m)

    def _cached(self, what, make, mode, n_beams: int, range_m: float):
        """``make(mode, n_beams, range_m)``, made once per setting and ``what`` (the oldest of
        `max_cached` dropped first)."""
        key = (what, mode, int(n_beams), round(float(range_m), 9))
        with self._lock:
            if key not in self._cache:
                if len(self._cache) >= self.max_cached:
                    self._cache.pop(next(iter(self._cache)))
                self._cache[key] = make(mode, int(n_beams), float(range_m))
            return self._cache[key]

    def _choose(self, root):
        """The XML element of the sonar to render (given an id if it has none; ``_id`` says it)."""
        sensors = list(root.iter("sensor"))
        sonars = [s for s in sensors if s.get("type") == "sonar"]
        if isinstance(self.sensor, int) or (isinstance(self.sensor, str) and self.sensor.isdigit()):
            k = int(self.sensor)         # an index among the scene's sensors, as --sensor takes it
            chosen = [sensors[k]] if 0 <= k < len(sensors) and sensors[k].get("type") == "sonar" else []
        else:
            chosen = [s for s in sonars if self.sensor is None or s.get("id") == self.sensor][:1]
        if not chosen:
            raise ValueError(f"{self.path}: no sonar sensor"
                             + (f" with id {self.sensor!r}" if self.sensor is not None else ""))
        el = chosen[0]
        if el.get("id") is None:
            el.set("id", _ID)
        self._id = el.get("id")
        return el

    def water(self) -> dict:
        """The rendered sensor's water (`mitsonar.devices.oculus.virtual.scene_water`: its
        ``temperature`` and ``surface_z``), from the scene as it loads."""
        from mitsonar.sim.scene import live_scene
        from mitsonar.devices.oculus.virtual import scene_water

        scene = live_scene(self.path, self._choose)
        return scene_water(next(s for s in scene.sensors() if s.id() == self._id))

    def _values(self, mode, n_beams: int, range_m: float) -> dict:
        """The sensor's XML properties for a mode, a beam count and a range: {name: (tag, value)}."""
        from mitsonar.presets.oculus import bearing_table

        n_bins = max(1, min(4096, int(round(range_m / self.bin_width))))
        table = bearing_table(mode.aperture, n_beams) / 100.0
        return {"bearings": ("string", " ".join(f"{b:.2f}" for b in table)),
                "range_min": ("float", 0.0), "range_max": ("float", range_m),
                "n_bins": ("integer", n_bins), "beamwidth_h": ("float", mode.beamwidth_h),
                "beamwidth_v": ("float", mode.beamwidth_v), "tx_beamwidth_h": ("float", mode.aperture),
                "tx_beamwidth_v": ("float", mode.beamwidth_v), "frequency": ("float", mode.frequency)}

    def _edit(self, root, values):
        """Set ``values`` on the chosen sonar's element of ``root``; returns the element."""
        el = self._choose(root)
        for child in [c for c in el if c.get("name") in ("n_pings", "bearing_start", "bearing_step")]:
            el.remove(child)             # the table says them
        for name, (tag, value) in values.items():
            child = next((c for c in el if c.get("name") == name), None)
            if child is None:
                child = ET.SubElement(el, tag, name=name)
            child.tag = tag
            child.set("value", str(value))
        return el

    def sensor_at(self, mode, n_beams: int, range_m: float):
        """The scene's sonar sensor alone at that geometry (a new sensor object, cached per
        setting), for rendering the scene as loaded (`mitsonar.live.heads.LiveOculus`: the shapes
        it moves stay moved)."""
        return self._cached("sensor", self._load_sensor, mode, n_beams, range_m)

    def _load_sensor(self, mode, n_beams: int, range_m: float):
        import mitsuba as mi

        from mitsonar.sim.scene import scene_folder
        from mitsonar.sim.variant import ensure_variant

        try:
            root = ET.parse(self.path).getroot()
        except (OSError, ET.ParseError) as e:
            raise ValueError(f"{self.path}: cannot read the scene XML ({e})") from None
        el = self._edit(root, self._values(mode, n_beams, range_m))
        el.set("version", root.get("version", "3.0.0"))
        ensure_variant()
        scene_folder(self.path)
        text = ET.tostring(el, encoding="unicode")
        # the scene's <default> $parameters the sensor uses (Mitsuba refuses unused ones)
        defaults = {d.get("name"): d.get("value") for d in root.iter("default") if f"${d.get('name')}" in text}
        return mi.load_string(text, **defaults)

    def _render(self, mode, n_beams: int, range_m: float):
        from mitsonar.sim.scene import live_scene
        from mitsonar.sim.render import render_scan

        values = self._values(mode, n_beams, range_m)
        scene = live_scene(self.path, lambda root: self._edit(root, values))
        scan = render_scan(scene, spp=self.spp, seed=self.seed, sensor=self._id)
        self.renders += 1
        return scan
