import contextlib
import os
import shutil
import sys
import tempfile

import numpy as np
import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCENES = os.path.join(ROOT, "scenes_xml")


def frame_matrix(boresight, scan_axis, position=(0.0, 0.0, 0.0)):
    """4x4 beam frame (columns x, y = scan axis, z = boresight, position) from two directions."""
    z = np.asarray(boresight, float)
    z /= np.linalg.norm(z)
    y = np.asarray(scan_axis, float)
    y = y - z * (y @ z)
    y /= np.linalg.norm(y)
    x = np.cross(y, z)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = x, y, z, position
    return m


def subcommand_runner(module):
    """``run(*argv)``: ``mitsonar ARGV`` parsed by ``module``'s subcommands alone (its
    ``add_subcommands``, e.g. `mitsonar.cli.live`), arguments turned to strings; returns the
    command's exit status."""
    import argparse

    def run(*argv):
        parser = argparse.ArgumentParser(prog="mitsonar")
        module.add_subcommands(parser.add_subparsers(dest="command", required=True))
        args = parser.parse_args([str(a) for a in argv])
        return args.func(args)

    return run


def on_cuda() -> bool:
    """True when the suite runs on a ``cuda`` variant (``MITSONAR_VARIANT=cuda_ad_mono``). There,
    the same arithmetic compiled into two different kernels may round differently (ptxas fuses
    multiplies and adds into FMAs per kernel) and OptiX builds its own BVH, so assertions of bit
    identity between two code paths become float32-rounding agreement (each test says how close)."""
    import mitsonar  # noqa: F401  (selects the variant: skip conditions are read before any test runs)
    import mitsuba as mi

    return (mi.variant() or "").startswith("cuda")


def matrix_attr(m):
    return " ".join(f"{v:.17g}" for v in np.asarray(m, float).ravel())


def sonar_xml(to_world=None, **params):
    """A <sensor type="sonar"> element; ints become <integer>, strings <string>, floats <float>."""
    items = []
    if to_world is not None:
        items.append(f'<transform name="to_world"><matrix value="{matrix_attr(to_world)}"/></transform>')
    for k, v in params.items():
        if isinstance(v, str):
            items.append(f'<string name="{k}" value="{v}"/>')
        elif isinstance(v, (int, np.integer)) and not isinstance(v, bool):
            items.append(f'<integer name="{k}" value="{int(v)}"/>')
        else:
            items.append(f'<float name="{k}" value="{float(v):.17g}"/>')
    return '<sensor type="sonar">' + "".join(items) + "</sensor>"


def scene_xml(sensor, *shapes, integrator='<integrator type="sonar_tof"/>'):
    return '<scene version="3.0.0">' + integrator + sensor + "".join(shapes) + "</scene>"


def rectangle_xml(to_world, bsdf):
    return f'<shape type="rectangle"><transform name="to_world"><matrix value="{matrix_attr(to_world)}"/></transform>{bsdf}</shape>'


def sphere_xml(center, radius, bsdf):
    c = center
    return (f'<shape type="sphere"><point name="center" x="{c[0]}" y="{c[1]}" z="{c[2]}"/>'
            f'<float name="radius" value="{radius}"/>{bsdf}</shape>')


def acoustic_xml(diffuse=0.0, specular=0.0, shininess=30.0):
    return (f'<bsdf type="acoustic"><float name="diffuse" value="{diffuse}"/>'
            f'<float name="specular" value="{specular}"/><float name="shininess" value="{shininess}"/></bsdf>')


def script(path):
    """The module of the script at ``path`` (relative to the checkout: ``benchmarks/live.py``),
    loaded from its file (benchmarks/, scripts/ and examples/ are not packages)."""
    import importlib.util

    name = os.path.splitext(os.path.basename(path))[0]
    spec = importlib.util.spec_from_file_location(name, os.path.join(ROOT, path))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def example(name):
    """The module ``examples/<name>.py`` (its folder on ``sys.path``, for its own imports)."""
    sys.path.insert(0, os.path.join(ROOT, "examples"))
    return script(os.path.join("examples", name + ".py"))


