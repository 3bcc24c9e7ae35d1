#!/usr/bin/env bash
# Prepare benchmarks/gpu.sh's wheels, here (with network), for a GPU machine without network:
# the packages mitsonar needs that an NVIDIA machine's Python 3.12 image lacks (mitsuba, drjit,
# OpenEXR, pyserial, bluerobotics-ping; numpy, scipy, matplotlib, pyyaml, tqdm, threadpoolctl and
# pytest are there), as CPython 3.12 x86-64 wheels in .gpu_wheels/ (ignored by git through
# .git/info/exclude, so it travels only when named: carry ".gpu_wheels"). The Mitsuba wheel is
# trimmed to the variants mitsonar runs (llvm_ad_mono, cuda_ad_mono, and scalar_rgb) and loses its
# C++ headers and sun-sky tables, so that the tree and the wheels fit a 64 MiB transfer.
#
# Usage: bash benchmarks/gpu_prep.sh   (GPU_PYTHON=3.12 to target another Python)
set -euo pipefail
cd "$(dirname "$0")/.."
dest=.gpu_wheels
exclude=$(git rev-parse --git-path info/exclude)
mkdir -p "$(dirname "$exclude")"
grep -qxF "/$dest/" "$exclude" 2>/dev/null || echo "/$dest/" >> "$exclude"
rm -rf "$dest" && mkdir -p "$dest"
py=${GPU_PYTHON:-3.12}
python3 -m pip download -q --no-deps --only-binary=:all: --python-version "$py" --implementation cp \
    --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 --platform manylinux_2_17_x86_64 \
    --platform manylinux2014_x86_64 --platform any -d "$dest" \
    "mitsuba>=3.9,<3.10" "drjit>=1.5,<1.6" "OpenEXR>=3.3,<4" "pyserial>=3.5,<4" "bluerobotics-ping>=0.2,<0.3"
python3 - "$dest" <<'PY'
import glob, os, re, sys, zipfile

keep = ("llvm_ad_mono.", "cuda_ad_mono.", "scalar_rgb.")
for path in glob.glob(os.path.join(sys.argv[1], "mitsuba-*.whl")):
    def dropped(name):
        base = name.split("/")[-1]
        if re.match(r"(llvm|cuda|scalar)_\w+\.cpython", base) and not base.startswith(keep):
            return True
        return name.startswith(("mitsuba/include/", "mitsuba/data/sunsky/"))
    src = zipfile.ZipFile(path)
    out = path + ".tmp"
    with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as dst:
        for info in src.infolist():
            if dropped(info.filename):
                continue
            data = src.read(info)
            if info.filename.endswith(".dist-info/RECORD"):   # the kept files only
                lines = data.decode().splitlines()
                data = ("\n".join(l for l in lines if not dropped(l.split(",")[0])) + "\n").encode()
            dst.writestr(info, data)
    src.close()
    os.replace(out, path)
PY
du -ch "$dest"/*.whl | tail -1
