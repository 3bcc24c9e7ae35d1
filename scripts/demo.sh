#!/usr/bin/env bash
# Set up (idempotent) and run the main job: render the demo scenes to EXR + pictures in out/.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
exec .venv/bin/mitsonar demo -o out "$@"
