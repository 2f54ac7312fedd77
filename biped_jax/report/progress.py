"""The command line's live display: one bar per counted stage, a status line naming the program XLA is
compiling, and a log of every finished count (so that a log piped to a file shows the counts too)."""

from __future__ import annotations

import contextlib
import time

from rich.console import Console

from biped_jax.report import interrupts

console = Console(stderr=True)


def iteration_progress(say, label: str, max_iterations: int):
    """A batched solver's progress callback ``(iteration, row)`` telling ``say`` the iteration, how many of
    the batch's problems have finished (``row["done"]``) and at most how long the stage has left (its
    iterations so far timed, up to ``max_iterations``; each solve of a continuation timed anew)."""
    clock = {"start": time.perf_counter(), "last": -1}

    def report(i, row):
        if i < clock["last"]:  # a new solve (a continuation's next stage): its own clock
            clock["start"] = time.perf_counter()
        clock["last"] = i
        elapsed = time.perf_counter() - clock["start"]
        left = elapsed / max(i, 1) * max(max_iterations - i, 0)
        done = row["done"]
        say(f"{label}: interior-point iteration {i}, {int(sum(bool(d) for d in done))} of {len(done)} finished, "
            f"{elapsed:.0f} s, at most {left:.0f} s left")
    return report


@contextlib.contextmanager
def live_progress(quiet_prefixes: tuple[str, ...] = ()):
    """A live display: a status line (the latest message, or the program being compiled, with the
    elapsed time) and one bar per counted stage (done of all, elapsed, estimated time left). Yields
    ``progress(message, task=None)``; ``task`` = (stage, done, total) moves that stage's bar, and every
    change of a count is logged (so a log piped to a file shows the counts too). Every message that
    does not start with one of ``quiet_prefixes`` (frequent per-iteration lines) is logged as well.
    Program names come from JAX's compile log (:func:`biped_jax.report.compile_profile.profile_compiles`,
    which the command line runs around every command)."""
    started = time.perf_counter()
    bars = _stage_bars()
    status = bars.add_task("starting", total=None)
    stages: dict[str, int] = {}
    latest = ["starting"]

    def show(text: str) -> None:
        bars.update(status, description=f"[{time.perf_counter() - started:5.0f} s] {text}")

    def compiling(name: str | None) -> None:
        show(latest[0] if name is None else f"compiling {name} (XLA; the first run of a program)")

    def progress(message: str, task: tuple[str, int, int] | None = None) -> None:
        interrupts.checkpoint()  # every progress report is a safe point to stop at
        latest[0] = message
        show(message)
        if task is not None:
            stage, done, total = task
            if stage not in stages:  # the stages run one after another: a new one ends those before
                for earlier in stages.values():
                    bars.update(earlier, completed=bars.tasks[earlier].total)
                stages[stage] = bars.add_task(stage, total=total)
            before = bars.tasks[stages[stage]].completed
            bars.update(stages[stage], completed=done, total=total)
            if done != before:
                left = bars.tasks[stages[stage]].time_remaining
                console.log(f"{stage}: {done} of {total} done" + ("" if left is None or done >= total
                                                                  else f", about {left / 60:.1f} min left"))
        if not (quiet_prefixes and message.startswith(quiet_prefixes)):
            console.log(message)

    listeners.append(compiling)
    try:
        with bars:
            yield progress
    finally:
        listeners.remove(compiling)


def _stage_bars():
    """rich's Progress with a status line (no total: description only) and stage bars (bar, done of
    all, elapsed, estimated time left)."""
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        ProgressColumn,
        SpinnerColumn,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )
    from rich.text import Text

    class StageOnly(ProgressColumn):  # a column shown on the stages' bars, not on the status line
        def __init__(self, column):
            self.column = column
            super().__init__()

        def render(self, task):
            return self.column.render(task) if task.total is not None else Text("")

    # the estimate of time left: the pace over the stage so far (problems take minutes, not seconds)
    return Progress(SpinnerColumn(), TextColumn("{task.description}"),
                    *map(StageOnly, (BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(), TextColumn("left"),
                                     TimeRemainingColumn())), console=console, speed_estimate_period=24 * 3600.0)


#: Who hears of compilations (the live display while one is open): see :func:`compile_listener`.
listeners: list = []


def compile_listener(name: str | None) -> None:
    """Tells the open live displays that ``name`` is compiling (None: compiling ended); before and after
    a compilation is a safe point to stop at (:func:`biped_jax.report.interrupts.checkpoint`)."""
    interrupts.checkpoint()
    for listener in listeners:
        listener(name)
