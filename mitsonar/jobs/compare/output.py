"""The output folder of a comparison: checked before anything is rendered, created only when the
inputs are good, removed again if the run fails, and its files written under temporary names
that are renamed together at the end (an interrupted run leaves no half-written results)."""
from __future__ import annotations

import json
import os
import shutil

from mitsonar import _files
from mitsonar._files import StagedFiles, replacing
from mitsonar.jobs.compare.common import CompareError, jsonable


def check_output_folder(path) -> None:
    """Raise `CompareError` (one line) unless ``path`` is a folder this process can write in or
    can create (its nearest existing ancestor is a folder it can write in). Creates nothing."""
    _files.check_output_folder(path, CompareError, writable=True)


class OutputFolder:
    """Context manager for one run's output folder.

    On entry the folder is checked (`check_output_folder`) and created with any missing parents.
    `stage` gives a temporary path for an output file and `commit` renames every staged file to
    its name. If the block raises (KeyboardInterrupt included), staged files are deleted and, if
    this run created the folder and nothing was committed to it, the folder is removed; a cached
    reference committed before the failure stays, as does whatever a folder held before.
    """

    def __init__(self, path):
        self.path = os.fspath(path)
        self.created = None  # the top-most folder this run made, if any
        self._staged = StagedFiles()

    def __enter__(self):
        check_output_folder(self.path)
        missing, p = [], os.path.abspath(self.path)
        while not os.path.exists(p):
            missing.append(p)
            p = os.path.dirname(p)
        try:
            os.makedirs(self.path, exist_ok=True)
        except OSError as exc:
            raise CompareError(f"-o {self.path!r}: cannot create the output folder ({exc.strerror})") from None
        self.created = missing[-1] if missing else None
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is not None:
            self.discard()
        return False

    def final(self, name) -> str:
        """The path ``name`` will have in the folder."""
        return os.path.join(self.path, name)

    def stage(self, name) -> str:
        """A temporary path (same folder, same extension) for the output file ``name``."""
        return self._staged.temporary(self.final(name))

    def commit(self) -> None:
        """Rename every staged file to its final name."""
        self._staged.commit()

    def discard(self) -> None:
        """Delete the staged files, and the folder if this run created it and it holds nothing
        else: a reference cached before the failure stays (it took most of the run's time, and a
        later run reuses it)."""
        self._staged.discard()
        if self.created:
            kept = [f for _, _, files in os.walk(self.created) for f in files]
            if not kept:
                shutil.rmtree(self.created, ignore_errors=True)


def write_json(result, path):
    """Write ``result`` as strict JSON (NaN and infinities become null), under a temporary name
    renamed at the end."""
    with replacing(path) as tmp, open(tmp, "w") as fh:
        json.dump(jsonable(result), fh, indent=2)
        fh.write("\n")


__all__ = ["OutputFolder", "check_output_folder", "write_json"]
