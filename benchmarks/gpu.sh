#!/usr/bin/env bash
# The GPU checks of issue 55 in one go, on a machine with an NVIDIA GPU and no network: the
# frame, box-scan, side-scan, live-ping and dataset benchmarks and the GPU-relevant tests on
# cuda_ad_mono, in at most 6 minutes, printing one JSON object with the card's name (last line).
#
# What it installs comes with the tree: the wheels benchmarks/gpu_prep.sh put in .gpu_wheels/
# (carry ".gpu_wheels"), installed into /tmp/mitsonar-site unless mitsuba and drjit import
# already (a carried virtual environment, or an earlier run). Each step runs under its own
# time limit (BUDGET_S seconds in all, 360 by default); a step past its limit is recorded as such
# and the next one runs. With $OUT set (the device tool), the JSON and each step's log go there.
#
# Usage: bash benchmarks/gpu.sh
#   MITSONAR_VARIANT=llvm_ad_mono  try it on a CPU;  PYTHON=.venv/bin/python  another interpreter;
#   GPU_STEPS=tests,dataset        only these steps;  BUDGET_S=360  the seconds for all steps
set -uo pipefail
cd "$(dirname "$0")/.."
out=${OUT:-$(mktemp -d)}
PYTHON=${PYTHON:-python3}
site=/tmp/mitsonar-site
if ! "$PYTHON" -c "import mitsuba, drjit" 2>/dev/null; then
    if ! ls .gpu_wheels/*.whl >/dev/null 2>&1; then
        echo '{"error": "neither mitsuba nor .gpu_wheels/ here: run benchmarks/gpu_prep.sh where pip works and carry .gpu_wheels"}'
        exit 2
    fi
    "$PYTHON" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target "$site" \
        .gpu_wheels/*.whl >"$out/install.log" 2>&1 || { echo '{"error": "wheel install failed: see install.log"}'; exit 2; }
    export PYTHONPATH="$site"
fi
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}"
export MITSONAR_VARIANT=${MITSONAR_VARIANT:-cuda_ad_mono} PYTHONUNBUFFERED=1
exec "$PYTHON" - "$out" "${BUDGET_S:-360}" "${GPU_STEPS:-}" <<'PY'
import json, os, subprocess, sys, time

out, budget, only = sys.argv[1], float(sys.argv[2]), [s for s in sys.argv[3].split(",") if s]
start = time.monotonic()
try:
    card = subprocess.run(["nvidia-smi", "--query-gpu=name,driver_version,memory.total", "--format=csv,noheader"],
                          capture_output=True, text=True, timeout=20).stdout.strip()
except (OSError, subprocess.SubprocessError) as exc:
    card = f"no nvidia-smi ({exc.__class__.__name__})"
py = sys.executable
# (name, command, seconds): the benchmarks print one JSON object (their last), the tests a summary
STEPS = [
    ("tests", [py, "-m", "pytest", "-q", "-x", "-p", "no:randomly", "-p", "no:cacheprovider",
               "tests/test_devicechain.py", "tests/test_electronics.py", "tests/test_realism.py",
               "tests/test_determinism.py", "-k", "not hilbert and not worker"], 100),
    ("frame_and_live_ping", [py, "benchmarks/frame_profile.py", "--quick"], 70),
    ("frame_targets", [py, "benchmarks/frame_targets.py", "--quick", "--repeats", "3", "--ref-spp", "4096",
                       "--big-spp", "4096"], 110),
    ("sidescan", [py, "benchmarks/sidescan.py", "--repeats", "3", "--ref-spp", "16384"], 40),
    ("dataset", [py, "benchmarks/dataset.py", "--samples", "8", "--spp", "256"], 30),
]


def last_json(text):
    """The last JSON object printed: a line that parses, or the last '{' ... '}' block."""
    lines = text.strip().splitlines()
    for i in range(len(lines) - 1, -1, -1):
        if lines[i].startswith("{"):
            try:
                return json.loads("\n".join(lines[i:]))
            except ValueError:
                continue
    return None


result = {"card": card, "variant": os.environ["MITSONAR_VARIANT"], "steps": {}}
for name, cmd, limit in STEPS:
    if only and name not in only:
        continue
    left = budget - (time.monotonic() - start)
    if left < 10:
        result["steps"][name] = {"skipped": "no time left in the budget"}
        continue
    t0 = time.monotonic()
    try:
        run = subprocess.run(cmd, capture_output=True, text=True, timeout=min(limit, left - 5))
        rc, text = run.returncode, run.stdout + run.stderr
    except subprocess.TimeoutExpired as exc:
        rc = "timeout"
        text = (exc.stdout or b"").decode(errors="replace") if isinstance(exc.stdout, bytes) else (exc.stdout or "")
    with open(os.path.join(out, f"{name}.log"), "w") as fh:
        fh.write(text)
    entry = {"rc": rc, "seconds": round(time.monotonic() - t0, 1)}
    if name == "tests":
        entry["summary"] = text.strip().splitlines()[-1] if text.strip() else ""
    else:
        entry["result"] = last_json(text)
        if entry["result"] is None:
            entry["tail"] = text[-600:]
    result["steps"][name] = entry
result["seconds"] = round(time.monotonic() - start, 1)
with open(os.path.join(out, "gpu.json"), "w") as fh:
    json.dump(result, fh, indent=1)
print(json.dumps(result))
PY
