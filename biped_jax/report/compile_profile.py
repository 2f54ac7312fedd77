"""Which programs a command compiles, and how long each took: JAX's own compile log, captured.

JAX reports every backend compilation ("Finished XLA compilation of NAME in T sec", logger
``jax._src.dispatch``) and every hit of the persistent cache ("Persistent compilation cache hit for
'NAME'", logger ``jax._src.compiler``) at DEBUG level. :func:`profile_compiles` listens to both for the
duration of a block, without printing them, so a command can list its distinct programs with their
compile (or cache-load) seconds: the figures the first-result issue asks for.
"""

from __future__ import annotations

import contextlib
import logging
import re

_LOGGERS = ("jax._src.dispatch", "jax._src.compiler", "jax._src.interpreters.pxla")
_STARTED = re.compile(r"Compiling (?P<name>\S+) with global shapes")
_FINISHED = re.compile(r"Finished XLA compilation of (?P<name>.+) in (?P<seconds>[0-9.eE+-]+) sec")
_HIT = re.compile(r"Persistent compilation cache hit for '(?P<name>[^']+)'")


def _key(name: str) -> str:
    """'jit(lagrangian)' and the module name 'jit_lagrangian' name the same program."""
    return re.sub(r"[^0-9a-zA-Z]+", "_", name).strip("_")


class CompileProfile(logging.Handler):
    """The compilations seen: ``events``, one dict per backend compilation (name, seconds, cache "hit"
    when it came from the persistent cache, else "compiled"). ``listener(name)``, when given, hears the
    name of each program as its lowering starts (before the compiler or the cache) and None when it is
    done: what a progress display shows as "compiling"."""

    def __init__(self, listener=None):
        super().__init__(level=logging.DEBUG)
        self.events: list[dict] = []
        self._hits: set[str] = set()  # programs whose cache hit was logged, awaiting their "Finished" line
        self.listener = listener

    def emit(self, record: logging.LogRecord) -> None:
        message = record.getMessage()
        started = _STARTED.search(message)
        if started:
            if self.listener:
                self.listener(started["name"])
            return
        hit = _HIT.search(message)
        if hit:
            self._hits.add(_key(hit["name"]))
            return
        done = _FINISHED.search(message)
        if done:
            key = _key(done["name"])
            cached = key in self._hits
            self._hits.discard(key)
            self.events.append({"name": done["name"], "seconds": float(done["seconds"]),
                                "cache": "hit" if cached else "compiled"})
            if self.listener:
                self.listener(None)

    def summary(self) -> dict:
        """Per distinct program: how often it was compiled or loaded, and the seconds; and the totals."""
        programs: dict[str, dict] = {}
        for event in self.events:
            row = programs.setdefault(event["name"], {"compiled": 0, "hit": 0, "seconds": 0.0})
            row[event["cache"]] += 1
            row["seconds"] += event["seconds"]
        return {"distinct_programs": len(programs), "compilations": len(self.events),
                "seconds": sum(e["seconds"] for e in self.events),
                "seconds_compiled": sum(e["seconds"] for e in self.events if e["cache"] == "compiled"),
                "programs": dict(sorted(programs.items(), key=lambda kv: -kv[1]["seconds"]))}


@contextlib.contextmanager
def profile_compiles(listener=None):
    """Yields a :class:`CompileProfile` that records the block's compilations (nothing is printed;
    ``listener`` as there)."""
    profile = CompileProfile(listener)
    saved = []
    for name in _LOGGERS:
        logger = logging.getLogger(name)
        saved.append((logger, logger.level, logger.propagate))
        logger.setLevel(logging.DEBUG)
        logger.propagate = False  # JAX's own DEBUG lines stay out of the user's terminal
        logger.addHandler(profile)
    try:
        yield profile
    finally:
        for logger, level, propagate in saved:
            logger.removeHandler(profile)
            logger.setLevel(level)
            logger.propagate = propagate
