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


def check_output_folder(folder, error, *, option="-o", writable=False) -> None:
    """Refuse, with one line raised as ``error``, an output folder that is a file; with
    ``writable``, also one this process could not create or write in (its nearest existing
    ancestor is a file, or not writable). Creates nothing: `make_output_folder` does. (A folder
    that holds an earlier run: `mitsonar.cli.common.check_outputs`, the ``--force`` policy.)"""
    folder = os.fspath(folder)
    if os.path.exists(folder) and not os.path.isdir(folder):
        raise error(f"{option} {folder!r} is a file, not a folder")
    if writable:
        parent = os.path.abspath(folder)
        while not os.path.exists(parent):
            parent = os.path.dirname(parent)
        if not os.path.isdir(parent):
            raise error(f"{option} {folder!r}: cannot create the output folder ({parent!r} is a file, not a folder)")
        if not os.access(parent, os.W_OK | os.X_OK):
            raise error(f"{option} {folder!r}: cannot create the output folder ({parent!r}: permission denied)"
                        if parent != os.path.abspath(folder) else
                        f"{option} {folder!r}: cannot write in the output folder (permission denied)")


def make_output_folder(folder, error, option="-o") -> None:
    """Create an output folder (and its parents), or raise ``error`` saying in one line why not
    (it cannot be created, or this process cannot write in it)."""
    try:
        os.makedirs(folder, exist_ok=True)
    except OSError as exc:
        raise error(f"{option} {folder!r}: cannot create the output folder ({exc.strerror})") from None
    if not os.access(folder, os.W_OK):
        raise error(f"{option} {folder!r}: the output folder is not writable")


#: The sentences of `check_output_file`, by problem. Fields: ``path`` (as given), ``folder`` (its
#: absolute folder), ``given_folder`` (its folder as given, ``.`` for none), ``ext`` (its lower-case
#: extension, ``(none)`` without one), ``allowed`` (``.exr or .npz``) and ``allowed_list``
#: (``.exr, .npz``). ``not_a_folder`` None: said as ``no_folder``.
OUTPUT_FILE_WORDS = {
    "directory": "{path}: is a directory; give a file name",
    "extension": "{path}: unknown extension {ext!r}; use {allowed}",
    "exists": "{path}: exists; refusing to overwrite it (use --force)",
    "no_folder": "{path}: folder {folder} does not exist",
    "not_a_folder": None,
    "not_writable": "{path}: folder {folder} is not writable",
}


def check_output_file(path, error, *, extensions=(), force=True, folder_may_be=None, words=None) -> str:
    """Refuse, before any slow work, an output file that cannot be written, in one line raised as
    ``error``: a path that is a folder; an extension not in ``extensions`` (when given; compared
    in lower case); an existing file unless ``force``; a missing folder (unless it is
    ``folder_may_be``, a folder the caller is about to make) or a file where the folder should be;
    a folder this process cannot write in, or an existing file it cannot write. Checked in that
    order. ``words`` replaces sentences
    of `OUTPUT_FILE_WORDS` (a command keeps its own wording). Returns the path as a string.
    Creates nothing: outputs are then written under a temporary name (`StagedFiles`)."""
    path = os.fspath(path)
    say = {**OUTPUT_FILE_WORDS, **(words or {})}
    folder = os.path.dirname(os.path.abspath(path))
    ext = os.path.splitext(path)[1].lower()
    fields = dict(path=path, folder=folder, given_folder=os.path.dirname(path) or ".", ext=ext or "(none)",
                  allowed=" or ".join(extensions), allowed_list=", ".join(extensions))

    def refuse(problem):
        raise error((say[problem] or say["no_folder"]).format(**fields))

    if os.path.isdir(path):
        refuse("directory")
    if extensions and ext not in extensions:
        refuse("extension")
    exists = os.path.exists(path)
    if exists and not force:
        refuse("exists")
    made = folder_may_be is not None and folder == os.path.abspath(os.fspath(folder_may_be))
    if not os.path.isdir(folder):
        if os.path.exists(folder):
            refuse("not_a_folder")
        if made:
            return path
        refuse("no_folder")
    if not os.access(folder, os.W_OK | os.X_OK) or (exists and not os.access(path, os.W_OK)):
        refuse("not_writable")
    return path


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
