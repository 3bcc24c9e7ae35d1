"""Frozen render passes: a pass's kernel recorded once and replayed (issue "Survey speed").

A histogram pass (`sonar_tof.SonarTOFIntegrator`) traces the echo path in Python and Dr.Jit
turns the trace into one kernel. Tracing, assembling the kernel's IR and looking it up in the
kernel cache cost milliseconds per pass whatever the number of paths: at the spp of a 5 % scan
(a 200-ping box scan in tens of milliseconds) that is a tenth of the frame. ``dr.freeze``
(Dr.Jit's frozen functions, `drjit.freeze`) records the kernel launches of a call and replays
them on the next call with compatible inputs, skipping the Python tracing.

What makes a replay give the same numbers as tracing again:

* every JIT value the pass reads is an input of the frozen call: the arguments (seed, first
  sample, the emitted directions) and `jit_state` of the pass's context (the `common.PathSetup`
  or `shared_beams.SharedFrame`: the ping frames, the range window, the beam's parameters, the
  scene), all opaque, so a new pose, window, seed or pass start is new data for the same kernel;
* everything else that shapes the kernel is in the recording's key (`Context`): the pass's body,
  the integrator's class and settings, the scene, sensor and beam objects, and every Python
  number and string of the context (sizes, the beam's pattern, the window's width in beams);
* a scene that holds textures anywhere (`has_textures`) is traced every pass (`Context.freezable`): a replay after
  texels changed through ``mi.traverse`` read the old texels (tests/test_gradients.py's
  per-texel finite difference found it);
* so is a scene without shapes (its ray casts dispatch over shapes of other scenes, which its
  recording cannot name: Dr.Jit refused it);
* so is a scene whose meshes move (`trace_every_pass`, called by ``scan_parameters`` for vertex
  positions): a replay casts rays at the acceleration structure it recorded, not at the one
  ``params.update()`` rebuilt;
* the emitted directions are drawn before the frozen call (`emitted`): the beam's sampling table
  (``mi.MarginalContinuous2D0``) hides its arrays from Dr.Jit's traversal, so it cannot be read
  inside a recording. Drawn in a kernel of its own, the direction and its weight are the same
  float32 values as when the path kernel draws them itself (checked bit for bit in
  tests/test_speed.py, with and without freezing).

Dr.Jit refuses (``record(): ... was not specified as an input variable``) a recording that reads
a JIT value the inputs do not name, so a value missed here cannot be baked in silently.
``FREEZE = False`` (or ``dr.set_flag(dr.JitFlag.KernelFreezing, False)``) traces every pass.
"""
from __future__ import annotations

import sys

import drjit as dr
import mitsuba as mi
import numpy as np

# Trace every pass when False (the frozen and traced passes give the same scan, float32 bit for bit).
FREEZE = True
# Recordings kept per process (one per scene, sensor, integrator and pass size in use); past this
# number they are all dropped and made anew as needed.
MAX_RECORDINGS = 32


# Exact types of the leaves most members are (a `jit_state` walk visits some 170 objects per
# pass): taken in the loops below without a call. Subclasses (an IntEnum, np.float64) still go
# through `walk`'s isinstance tests: the same entries either way.
_LEAVES = frozenset((bool, int, float, str, type(None)))


