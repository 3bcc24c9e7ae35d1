"""Writing output files so that a failure leaves nothing behind: a temporary name in the same
folder, renamed onto the destination at the end. Imports nothing from mitsonar."""
from __future__ import annotations

import contextlib
import os
import tempfile


@contextlib.contextmanager
def replacing(path):
    """Yield a temporary file name beside ``path`` (same extension) to write; when the block ends
    without an exception it is renamed onto ``path`` (with the usual permissions, not mkstemp's
    0600), otherwise removed. The rename is atomic on one file system."""
    path = os.fspath(path)
    folder = os.path.dirname(os.path.abspath(path))
    fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix=os.path.splitext(path)[1], dir=folder)
    os.close(fd)
    try:
        yield tmp
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)
