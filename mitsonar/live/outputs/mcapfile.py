"""An MCAP recording of a live session (``mitsonar live --mcap FILE``): the channels of
`mitsonar.live.outputs.foxglove.FoxgloveChannels` written by foxglove-sdk's MCAP writer,
under a temporary name beside ``FILE`` (`mitsonar._files.StagedFiles`) renamed onto it when
the session closes (SIGINT, SIGTERM, ``--seconds``: the file is complete and readable); a
session that fails to start removes it (`discard`). A process killed outright (SIGKILL) leaves the
temporary ``.NAME.*.partial.mcap``, without its summary.
"""
from __future__ import annotations

from mitsonar._files import StagedFiles, check_output_file
from mitsonar.live.outputs.base import OutputError
from mitsonar.live.outputs.foxglove import FoxgloveChannels, require_foxglove
from mitsonar.live.outputs.pictures import Pictures

__all__ = ["McapRecording", "check_mcap_path"]

_WORDS = {"directory": "--mcap {path}: is a folder; give an .mcap file name",
          "extension": "--mcap {path}: the file name must end in .mcap",
          "exists": "--mcap {path}: exists; --force to overwrite",
          "no_folder": "--mcap {path}: the folder {folder} does not exist",
          "not_writable": "--mcap {path}: the folder {folder} is not writable"}


def check_mcap_path(path, force=False) -> str:
    """``path`` as a string, or `OutputError` (one line) if it cannot be the recording: a folder,
    not ``.mcap``, an existing file (unless ``force``), a missing or read-only folder; or
    foxglove-sdk missing."""
    require_foxglove("--mcap")
    return check_output_file(path, OutputError, extensions=(".mcap",), force=force, words=_WORDS)


class McapRecording(FoxgloveChannels):
    """The live channels recorded into ``path`` (module doc); `close` puts the file in place,
    `discard` removes it. ``count``: pings recorded."""

    def __init__(self, path, pictures: Pictures | None = None, force=False):
        self.path = check_mcap_path(path, force)
        super().__init__(pictures, flag="--mcap")
        self._staged = StagedFiles()
        tmp = self._staged.temporary(self.path)
        try:
            self.writer = self._fg.open_mcap(tmp, allow_overwrite=True, context=self.context)
        except Exception as e:           # noqa: BLE001
            self._staged.discard()
            raise OutputError(f"--mcap {self.path}: cannot write ({e})") from None

    def close(self) -> None:
        try:
            self.writer.close()
        except BaseException:
            self._staged.discard()        # a recording that could not be finished leaves no file
            raise
        self._staged.commit()

    def discard(self) -> None:
        try:
            self.writer.close()
        finally:
            self._staged.discard()