def jit_state(obj):
    """(JIT values, Python scalars) reachable from ``obj``: arrays and Dr.Jit-traversable objects
    (the scene, its plugins) go to the first list, in a fixed order; numbers and strings, and the
    identity of objects that are neither, to the second (the recording's key)."""
    values, scalars, seen = [], [], set()
    leaves, add = _LEAVES, scalars.append

    def walk(o, path):
        if isinstance(o, (bool, int, float, str, type(None), np.generic)):
            add((path, o if not isinstance(o, np.generic) else o.item()))
            return
        if isinstance(o, np.ndarray):
            return      # host data: read into JIT values (which are inputs) when a setup is built
        if id(o) in seen:
            return
        seen.add(id(o))
        if isinstance(o, dr.ArrayBase):
            values.append(o)
            add((path, type(o).__name__, dr.width(o)))
            return
        if isinstance(o, (tuple, list)):
            for i, v in enumerate(o):
                if type(v) in leaves:
                    add((f"{path}[{i}]", v))
                else:
                    walk(v, f"{path}[{i}]")
            return
        if isinstance(o, dict):
            for k in sorted(o, key=str):
                walk(o[k], f"{path}[{k!r}]")
            return
        if isinstance(o, dr.detail.TraversableBase):
            values.append(o)      # Dr.Jit traverses it (a scene: shapes, BSDFs; a Python plugin: its members)
            add((path, type(o).__name__, id(o)))
            if isinstance(o, mi.Scene):
                # A Python BSDF's members are walked here: Dr.Jit's traversal of the scene does
                # not reach the textures they hold (a bitmap's texels changed through
                # mi.traverse would otherwise replay stale).
                for i, shape in enumerate(o.shapes()):
                    walk(shape.bsdf(), f"{path}.shapes[{i}].bsdf")
            if not hasattr(o, "__dict__"):
                return
        elif not hasattr(o, "__dict__"):
            add((path, type(o).__name__, id(o)))
            return
        for k, v in sorted(vars(o).items()):
            if type(v) in leaves:
                add((f"{path}.{k}", v))
            else:
                walk(v, f"{path}.{k}")

    walk(obj, "")
    return values, tuple(scalars)


class Context:
    """The non-JIT argument of a frozen pass: ``body(ctx, *args)`` and its context; equal (and
    hashed alike) when the body, the integrator and every Python scalar of the context are, so
    Dr.Jit replays a recording only for the pass it recorded."""

    def __init__(self, body, owner, ctx):
        self.body, self.ctx = body, ctx
        # Before the walk: a scene's first mi.traverse changes what the walk would find (the next
        # call then missed the recording made after it).
        scene = getattr(ctx, "scene", None) or getattr(getattr(ctx, "path_setup", None), "scene", None)
        textured = scene is not None and has_textures(scene)
        self.values, scalars = jit_state(ctx)
        # The owner (the integrator) by its class and settings, not its identity: render_scan
        # with an integrator dict makes a new one per call, which may replay the same recording.
        settings = tuple((k, v) for k, v in sorted(vars(owner).items())
                         if isinstance(v, (bool, int, float, str, type(None))))
        self.key = (body.__qualname__, type(owner).__qualname__, settings, scalars)
        # Textures (a bitmap of diffuse reflectance) are traced every pass: a replay after their
        # texels changed through mi.traverse was seen to read the texels before the change, also
        # for a texture a C++ BSDF holds (an acoustic BSDF in a twosided, Mitsuba's diffuse with a
        # bitmap), which the walk above does not reach: the scene's own traversal says.
        moving = scene is not None and _moving.get(id(scene)) is scene
        # A scene without shapes is traced too: its ray casts still dispatch over the shapes
        # Dr.Jit has registered (another scene's, loaded earlier), which no input of its
        # recording names: Dr.Jit refused the recording ("virtual function call ... no such
        # object instance was found in the function's inputs").
        empty = scene is not None and len(scene.shapes()) == 0
        self.freezable = (not textured and not moving and not empty
                          and not any(isinstance(v, mi.Texture) for v in self.values))

    def __hash__(self):
        return hash(self.key)

    def __eq__(self, other):
        return isinstance(other, Context) and other.key == self.key


# id(scene) -> (scene, whether anything it holds is a texture); the scene is kept so that its id
# is not reused while the entry lives; emptied past `MAX_RECORDINGS` entries.
_textured = {}


def has_textures(scene) -> bool:
    """Whether any parameter ``mi.traverse(scene)`` reaches belongs to a texture (once per scene)."""
    entry = _textured.get(id(scene))
    if entry is None or entry[0] is not scene:
        if len(_textured) >= MAX_RECORDINGS:
            _textured.clear()
        params = mi.traverse(scene)
        found = any(isinstance(params.properties[k][2], mi.Texture) for k in params.keys())
        entry = _textured[id(scene)] = (scene, found)
    return entry[1]


