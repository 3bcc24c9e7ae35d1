"""Writing the results."""
from __future__ import annotations

import json
import os

from .common import jsonable


def write_json(result, path):
    """Write ``result`` as strict JSON (NaN and infinities become null), under a temporary name
    renamed at the end."""
    tmp = path + ".tmp"
    with open(tmp, "w") as fh:
        json.dump(jsonable(result), fh, indent=2)
        fh.write("\n")
    os.replace(tmp, path)


__all__ = ["write_json"]
