"""Writing output files so that a failure leaves nothing behind: each file is written under a
temporary name in its own folder and renamed onto its final name at the end. Imports nothing
from mitsonar."""
from __future__ import annotations

import contextlib
import os
import tempfile


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


#: The process's umask, read once (reading it means setting it, which races with other threads).
_UMASK = _umask()


def check_output_folder(folder, error, *, holds=None, what="", option="-o", force=False) -> None:
    """Refuse, with one line raised as ``error``, an output folder that is a file, or one that
    already holds a run (``holds(folder)`` true; ``what`` names the run: "already holds {what};
    choose a new or empty folder", and, when the command takes ``--force`` (``force`` True),
    "or --force to replace it"). Creates nothing: `make_output_folder` does."""
    if os.path.exists(folder) and not os.path.isdir(folder):
        raise error(f"{option} {folder!r} is a file, not a folder")
    if holds is not None and os.path.isdir(folder) and holds(folder):
        raise error(f"{option} {folder!r} already holds {what}; choose a new or empty folder"
                    + (", or --force to replace it" if force else ""))


def make_output_folder(folder, error, option="-o") -> None:
    """Create an output folder (and its parents), or raise ``error`` saying in one line why not."""
    try:
        os.makedirs(folder, exist_ok=True)
    except OSError as exc:
        raise error(f"{option} {folder!r}: cannot create the output folder ({exc.strerror})") from None


class StagedFiles:
    """Files written under temporary names next to their final ones: `temporary(final)` gives
    the name to write, `commit` renames every file into place (all or none: if one rename fails,
    those already renamed are removed), `discard` removes what was not committed. Temporary names
    keep the final extension last (writers choose the format by it) and start with a dot."""

    def __init__(self):
        self.pending = []  # (temporary, final)

    def temporary(self, final) -> str:
        final = os.fspath(final)
        folder, name = os.path.split(os.path.abspath(final))
        stem, ext = os.path.splitext(name)
        try:
            fd, tmp = tempfile.mkstemp(dir=folder, prefix=f".{stem}.", suffix=f".partial{ext}")
        except OSError as exc:  # its text would name the temporary file: name the user's
            raise type(exc)(exc.errno, f"cannot write {final} ({exc.strerror})") from None
        os.close(fd)
        self.pending.append((tmp, final))
        return tmp

    def commit(self) -> None:
        done = []
        try:
            for tmp, final in self.pending:
                os.chmod(tmp, 0o666 & ~_UMASK)  # mkstemp makes 0600; a plain open would give these
                os.replace(tmp, final)
                done.append(final)
        except OSError:
            for final in done:
                os.remove(final)
            raise
        self.pending = []

    def discard(self) -> None:
        for tmp, _ in self.pending:
            try:
                os.remove(tmp)
            except OSError:
                pass
        self.pending = []

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            self.commit()
        else:
            self.discard()
        return False


@contextlib.contextmanager
def replacing(path):
    """Yield a temporary name beside ``path`` to write one file; when the block ends without an
    exception it is renamed onto ``path``, otherwise removed (`StagedFiles` for one file)."""
    with StagedFiles() as files:
        yield files.temporary(path)