# id(scene) -> scene: scenes whose meshes move (`trace_every_pass`), traced every pass
_moving = {}


def trace_every_pass(scene):
    """Trace every pass of ``scene`` from now on: its meshes' vertices will change through
    ``mi.traverse``. A replay casts its rays at the acceleration structure of the geometry it
    recorded (the ray-tracing library's scene is no JIT value, so no input of the recording): after
    ``params.update()`` rebuilt it, replays read the old one or a freed one (renders of the same
    vertices and seed came out different, tests/test_refine_piles.py). `mitsonar.sim.render.scan_parameters`
    calls it for a scene asked for vertex positions."""
    if len(_moving) >= MAX_RECORDINGS:
        # forget only the scenes nobody else holds (clearing all would let a moving scene still in
        # use be replayed again): the dict's reference and getrefcount's argument are all they have
        for k in [k for k in _moving if sys.getrefcount(_moving[k]) <= 2]:
            del _moving[k]
    _moving[id(scene)] = scene


def _state(context, *args):
    return tuple(context.values)


def _call(context, *args):
    return context.body(context.ctx, *args)


# One recording per pass size is expected (a sweep over spp makes many): no warning for that.
# No limit inside Dr.Jit: it would drop a recording during a call (see `run`); `run` drops them.
_frozen = dr.freeze(_call, state_fn=_state, warn_after=1 << 30)
# Every context a recording was made with, kept alive until `clear` (outside any recording).
# A context holds its setup, whose ping frames are NumPy memory mapped by Dr.Jit: freeing such
# an array queues a host callback, which Dr.Jit cannot record and aborts the process on, so none
# may be freed while a recording is made. Keeping the contexts also keeps the objects whose
# identity is in a key (scene, sensor, beams) from being freed and their addresses reused.
_alive = []


def clear():
    """Drop every recording (the next pass of each context records anew)."""
    _frozen.clear()
    _alive.clear()


def run(body, owner, ctx, *args):
    """``body(ctx, *args)`` (a JIT array out), frozen unless `FREEZE` is off: traced and recorded
    on the first call with this context's key, replayed after. ``args`` are JIT values (opaque).

    A recording's virtual calls (the scene's BSDFs and shapes) are bound to Dr.Jit's registry of
    instances as it was when it was recorded; when scenes have been loaded or freed since, Dr.Jit
    refuses the replay (``assign_with_registry()``) and the recordings are made anew."""
    if not FREEZE:
        return body(ctx, *args)
    if len(_alive) >= MAX_RECORDINGS:
        clear()
    context = Context(body, owner, ctx)
    if not context.freezable:
        return body(ctx, *args)
    try:
        return _recorded(context, args)
    except RuntimeError as exc:
        if "registry" not in str(exc):
            raise
    clear()
    return _recorded(context, args)


def _recorded(context, args):
    """The frozen call, with the cyclic garbage collector held off (it could free an old setup's
    mapped arrays during a recording) and ``context`` kept when Dr.Jit recorded with it."""
    import gc

    n = _frozen.n_recordings
    enabled = gc.isenabled()
    gc.disable()
    try:
        return _frozen(context, *args)
    finally:
        if enabled:
            gc.enable()
        if _frozen.n_recordings != n:
            _alive.append(context)


class Emitted:
    """A beam whose ``sample`` returns directions drawn beforehand (`emitted`); the rest of the
    beam (``eval_dir``, ``eval``, ...) is the beam's own."""

    def __init__(self, beam, d, weight):
        self._beam, self._d, self._w = beam, d, weight

    def sample(self, u, active=True):
        return self._d, self._w

    def __getattr__(self, name):
        return getattr(self._beam, name)


def emitted(beam, samples):
    """The emitted directions and weights of ``samples`` (dims 0-1) from ``beam``, evaluated."""
    d, w = beam.sample(samples.get2(0), True)
    dr.eval(d, w)
    return d, w
