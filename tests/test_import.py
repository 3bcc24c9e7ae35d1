"""``import mitsonar`` only defines names (issue 57, "A house without magic"): no Mitsuba, Dr.Jit,
SciPy or Matplotlib, no import hook, no environment variable; the variant is chosen and the
plugins registered on first use or by `mitsonar.set_variant`."""
import json
import os
import subprocess
import sys

HEAVY = ("mitsuba", "drjit", "scipy", "matplotlib")


def run(code, **env):
    full = {k: v for k, v in os.environ.items() if k not in ("MITSONAR_VARIANT", "DRJIT_LIBLLVM_PATH")}
    full.update(env)
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=full, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


def test_import_mitsonar_has_no_side_effects():
    got = run("import json, os, sys\n"
              "before = (list(sys.meta_path), dict(os.environ))\n"
              "import mitsonar\n"
              f"heavy = sorted(m for m in sys.modules if m.split('.')[0] in {set(HEAVY)!r})\n"
              "print(json.dumps([heavy, list(sys.meta_path) == before[0], dict(os.environ) == before[1]]))")
    assert got == [[], True, True]


def test_first_use_chooses_the_variant_and_registers_the_plugins():
    """load_scene picks MITSONAR_VARIANT (else llvm_ad_mono) and registers the plugins; plain Mitsuba
    finds them after `set_variant`, and again after the variant changes."""
    got = run("import json, mitsonar, sys\n"
              "scene = mitsonar.load_scene(mitsonar.example_scene('box'))\n"
              "import mitsuba as mi\n"
              "first = [mitsonar.variant(), type(scene.sensors()[0]).__name__]\n"
              "mi.set_variant('scalar_rgb'); mi.set_variant('llvm_ad_mono')\n"
              "again = type(mi.load_dict({'type': 'sonar'})).__name__\n"
              "print(json.dumps(first + [again]))", MITSONAR_VARIANT="llvm_ad_mono")
    assert got == ["llvm_ad_mono", "SonarSensor", "SonarSensor"]
    got = run("import json, mitsonar\n"
              "mitsonar.set_variant()\n"
              "import mitsuba as mi\n"
              "print(json.dumps(type(mi.load_dict({'type': 'sonar'})).__name__))")
    assert got == "SonarSensor"


def test_the_libllvm_is_chosen_when_mitsonar_first_chooses_the_variant():
    """`set_variant` sets DRJIT_LIBLLVM_PATH (when a libLLVM of a working version is on the system)
    before Dr.Jit loads; once drjit is imported it leaves the environment alone."""
    from mitsonar.sim.variant import MIN_LLVM, find_libllvm

    path, version = find_libllvm()
    got = run("import json, os, mitsonar\n"
              "mitsonar.set_variant()\n"
              "print(json.dumps(os.environ.get('DRJIT_LIBLLVM_PATH')))")
    assert got == (path if version is not None and version >= MIN_LLVM else None)
    got = run("import json, os, drjit, mitsonar\n"
              "from mitsonar.sim.variant import prepare_llvm_environment\n"
              "prepare_llvm_environment()\n"
              "print(json.dumps(os.environ.get('DRJIT_LIBLLVM_PATH')))")
    assert got is None


def test_the_newest_libllvm_of_a_working_version_is_chosen(tmp_path, monkeypatch):
    """With LLVM 15, 16 and 19 installed (Debian's names: ``libLLVM-N.so`` and the soname of LLVM 18
    and later, ``libLLVM.so.19.1``), `find_libllvm` takes 19 and `prepare_llvm_environment` points
    Dr.Jit at it; with 15 alone it finds 15, too old, and sets nothing (`check_backend` then refuses)."""
    from mitsonar import backend

    lib, llvm16 = tmp_path / "lib", tmp_path / "llvm-16" / "lib"
    lib.mkdir()
    llvm16.mkdir(parents=True)
    for name in ("libLLVM-15.so", "libLLVM-15.so.1", "libLLVM.so.19.1", "libLLVMX86CodeGen.a"):
        (lib / name).write_bytes(b"")
    (llvm16 / "libLLVM.so").write_bytes(b"")
    patterns = [str(lib / "libLLVM*.so*"), str(tmp_path / "llvm-*" / "lib" / "libLLVM*.so*")]
    assert backend.find_libllvm(patterns) == (str(lib / "libLLVM.so.19.1"), 19)
    assert backend.find_libllvm(patterns[1:]) == (str(llvm16 / "libLLVM.so"), 16)
    assert backend.find_libllvm([str(lib / "libLLVM-15*")]) == (str(lib / "libLLVM-15.so"), 15)
    assert backend.find_libllvm([str(tmp_path / "none*")]) == (None, None)

    # the environment, as a fresh process that has not imported drjit sees it
    monkeypatch.delitem(sys.modules, "drjit", raising=False)
    monkeypatch.delenv("DRJIT_LIBLLVM_PATH", raising=False)
    monkeypatch.setattr(backend, "LIBLLVM_PATTERNS", tuple(patterns))
    backend.prepare_llvm_environment()
    assert os.environ["DRJIT_LIBLLVM_PATH"] == str(lib / "libLLVM.so.19.1")
    monkeypatch.delenv("DRJIT_LIBLLVM_PATH")
    monkeypatch.setattr(backend, "LIBLLVM_PATTERNS", (str(lib / "libLLVM-15*"),))
    backend.prepare_llvm_environment()
    assert "DRJIT_LIBLLVM_PATH" not in os.environ


def test_the_receiver_chain_and_the_plugins_choose_the_variant_on_first_use():
    """Entry points that need no scene work first in a fresh interpreter: the electronics' chain
    (Dr.Jit kernels) and a plugin module imported directly after `ensure_variant`, whose class is
    the one Mitsuba builds."""
    got = run("import json, numpy as np\n"
              "from mitsonar.receiver.electronics import Electronics\n"
              "data = Electronics().apply(np.full((2, 5), 1e-3), np.linspace(1.0, 2.0, 5), seed=1)\n"
              "import mitsonar\n"
              "print(json.dumps([list(data.shape), mitsonar.variant()]))")
    assert got == [[2, 5], "llvm_ad_mono"]
    got = run("import json, mitsonar\n"
              "mitsonar.ensure_variant()\n"
              "import mitsuba as mi\n"
              "from mitsonar.plugins.integrators import common, sonar_tof\n"
              "print(json.dumps([common.MAX_DEPTH > 0,\n"
              "                  type(mi.load_dict({'type': 'sonar_tof'})) is sonar_tof.SonarTOFIntegrator]))")
    assert got == [True, True]
