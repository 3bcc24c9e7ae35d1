"""Worker processes that end with the process that started them.

`generate_dataset`'s local workers are spawned processes waiting on a queue. When the coordinator
is killed (SIGKILL: no ``finally``, no pool shutdown), nothing tells them: they kept waiting, and
so did the multiprocessing resource tracker, which ends only once every process holding its pipe
has ended. A worker calls `die_with_parent` first thing, and then:

* on Linux the kernel sends it SIGKILL when its parent ends (``prctl(PR_SET_PDEATHSIG)``; the
  parent here is the thread that started the worker: the coordinator's, which outlives its pool);
* on any POSIX system a daemon thread sees ``os.getppid()`` change (the orphan is adopted by
  init or a subreaper) within `PARENT_CHECK_S` and ends the process.

A worker writes nothing into the dataset folder (the coordinator alone does, renaming whole
files into place), so ending it abruptly loses nothing: a resumed run renders what is missing.
"""
from __future__ import annotations

import os
import signal
import sys
import threading
import time

PARENT_CHECK_S = 0.5   # how often the watchdog thread looks at os.getppid()
PR_SET_PDEATHSIG = 1   # <linux/prctl.h>


def _parent_death_signal(sig) -> bool:
    """Ask Linux to send ``sig`` to this process when its parent ends; False where it cannot."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        return libc.prctl(PR_SET_PDEATHSIG, int(sig), 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def die_with_parent(parent_pid: int) -> None:
    """End this process (exit status 1, no cleanup) as soon as ``parent_pid`` is no longer its
    parent: at once if that already happened, else by the parent-death signal and the watchdog
    thread described in the module docstring."""
    _parent_death_signal(signal.SIGKILL)
    if os.getppid() != parent_pid:   # the parent ended before the signal was asked for
        os._exit(1)

    def watch():
        while os.getppid() == parent_pid:
            time.sleep(PARENT_CHECK_S)
        os._exit(1)

    threading.Thread(target=watch, name="mitsonar-parent-watchdog", daemon=True).start()
