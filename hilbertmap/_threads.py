"""Long native calls that a Ctrl-C must not wait for, or break.

A LAPACK call (the Gram matrix's eigen-decomposition: seconds at 3000 inducing points, minutes at
10000) releases the GIL but returns to Python only when done, so a KeyboardInterrupt in the thread
that made it acts only then. A SciPy k-d tree query with ``workers=-1`` joins its own threads: a
KeyboardInterrupt there unwinds the query while they still run on its buffers, and the process
crashes (SIGSEGV) on its way out. `interruptible` runs such a call in a worker thread and waits
for it: the main thread takes the interrupt at once, the call goes on undisturbed in the
background (a daemon thread: it does not keep the process alive) and its result is dropped.

A process that means to exit while such a call still runs (`abandoned` says how many) should
leave with ``os._exit``: OpenBLAS's exit handler joins its own threads, and with a call cut off
in the middle by the interpreter's shutdown it can wait forever.
"""
from __future__ import annotations

import threading

__all__ = ["interruptible", "abandoned"]

_abandoned: list = []       # workers whose caller was interrupted


def interruptible(fn, *args, **kwargs):
    """``fn(*args, **kwargs)`` run in a daemon thread while the calling thread waits (module doc);
    its result, or its exception raised here."""
    out = {}

    def run():
        try:
            out["value"] = fn(*args, **kwargs)
        except BaseException as exc:  # handed to the waiting thread
            out["error"] = exc

    worker = threading.Thread(target=run, name="hilbertmap-worker", daemon=True)
    worker.start()
    try:
        while worker.is_alive():
            worker.join(0.1)
    except BaseException:       # KeyboardInterrupt: the call goes on without a caller
        _abandoned.append(worker)
        raise
    if "error" in out:
        raise out["error"]
    return out["value"]


def abandoned() -> int:
    """How many calls `interruptible` gave up waiting for (a KeyboardInterrupt) still run."""
    _abandoned[:] = [w for w in _abandoned if w.is_alive()]
    return len(_abandoned)
