#!/usr/bin/env bash
# The declared dependency ranges, tested (CI runs this after scripts/test.sh):
#
# 1. .venv-floors: every runtime dependency at the lower bound pyproject.toml declares (the
#    constraints scripts/floor_constraints.py writes, e.g. numpy==1.26, scipy==1.11.1,
#    matplotlib==3.8, OpenEXR==3.3), pytest and hypothesis at whatever suits them;
# 2. .venv-arlpy: the checkout and arlpy (the field's acoustics library, which pins numpy<2 and
#    scipy<1.14) installed by one pip command, as a user would (numpy 1.26.x, scipy 1.13.x);
#
# and in each, part of the suite. At the floors: the files below, which render every kind
# (mechanical, multibeam, side-scan, echo sounders), write and read the scan files (EXR, NPZ),
# compute the acoustics and the beam and material integrals, and run the CLI. Beside arlpy: a
# render of each kind, saved and read back, the CLI's render, survey and bathymetry commands, the
# files and the acoustics. Each environment is made anew (pip's cache makes that seconds). The
# floors are installed from wheels only: a floor with no wheel for this Python is not one a user
# can install.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}

FLOORS_TESTS=(
  tests/test_io.py tests/test_acoustics.py tests/test_beam.py tests/test_materials.py
  tests/test_multibeam.py tests/test_sidescan.py tests/test_bathymetry.py tests/test_cli.py
  tests/test_floors.py
  tests/test_hilbertmap.py::test_water_boundary_keeps_the_side_of_the_band_facing_the_sonar
  tests/test_frame_overhead.py::test_receive_weighted_emission_weights_integrate_the_fan
)
ARLPY_TESTS=(
  tests/test_io.py tests/test_acoustics.py tests/test_floors.py
  tests/test_cli.py::test_render_plot_info_round_trip
  tests/test_multibeam.py::test_every_row_sees_the_wall_where_the_geometry_puts_it
  tests/test_sidescan.py::test_rows_poses_times_and_the_file_round_trip
  tests/test_sidescan.py::test_survey_command_writes_the_waterfall_and_the_mosaic
  tests/test_bathymetry.py::test_altimeter_leading_edge_is_unbiased_where_the_centroid_is_long
  tests/test_bathymetry.py::test_cli_writes_the_products_and_refuses_bad_input_in_one_line
)

fresh_venv() {
  rm -rf "$1"
  "$PY" -m venv "$1"
  "$1/bin/python" -m pip install -q --upgrade pip >/dev/null
}

versions() {
  "$1/bin/python" -c 'import importlib.metadata as m
print("  " + ", ".join(f"{n} {m.version(n)}" for n in ("numpy", "scipy", "matplotlib", "OpenEXR", "mitsuba", "drjit")))'
}

echo "floors: runtime dependencies at their declared lower bounds (.venv-floors)"
fresh_venv .venv-floors
"$PY" scripts/floor_constraints.py > .venv-floors/constraints.txt
.venv-floors/bin/python -m pip install -q --only-binary :all: -c .venv-floors/constraints.txt -e . pytest hypothesis
versions .venv-floors
.venv-floors/bin/python -m pytest -q -p no:cacheprovider --durations=5 "${FLOORS_TESTS[@]}"

echo "floors: the checkout beside arlpy, one pip command (.venv-arlpy)"
fresh_venv .venv-arlpy
.venv-arlpy/bin/python -m pip install -q -e . arlpy pytest hypothesis
versions .venv-arlpy
.venv-arlpy/bin/python -c 'import arlpy.uwa, mitsonar'
.venv-arlpy/bin/python -m pytest -q -p no:cacheprovider --durations=5 "${ARLPY_TESTS[@]}"
