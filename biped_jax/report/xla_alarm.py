"""Keeps XLA's "Very slow compile?" alarm out of the user's way, and nothing else.

XLA's C++ runtime writes, to the process's standard error, a block of asterisks saying "Very slow
compile? If you want to file a bug, run with envvar XLA_FLAGS=--xla_dump_to=/tmp/foo" whenever one
compilation takes more than a couple of minutes, which on a 2-core CPU the gait programs do the first
time (they are cached after). XLA has no switch for it (openxla/xla#9828). :func:`quiet_compile_alarm`
passes standard error through a filter that replaces each such block by one line saying what it means,
and lets every other line through unchanged.
"""

from __future__ import annotations

import contextlib
import os
import re
import sys
import threading

_ALARM = re.compile(r"slow_operation_alarm|Very slow compile\?|^\*{8,}\s*$|^\s*$")
_EXPLAINED = ("(a compilation is taking minutes: normal for the gait programs on a small CPU the first "
              "time; JAX caches them for the next run)\n")


def is_alarm_line(line: str) -> bool:
    """True for the lines of XLA's slow-compile alarm block (and the blank lines inside it)."""
    return bool(_ALARM.search(line))


def filter_lines(lines, write) -> None:
    """Copies ``lines`` to ``write``, each alarm block replaced by one explanation (once per block)."""
    in_block = False
    for line in lines:
        if "slow_operation_alarm" in line or "Very slow compile?" in line:
            if not in_block:
                write(_EXPLAINED)
            in_block = True
            continue
        if in_block and is_alarm_line(line):
            continue
        in_block = False
        write(line)


@contextlib.contextmanager
def quiet_compile_alarm():
    """Filters file descriptor 2 for the block (see the module). A no-op where standard error is not
    the process's descriptor 2 (e.g. captured by a test runner). Yields the stream to write user
    messages to (the original standard error)."""
    try:
        if sys.stderr.fileno() != 2:
            raise ValueError
    except (AttributeError, ValueError, OSError):
        yield sys.stderr
        return
    sys.stderr.flush()
    original = os.dup(2)
    reader, writer = os.pipe()
    os.dup2(writer, 2)
    os.close(writer)
    out = os.fdopen(os.dup(original), "w", buffering=1)

    def pump():
        with os.fdopen(reader, "r", errors="replace") as source:
            filter_lines(source, lambda text: (out.write(text), out.flush()))
    thread = threading.Thread(target=pump, daemon=True)
    thread.start()
    try:
        yield out
    finally:
        sys.stderr.flush()
        os.dup2(original, 2)  # closes the pipe's last write end: the pump sees the end and stops
        os.close(original)
        thread.join(timeout=5)
        out.flush()
