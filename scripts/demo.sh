#!/usr/bin/env bash
# Set up (idempotent) and run the main job: render the demo scenes to EXR + pictures in out/.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
# --force: the demo renders its own pictures again on every run (out/ is its folder)
.venv/bin/mitsonar demo -o out --force "$@"
# Side-scan: a lawnmower survey over the wreck, its waterfall and georeferenced mosaic (out/wreck_sidescan_*).
.venv/bin/python -m mitsonar.scenes.sidescan_demo -o out -q
