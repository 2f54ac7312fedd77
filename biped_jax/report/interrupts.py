"""Ctrl-C and SIGTERM that are never lost: the command line's own signal handlers.

Python turns SIGINT into a KeyboardInterrupt raised wherever the main thread happens to be, and one
raised inside a garbage-collection callback (JAX registers one) is printed as "Exception ignored" and
discarded, so a run could go on to the end and report success. While :func:`handled` is active, a
signal only records the request; :func:`checkpoint`, called at the safe points (between solver
iterations and problems, around every compilation, before every result file, between stages), raises
:class:`Interrupted` there. A second signal of the same run raises at once (for a step that never
reaches a safe point), and the command line checks once more when the command returns, so a request
always ends the run as interrupted.
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading

#: The exit status of a run stopped by each signal (the shell's convention: 128 + the signal number).
EXIT_STATUS = {signal.SIGINT: 130, signal.SIGTERM: 143}
#: What the manifest and the last line say of each.
REASON = {signal.SIGINT: "interrupted by the user (Ctrl-C)", signal.SIGTERM: "terminated (SIGTERM)"}

_requested: list[int] = []  # the signals received while :func:`handled` is active, oldest first


class Interrupted(KeyboardInterrupt):
    """A run stopped at a safe point by SIGINT or SIGTERM (``signal_number``)."""

    def __init__(self, signal_number: int):
        super().__init__(REASON[signal_number])
        self.signal_number = signal_number


def requested() -> int | None:
    """The first signal received and not yet acted on (None when there is none)."""
    return _requested[0] if _requested else None


def checkpoint() -> None:
    """A safe point: raises :class:`Interrupted` if a stop was requested."""
    if _requested:
        raise Interrupted(_requested[0])


def _handler(number, frame) -> None:
    first = not _requested
    _requested.append(number)
    if first:  # os.write: the only output that is safe inside a signal handler
        os.write(2, b"\nstopping at the next safe point (between iterations, programs or files); "
                    b"press Ctrl-C again to stop at once\n")
        return
    raise Interrupted(_requested[0])


@contextlib.contextmanager
def handled():
    """SIGINT and SIGTERM recorded (not raised) for the block, the earlier handlers restored after.
    Outside the main thread (where Python allows no handlers) the block runs with the defaults."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    saved = {number: signal.signal(number, _handler) for number in EXIT_STATUS}
    _requested.clear()
    try:
        yield
    finally:
        for number, handler in saved.items():
            signal.signal(number, handler)
        _requested.clear()
