"""The declared dependency floors are the ones scripts/test_floors.sh installs: the constraints
scripts/floor_constraints.py writes pin every runtime dependency of pyproject.toml at its lower
bound, a dependency without one is refused, and the code keeps out of names that only NumPy 2
has (the floor is 1.26, and arlpy and others pin numpy<2)."""
import os
import re
import subprocess
import sys
import tomllib

import pytest
from conftest import ROOT

Requirement = pytest.importorskip("packaging.requirements").Requirement
Version = pytest.importorskip("packaging.version").Version

SCRIPT = os.path.join(ROOT, "scripts", "floor_constraints.py")


def generate(*args):
    return subprocess.run([sys.executable, SCRIPT, *args], capture_output=True, text=True, timeout=60)


def test_the_constraints_pin_every_runtime_dependency_at_its_lower_bound():
    with open(os.path.join(ROOT, "pyproject.toml"), "rb") as f:
        deps = [Requirement(d) for d in tomllib.load(f)["project"]["dependencies"]]
    run = generate()
    assert run.returncode == 0, run.stderr
    pins = [Requirement(line) for line in run.stdout.splitlines() if line and not line.startswith("#")]
    assert [p.name for p in pins] == [d.name for d in deps]
    for dep, pin in zip(deps, pins):
        (spec,) = pin.specifier
        lower = [s.version for s in dep.specifier if s.operator == ">="]
        assert spec.operator == "==" and [spec.version] == lower, (dep, pin)
        # the floor is inside the declared range (not excluded by an upper bound or a !=)
        assert dep.specifier.contains(Version(spec.version), prereleases=True), (dep, pin)


@pytest.mark.parametrize("dep", ["numpy", "numpy<3", "numpy==1.26", "numpy>=1.26,>=2"])
def test_a_dependency_without_one_lower_bound_is_one_line(tmp_path, dep):
    pyproject = tmp_path / "pyproject.toml"
    pyproject.write_text(f'[project]\nname = "x"\ndependencies = ["pyyaml>=6,<7", "{dep}"]\n')
    run = generate(str(pyproject))
    assert run.returncode == 1 and run.stdout == ""
    assert run.stderr.count("\n") == 1 and str(pyproject) in run.stderr and repr(dep) in run.stderr
    assert "'>=X'" in run.stderr


def test_markers_and_extras_keep_their_floor(tmp_path):
    pyproject = tmp_path / "pyproject.toml"
    pyproject.write_text('[project]\nname = "x"\n'
                         'dependencies = ["Foo.bar[a,b] >= 1.2.3 , <2 ; python_version >= \'3.11\'"]\n')
    run = generate(str(pyproject))
    assert run.returncode == 0 and run.stdout.splitlines()[1:] == ["Foo.bar==1.2.3"]


# Names NumPy 2.0 and later added (1.26 has none of them): mitsonar._compat holds what needs one.
NUMPY2_ONLY = re.compile(
    r"\b(?:np|numpy)\.(?:trapezoid|concat|isdtype|unstack|cumulative_sum|cumulative_prod|astype|"
    r"matrix_transpose|vecdot|permute_dims|unique_values|unique_counts|unique_inverse|unique_all|"
    r"bool|long|ulong|pow|acos|acosh|asin|asinh|atan|atanh|atan2|bitwise_left_shift|"
    r"bitwise_right_shift|bitwise_invert|linalg\.(?:vecdot|matrix_norm|vector_norm|matrix_transpose|"
    r"outer|cross|diagonal|trace|svdvals))\b")


def test_no_numpy_2_only_names_outside_the_compat_module():
    found = []
    for top in ("mitsonar", "plugins", "hilbertmap", "tests", "examples", "benchmarks", "scripts"):
        for root, _, files in os.walk(os.path.join(ROOT, top)):
            for name in files:
                path = os.path.join(root, name)
                if not name.endswith(".py") or path == os.path.join(ROOT, "mitsonar", "_compat.py"):
                    continue
                with open(path, encoding="utf-8") as f:
                    for k, line in enumerate(f, 1):
                        if NUMPY2_ONLY.search(line) and "NUMPY2_ONLY" not in line:
                            found.append(f"{os.path.relpath(path, ROOT)}:{k}: {line.strip()}")
    assert found == []


def test_the_trapezoid_rule_is_numpys():
    """`mitsonar._compat.trapezoid` integrates as NumPy's rule does on any supported release: exact
    for a line, along the axis asked, with unequal spacing."""
    import numpy as np

    from mitsonar._compat import trapezoid

    x = np.array([0.0, 0.5, 2.0, 3.0])
    y = np.stack([2.0 * x + 1.0, x ** 2])
    got = trapezoid(y, x, axis=1)
    assert got[0] == pytest.approx(3.0 ** 2 + 3.0)
    assert got[1] == pytest.approx(0.5 * (0.5 * 0.25 + 1.5 * (0.25 + 4.0) + 1.0 * (4.0 + 9.0)))
    assert trapezoid(y.T, x, axis=0) == pytest.approx(got)
