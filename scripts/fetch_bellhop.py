"""Fetch Bellhop (M. B. Porter's ray/beam model, the Acoustics Toolbox) for the propagation tests.

Its Linux binary ships inside the PyPI wheel of ``aubellhop`` (built for CPython 3.12 only; the
binary itself does not need Python): ``pip download`` the wheel, unpack ``bellhop.exe`` and the
gfortran libraries it loads (by RPATH ``$ORIGIN/../../aubellhop.libs``) into ``.bellhop/``
(gitignored). ``tests/test_propagation_bellhop.py`` runs ``.bellhop/aubellhop/bin/bellhop.exe``
and fails when it is missing. Idempotent: does nothing when the binary is there.
"""
import os
import stat
import subprocess
import sys
import tempfile
import zipfile

VERSION = "0.2.1"
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DEST = os.path.join(ROOT, ".bellhop")
EXE = os.path.join(DEST, "aubellhop", "bin", "bellhop.exe")


def main():
    if os.path.isfile(EXE) and os.access(EXE, os.X_OK):
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "-m", "pip", "download", f"aubellhop=={VERSION}", "--no-deps",
               "--python-version", "3.12", "--only-binary=:all:", "-q", "-d", tmp]
        if subprocess.run(cmd).returncode != 0:
            print(f"fetch_bellhop: pip download aubellhop=={VERSION} failed", file=sys.stderr)
            return 1
        wheels = [f for f in os.listdir(tmp) if f.endswith(".whl")]
        with zipfile.ZipFile(os.path.join(tmp, wheels[0])) as z:
            for name in z.namelist():
                if name.startswith(("aubellhop/bin/bellhop.exe", "aubellhop.libs/")):
                    z.extract(name, DEST)
    os.chmod(EXE, os.stat(EXE).st_mode | stat.S_IXUSR | stat.S_IXGRP | stat.S_IXOTH)
    print(f"fetch_bellhop: {os.path.relpath(EXE, ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