def jit_kernels(fn, *args, **kwargs):
    """Run ``fn`` and return the Dr.Jit kernels it launched: (hashes, hashes compiled anew).

    Comparing hashes between two calls does not depend on what an earlier run left in the kernel
    cache (~/.drjit): a value or an array size written into a kernel gives it a new hash."""
    import drjit as dr

    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        dr.kernel_history()  # clear
        fn(*args, **kwargs)
        history = [k for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT]
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    return [k["hash"] for k in history], [k["hash"] for k in history if not k.get("cache_hit")]


def drjit_cache_dir():
    """Dr.Jit's kernel cache, where it is for this process (``DRJIT_CACHE_DIR``, else ~/.drjit):
    a process given another HOME keeps using it instead of compiling every kernel again."""
    return os.environ.get("DRJIT_CACHE_DIR") or os.path.join(os.path.expanduser("~"), ".drjit")


@contextlib.contextmanager
def ray_sandbox():
    """A HOME and a temp folder of their own for the Ray a test starts, removed after: yields
    ``(env, home)``, the environment to run Ray in (the caller's without its ``RAY_*`` variables).

    A local ``ray.init()`` writes ``~/.ray/auth_token``, which turns token authentication on for
    every later Ray head of the user, and keeps its sessions (logs, sockets) under ``/tmp/ray``
    (``RAY_TMPDIR``): neither may be the user's. The folder is short (``/tmp/mrayXXXXXXXX``): Ray's
    unix sockets live under it (at most 107 bytes a path). tests/test_dataset_ray.py runs the
    tests that start Ray (marker ``starts_ray``) with a HOME and RAY_TMPDIR of its own and checks
    that they stay empty."""
    root = tempfile.mkdtemp(prefix="mray", dir="/tmp")
    home = os.path.join(root, "home")
    os.mkdir(home)
    env = {k: v for k, v in os.environ.items() if not k.startswith("RAY_")}
    # RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0: Ray otherwise replaces a loopback --node-ip-address by
    # the machine's routable address and listens on all interfaces; this keeps a head's ports on
    # 127.0.0.1 (and no other machine could join).
    env.update(HOME=home, RAY_TMPDIR=root, RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER="0", RAY_USAGE_STATS_ENABLED="0",
               DRJIT_CACHE_DIR=drjit_cache_dir())
    try:
        yield env, home
    finally:
        shutil.rmtree(root, ignore_errors=True)


@pytest.fixture
def ray_env():
    """`ray_sandbox` for a Ray started in the test's own process: this process's environment is
    the sandbox's until the test ends, then the one before it again (with it go the ``RAY_*``
    variables Ray sets in the process that starts it, such as ``RAY_AUTH_MODE``). The test shuts
    its Ray down before it returns. Yields the environment, for its subprocesses."""
    saved = dict(os.environ)
    with ray_sandbox() as (env, _):
        try:
            os.environ.clear()
            os.environ.update(env)
            yield env
        finally:
            os.environ.clear()
            os.environ.update(saved)


def pytest_collection_modifyitems(items):
    """A test that uses `ray_env` or tests/test_dataset_ray.py's ``ray_head`` starts Ray: marker
    ``starts_ray`` (the check that they leave nothing behind runs these)."""
    for item in items:
        if {"ray_env", "ray_head"} & set(getattr(item, "fixturenames", ())):
            item.add_marker(pytest.mark.starts_ray)


@pytest.fixture(scope="session")
def mitsonar_mod():
    import mitsonar

    return mitsonar


def pytest_configure(config):
    """The suite's variant: ``import mitsonar`` chooses none (tests/test_import.py checks that in
    fresh interpreters), so the tests' plugins, Dr.Jit arrays and ``mi.load_dict`` calls get the one
    a user's `mitsonar.set_variant` (or first `load_scene`) would give (``MITSONAR_VARIANT``, else
    ``llvm_ad_mono``), before any test module is imported."""
    import mitsonar

    mitsonar.ensure_variant()


sys.path.insert(0, os.path.dirname(__file__))
