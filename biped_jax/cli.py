"""The ``biped-jax`` command line.

``biped-jax reproduce --out DIR`` runs the paper's study (optimal steps of M1-M4, the 20 W question,
the smallest feasible power limits) and writes tables (markdown), figures (PNG) and ``results.json``
into DIR. ``biped-jax kelly --out DIR`` solves Kelly's five-link biped benchmark with the same optimiser
and writes ``kelly.json``. ``biped-jax donald`` walks DONALD in MJX,
``biped-jax humanoid`` replays the optimal gait on the 16-DoF humanoid under contact,
``biped-jax codesign`` co-designs gear ratios, windings and masses with the gait.
``biped-jax step`` simulates one heuristic PD-controlled step, ``biped-jax models`` lists
the robots and ``biped-jax view NAME`` opens one in MuJoCo's viewer.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
import time
from pathlib import Path

import numpy as np
from rich.console import Console

from biped_jax import checks, outputs

console = Console(stderr=True)

#: ``biped_jax.gait.DYNAMICS``, written out so that ``--help`` does not import JAX (a test keeps them equal).
DYNAMICS = ("chain", "mjx")
DYNAMICS_HELP = ("single-support dynamics of the gait rollout: MJX's pipeline, or the closed-form planar "
                 "chain (equal to MJX's to rounding, several times faster)")


def configure_jax(cache_dir: str | None = None) -> None:
    """float64 and the persistent compilation cache (set by the entry point, never on import)."""
    import jax
    jax.config.update("jax_enable_x64", True)
    cache = cache_dir or os.environ.get("BIPED_JAX_CACHE",
                                        str(Path.home() / ".cache" / "biped_jax" / "jax"))
    jax.config.update("jax_compilation_cache_dir", cache)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)


@contextlib.contextmanager
def live_progress(quiet_prefixes: tuple[str, ...] = ()):
    """A live display: a status line (the latest message, or the program being compiled, with the
    elapsed time) and one bar per counted stage (done of all, elapsed, estimated time left). Yields
    ``progress(message, task=None)``; ``task`` = (stage, done, total) moves that stage's bar, and every
    change of a count is logged (so a log piped to a file shows the counts too). Every message that
    does not start with one of ``quiet_prefixes`` (frequent per-iteration lines) is logged as well.
    Program names come from JAX's compile log (:func:`biped_jax.compile_profile.profile_compiles`,
    which the command line runs around every command)."""
    from rich.progress import (BarColumn, MofNCompleteColumn, Progress, ProgressColumn, SpinnerColumn,
                               TextColumn, TimeElapsedColumn, TimeRemainingColumn)
    from rich.text import Text

    class StageOnly(ProgressColumn):  # a column shown on the stages' bars, not on the status line
        def __init__(self, column):
            self.column = column
            super().__init__()

        def render(self, task):
            return self.column.render(task) if task.total is not None else Text("")

    started = time.perf_counter()
    # the estimate of time left: the pace over the stage so far (problems take minutes, not seconds)
    bars = Progress(SpinnerColumn(), TextColumn("{task.description}"),
                    *map(StageOnly, (BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(), TextColumn("left"),
                                     TimeRemainingColumn())), console=console, speed_estimate_period=24 * 3600.0)
    status = bars.add_task("starting", total=None)
    stages: dict[str, int] = {}
    latest = ["starting"]

    def show(text: str) -> None:
        bars.update(status, description=f"[{time.perf_counter() - started:5.0f} s] {text}")

    def compiling(name: str | None) -> None:
        show(latest[0] if name is None else f"compiling {name} (XLA; the first run of a program)")

    def progress(message: str, task: tuple[str, int, int] | None = None) -> None:
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


#: Who hears of compilations (the live display while one is open): see :func:`_compile_listener`.
listeners: list = []


def _compile_listener(name: str | None) -> None:
    for listener in listeners:
        listener(name)


def heuristic_steps(out: Path) -> dict:
    """One heuristic PD-controlled step per mass class, reported; see :mod:`biped_jax.step_study`."""
    from biped_jax import step_study
    from biped_jax.heuristic_step import HeuristicGait

    out.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    summaries, arrays = [], {}
    for mass_class in step_study.MASS_CLASSES:
        with console.status(f"simulating a heuristic step of the {mass_class} biped "
                            "(the first run compiles, about a minute)"):
            summary, arrays[mass_class] = step_study.step_report(mass_class, HeuristicGait())
        summaries.append(summary)
        console.print(f"[green]done[/] {mass_class}: touched down = {summary['touched_down']}")
    results = step_study.write_report(out, summaries, arrays, time.perf_counter() - started)
    console.print(f"wrote {out / 'results.json'}, {out / 'heuristic_step.md'}, {out / 'heuristic_step.png'}")
    return results


def reproduce(out: Path, settings, resume: bool = False, method: str = "sqp", quick: bool = False) -> dict:
    """The paper's study with a live progress display; see :func:`biped_jax.study.run_study`. ``quick``:
    the coarse look of :data:`biped_jax.study.QUICK_SETTINGS` (``settings`` ignored), every file stamped."""
    from biped_jax import study

    started = time.perf_counter()
    stamp = outputs.stamped(study.QUICK_STAMP) if quick else contextlib.nullcontext()
    with live_progress(("M1-M4", "20 W:", "restart:", "smallest power limit")) as progress, stamp:
        if quick:
            console.log(study.QUICK_STAMP)
            results = study.run_study(out, study.QUICK_SETTINGS, progress, resume=resume, method=method,
                                      families=study.QUICK_FAMILIES)
        else:
            results = study.run_study(out, settings, progress, resume=resume, method=method)
    for record in results["models"]:
        check = record["refinement"]
        console.print(f"{record['model']}: {record['status']}, J = {record['cost']:.4g} ({check['cost']:.4g} on "
                      f"{check['steps']} steps), largest violation {record['max_violation']:.1e}, smallest feasible "
                      f"M_W " + ("-" if record["min_power_limit_W"] is None else f"{record['min_power_limit_W']:.3f} W")
                      + f" ({record['min_power_status']})")
    console.print(f"wrote {out}/results.json, tables.md, fig2_trajectories.png, fig3_torque_rpm.png, "
                  f"convergence.png in {time.perf_counter() - started:.0f} s")
    return results


def kelly(out: Path, spans: int, degree: int, substeps: int) -> dict:
    """Kelly's benchmark with a live progress line; see :func:`biped_jax.kelly.run_kelly`."""
    import dataclasses

    from biped_jax import kelly as benchmark

    settings = dataclasses.replace(benchmark.KELLY_SETTINGS, spans=spans, degree=degree, substeps=substeps)
    started = time.perf_counter()
    with live_progress(("outer iteration",)) as progress:
        record = benchmark.run_kelly(out, settings, progress)
    console.print(f"Kelly's five-link biped: {record['status']}, J = {record['cost']:.4g} N^2 m^2 s on "
                  f"{record['steps']} Runge-Kutta steps ({record['cost_coarse']:.4g} on {record['steps_coarse']}, "
                  f"{record['cost_refined']:.4g} on {record['steps_refined']}), largest violation "
                  f"{record['max_violation']:.1e}; active: {', '.join(record['active_constraints'])}")
    console.print(f"wrote {out}/kelly.json, kelly_step.png in {time.perf_counter() - started:.0f} s")
    return record


def donald_walk(out: Path, steps: int, faster: bool = False, resume: bool = False) -> dict:
    """DONALD's walk (or the optimised one); see :mod:`biped_jax.donald_study`."""
    from biped_jax import donald_study

    started = time.perf_counter()
    with live_progress() as progress:
        if faster:
            report = donald_study.run_faster(out, steps, progress, resume=resume)
        else:
            report = donald_study.run_donald(out, steps, progress)
    if faster:
        result = report["optimisation"]
        console.print(f"optimiser: {result['status']}, speed over steps 2-3 {result['default_speed_mps']:.4f} -> "
                      f"{result['speed_mps']:.4f} m/s, largest scaled violation {result['max_scaled_violation']:.1e}")
        chosen = report["candidates"][report["chosen_candidate"]]
        console.print(f"walked with the full contact solver: {sum(c['verified'] for c in report['candidates'])} of "
                      f"{len(report['candidates'])} candidates verified (margin >= "
                      f"{1e3 * donald_study.VERIFIED_MARGIN:.0f} mm, no fall); chosen: "
                      + ("the default gait" if report["chosen_candidate"] == 0
                         else f"outer iterate {report['chosen_candidate']}")
                      + f", {chosen['speed_mps']:.4f} m/s ({report['speed_gain_mps']:+.4f} m/s over the default)")
    verdict = "fell" if report["fell"] else "did not fall"
    console.print(f"DONALD: {report['steps']} touchdowns, {report['distance_m']:.3f} m forward at "
                  f"{report['speed_mps']:.4f} m/s, {verdict}; smallest static-stability margin in single "
                  f"support {1e3 * report['min_support_margin_m']:.1f} mm")
    name = "donald_faster" if faster else "donald"
    console.print(f"wrote {out}/{name}.json, {name}_walk.png, {name}_torque_speed.png, {name}_replay.npz "
                  f"in {time.perf_counter() - started:.0f} s")
    return report


def humanoid_walk(out: Path, model: str, steps: int, settings, gaits: Path | None) -> dict:
    """The optimal gait replayed on the humanoid; see :mod:`biped_jax.humanoid_study`."""
    from biped_jax import humanoid_study

    started = time.perf_counter()
    with live_progress(("humanoid: t =", f"{model}: outer")) as progress:
        report = humanoid_study.run_humanoid(out, model, steps, settings, gaits, progress)
    verdict = "fell" if report["fell"] else "did not fall"
    errors = report["tracking_error_rad"]
    console.print(f"humanoid ({report['mass_class']}) replaying {model}: {report['steps']} touchdowns, "
                  f"{report['distance_m']:.3f} m at {report['speed_mps']:.3f} m/s (gait: "
                  f"{report['gait_speed_mps']:.3f}), {verdict}; joint tracking error RMS "
                  f"{1e3 * errors['rms']:.1f} mrad, max {1e3 * errors['max']:.1f} mrad outside impacts")
    touchdowns = report["touchdowns"]
    if touchdowns:
        impulse, jump = (np.median([t[key] for t in touchdowns])
                         for key in ("impulse_relative_error", "velocity_jump_relative_error"))
        rebounds = sum(t["replay_rebound"] for t in touchdowns)
        console.print(f"touchdowns isolated from the controller against the impact map (medians): impulse error "
                      f"{impulse:.0%}, velocity-jump error {jump:.0%}; in the replay the landing foot rebounded "
                      f"at {rebounds} of {len(touchdowns)}")
    console.print(f"wrote {out}/humanoid.json, humanoid_walk.png, humanoid_tracking.png, humanoid_torque_speed.png, "
                  f"humanoid_replay.npz in {time.perf_counter() - started:.0f} s")
    return report


def codesign(out: Path, settings, iterations: int, resume: bool = False, solver: str = "sqp") -> dict:
    """The co-design studies; see :mod:`biped_jax.codesign_study`."""
    from biped_jax import codesign_study

    started = time.perf_counter()
    with live_progress() as progress:
        results = codesign_study.run_codesign(out, settings, iterations, progress, resume=resume,
                                               solver_name=solver)
    for speed, fit in results["mass_scaling"]["fits"].items():
        console.print(f"(a) {speed} m/s: peak joint power ~ M^{fit['peak_power_exponent']:.2f}, Joule energy per "
                      f"metre ~ M^{fit['joule_per_metre_exponent']:.2f} ({fit['converged']} of 8 masses converged)")
    limits = results["speed_limits"]
    best = int(np.argmax(np.nan_to_num(limits["max_speed_mps"], nan=-1.0)))
    console.print(f"(b) fastest: {limits['max_speed_mps'][best]:.3f} m/s with {limits['gearheads'][best]}")
    front = [results["pareto"]["designs"][i] for i in results["pareto"]["pareto"]]
    console.print("(c) Pareto front: " + ", ".join(
        f"{r['winding']} + {r['gearhead']} ({r['total_mass_kg']:.2f} kg, {r['joule_energy_per_metre_J_per_m']:.3g} J/m)"
        for r in front))
    optimum = results["co_optimisation"]
    if optimum["best"] is None:
        console.print("(d) no snapped design has a converged gait")
    else:
        record = optimum["snapped"][optimum["best"]]
        console.print(f"(d) best snapped design: {', '.join(record['gearheads'])}: {record['status']}, "
                      f"{record['joule_energy_J']:.4g} J per step")
    console.print(f"wrote {out}/codesign.json and four figures in {time.perf_counter() - started:.0f} s")
    return results


def _integer(name: str, low: int, high: int):
    """An argparse type: an integer in [low, high] (the subcommand's usage names a bad one)."""
    def parse(text: str) -> int:
        try:
            return checks.integer_in(f"--{name}", int(text), low, high)
        except ValueError:
            raise argparse.ArgumentTypeError(f"--{name} must be an integer in [{low}, {high}], got {text!r}") from None
    return parse


def _substeps(text: str) -> int:
    value = _integer("substeps", *checks.GAIT_INTEGER_RANGES["substeps"])(text)
    if value % 2:
        raise argparse.ArgumentTypeError(f"--substeps must be even (Simpson's rule pairs the steps), got {value}")
    return value


def _output_folder(text: str) -> Path:
    """An argparse type: a folder that can be written (checked before any computing; created later)."""
    try:
        return outputs.check_output_dir(Path(text))
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def _input_folder(text: str) -> Path:
    path = Path(text)
    if not path.is_dir():
        fault = "is not a folder" if path.exists() else "does not exist"
        raise argparse.ArgumentTypeError(f"--gaits {text}: {fault}")
    return path


def _out_argument(parser) -> None:
    parser.add_argument("--out", type=_output_folder, default=Path("out"), help="output folder (default: out/)")
    parser.add_argument("--profile-compile", action="store_true",
                        help="list every program JAX compiles (or loads from its cache) with its seconds, "
                             "in OUT/compile_profile.json and a summary at the end")


def _space_arguments(parser, when: str = "", substeps: int = 8, segments: bool = False, spans: int = 16) -> None:
    """The gait problem's reference space and grid (``biped_jax.gait.GaitSettings``); ``segments``
    adds --segments (default: one per knot span)."""
    ranges = checks.GAIT_INTEGER_RANGES
    parser.add_argument("--spans", type=_integer("spans", *ranges["spans"]), default=spans,
                        help=f"knot spans of the joint B-splines{when}, {ranges['spans'][0]}-{ranges['spans'][1]} "
                             f"(default {spans})")
    parser.add_argument("--degree", type=_integer("degree", *ranges["degree"]), default=3,
                        help=f"B-spline degree{when}, {ranges['degree'][0]}-{ranges['degree'][1]} (default 3)")
    parser.add_argument("--substeps", type=_substeps, default=substeps,
                        help=f"Runge-Kutta steps per knot span, even{when} (default {substeps})")
    if segments:
        parser.add_argument("--segments", type=_integer("segments", 1, ranges["spans"][1]), default=None,
                            help="shooting segments of the stance angle, dividing --spans (1: single shooting; "
                                 "default: one per knot span)")


#: ``study.STUDY_SETTINGS``' knot spans and steps per span, the defaults of ``reproduce`` (written here:
#: the parser imports no JAX; tests/test_cli.py checks they agree).
STUDY_SPANS, STUDY_SUBSTEPS = 48, 4


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="biped-jax", description=__doc__.splitlines()[0])
    commands = parser.add_subparsers(dest="command", required=True)
    run = commands.add_parser("reproduce", help="run the paper's study and write results")
    _out_argument(run)
    _space_arguments(run, substeps=STUDY_SUBSTEPS, segments=True, spans=STUDY_SPANS)
    run.add_argument("--quick", action="store_true",
                     help="a coarse first look in a few minutes (8 knot spans, 3 start families; overrides "
                          "--spans/--substeps/--segments); every file it writes says so")
    run.add_argument("--solver", choices=("sqp", "al"), default="sqp",
                     help="sqp: SLSQP from every start family (default); al: the batched augmented Lagrangian")
    run.add_argument("--dynamics", choices=DYNAMICS, default="chain", help=DYNAMICS_HELP + " (default chain)")
    run.add_argument("--resume", action="store_true",
                     help="continue an interrupted study in --out from its finished stages (OUT/stages)")
    bench = commands.add_parser("kelly", help="solve Kelly's five-link biped benchmark (SIAM Review 2017)")
    _out_argument(bench)
    _space_arguments(bench)
    walker = commands.add_parser("donald", help="DONALD's statically stable walk in MJX (figures, JSON)")
    _out_argument(walker)
    walker.add_argument("--steps", type=_integer("steps", 1, 1000), default=8, help="steps to walk, 1-1000 (default 8)")
    walker.add_argument("--faster", action="store_true",
                        help="first optimise the gait for speed (tens of minutes), then walk the optimum")
    walker.add_argument("--resume", action="store_true",
                        help="with --faster: continue from the finished optimisation in --out (OUT/stages)")
    replay = commands.add_parser("humanoid", help="the optimal sagittal gait replayed on the 16-DoF humanoid "
                                 "under contact in MJX (figures, JSON; it walks slower than the gait, see "
                                 "README)")
    _out_argument(replay)
    replay.add_argument("--model", default="M2", choices=("M1", "M2", "M3", "M4"),
                        help="which of the paper's models (default M2)")
    replay.add_argument("--steps", type=_integer("steps", 1, 1000), default=10,
                        help="steps to walk, 1-1000 (default 10)")
    replay.add_argument("--gaits", type=_input_folder, default=None,
                        help="folder with results.json from `biped-jax reproduce` (default: solve the model here)")
    _space_arguments(replay, " when solving here")
    design = commands.add_parser("codesign", help="co-design studies: gear ratios, windings and masses with "
                                 "the gait (figures, JSON; tens of minutes)")
    _out_argument(design)
    _space_arguments(design)
    design.add_argument("--iterations", type=_integer("iterations", 1, 1000), default=5,
                        help="co-optimisation iterations, 1-1000 (default 5)")
    design.add_argument("--dynamics", choices=DYNAMICS, default="chain", help=DYNAMICS_HELP + " (default chain)")
    design.add_argument("--solver", choices=("sqp", "al"), default="sqp",
                        help="sqp: SLSQP, one design after another (default); al: the batched augmented Lagrangian")
    design.add_argument("--resume", action="store_true",
                        help="continue interrupted studies in --out from their finished parts (OUT/stages)")
    drive = commands.add_parser("drives", help="drive-train selection (Table 6, Figs. 4-5) from solved gaits")
    _out_argument(drive)
    drive.add_argument("--gaits", type=_input_folder, default=None,
                       help="folder with trajectories.npz from `biped-jax reproduce` (default: --out)")
    step = commands.add_parser("step", help="simulate one heuristic PD-controlled step per mass class")
    _out_argument(step)
    commands.add_parser("models", help="list the robot models")
    view = commands.add_parser("view", help="open a model in MuJoCo's viewer (needs a display)")
    view.add_argument("name")
    view.add_argument("--replay", type=Path, default=None,
                      help="an .npz with t and qpos (e.g. out/donald_replay.npz) to play back")
    for name, sub in commands.choices.items():
        sub.set_defaults(parser=sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """The command line; returns the exit status (130 after Ctrl-C, with one line saying so)."""
    args = _parser().parse_args(argv)
    if args.command == "donald" and args.resume and not args.faster:
        args.parser.error("--resume continues the --faster optimisation; give both or neither")
    if not hasattr(args, "out"):
        return _run(args)
    try:
        with outputs.run_manifest(args.out, ["biped-jax"] + (sys.argv[1:] if argv is None else list(argv)),
                                  resume=getattr(args, "resume", False)):
            with _user_stream():
                from biped_jax.compile_profile import profile_compiles
                with profile_compiles(_compile_listener) as profile:  # names what is compiling
                    status = _run(args)
                if args.profile_compile:
                    _report_compiles(profile.summary(), args.out)
                return status
    except KeyboardInterrupt:
        listed = outputs.read_manifest(args.out)
        kept = ", ".join(listed["files"]) if listed and listed["files"] else "nothing"
        hint = ""
        if listed and any(name.startswith("stages/") for name in listed["files"]):
            hint = "; the same command with --resume continues from the finished stages"
        console.print(f"interrupted: finished and kept in {args.out}: {kept} (see {args.out / outputs.MANIFEST})"
                      + hint)
        return 130


@contextlib.contextmanager
def _user_stream():
    """XLA's slow-compile alarm filtered out of standard error (:mod:`biped_jax.xla_alarm`), the
    console writing to the real terminal meanwhile (so the live progress line still shows)."""
    from biped_jax.xla_alarm import quiet_compile_alarm
    with quiet_compile_alarm() as stream:
        if stream is sys.stderr:  # nothing filtered (e.g. a test runner captures standard error)
            yield
            return
        console.file = stream
        try:
            yield
        finally:
            console.file = None  # back to whatever sys.stderr is (rich resolves it at each write)


def _report_compiles(summary: dict, out: Path) -> None:
    outputs.write_json(out / "compile_profile.json", summary)
    console.print(f"compiled {summary['compilations']} times, {summary['distinct_programs']} distinct programs, "
                  f"{summary['seconds']:.0f} s ({summary['seconds_compiled']:.0f} s not from the cache); "
                  f"largest: " + ", ".join(f"{name} {row['seconds']:.0f} s"
                                           for name, row in list(summary["programs"].items())[:5])
                  + f" (all in {out / 'compile_profile.json'})")


def _run(args) -> int:
    parser = args.parser
    from biped_jax import robots
    if args.command == "models":
        for name, (file_name, description) in robots.ROBOTS.items():
            print(f"{name:28s} {description}  [{robots.models_dir() / file_name}]")
        return 0
    if args.command == "view":
        try:
            model = robots.load_mj_model(args.name)
            replay = None if args.replay is None else load_replay(args.replay)
        except ValueError as error:
            parser.error(str(error))
        if replay is not None and replay["qpos"].shape[1] != model.nq:
            parser.error(f"--replay {args.replay}: qpos has {replay['qpos'].shape[1]} columns, "
                         f"{args.name} has {model.nq} coordinates")
        import mujoco.viewer
        if replay is None:
            mujoco.viewer.launch(model)
            return 0
        data = mujoco.MjData(model)
        with mujoco.viewer.launch_passive(model, data) as viewer:
            for t, qpos in zip(np.diff(replay["t"], prepend=0.0), replay["qpos"]):
                data.qpos[:] = qpos
                mujoco.mj_forward(model, data)
                viewer.sync()
                time.sleep(float(t))
        return 0
    if args.command == "drives":
        from biped_jax import drive_selection
        source = (args.gaits or args.out) / "trajectories.npz"
        if not source.is_file():
            parser.error(f"no gait trajectories at {source}: run `biped-jax reproduce --out "
                         f"{args.gaits or args.out}` first")
        try:
            workspaces = drive_selection.load_workspaces(source)
        except ValueError as error:
            parser.error(str(error))
        drive_selection.run_drive_study(args.out, workspaces)
        console.print(f"wrote into {args.out}: " + ", ".join(outputs.read_manifest(args.out)["files"]))
        return 0
    configure_jax()
    if args.command == "step":
        heuristic_steps(args.out)
        return 0
    settings = None
    if hasattr(args, "spans"):
        from biped_jax.gait import GaitSettings
        try:
            settings = GaitSettings(spans=args.spans, degree=args.degree, substeps=args.substeps,
                                    dynamics=getattr(args, "dynamics", "chain"),
                                    segments=getattr(args, "segments", 1) or args.spans)
        except ValueError as error:
            parser.error(str(error))
    if args.command == "kelly":
        kelly(args.out, args.spans, args.degree, args.substeps)
        return 0
    if args.command == "donald":
        donald_walk(args.out, args.steps, args.faster, args.resume)
        return 0
    if args.command == "humanoid":
        try:
            humanoid_walk(args.out, args.model, args.steps, settings, args.gaits)
        except (ValueError, FileNotFoundError) as error:
            parser.error(str(error))
        return 0
    if args.command == "codesign":
        codesign(args.out, settings, args.iterations, args.resume, args.solver)
        return 0
    reproduce(args.out, settings, args.resume, args.solver, args.quick)
    return 0


def load_replay(path: Path) -> dict:
    """``t`` (T,) and ``qpos`` (T, nq) from a replay ``.npz``; ValueError naming the file and the fault."""
    if not path.is_file():
        raise ValueError(f"--replay {path}: " + ("is not a file" if path.exists() else "does not exist"))
    try:
        stored = outputs.read_npz(path)
    except ValueError as error:
        raise ValueError(f"--replay {path}: {error}") from None
    missing = [key for key in ("t", "qpos") if key not in stored]
    if missing:
        raise ValueError(f"--replay {path}: no array {', '.join(missing)} (needs t and qpos)")
    arrays = {key: np.asarray(stored[key], dtype=float) for key in ("t", "qpos")}
    if arrays["t"].ndim != 1 or arrays["qpos"].ndim != 2 or len(arrays["t"]) != len(arrays["qpos"]) \
            or not len(arrays["t"]):
        raise ValueError(f"--replay {path}: needs t (T,) and qpos (T, nq) with T > 0, got shapes "
                         f"{arrays['t'].shape} and {arrays['qpos'].shape}")
    if not (np.all(np.isfinite(arrays["t"])) and np.all(np.isfinite(arrays["qpos"]))):
        raise ValueError(f"--replay {path}: contains NaN or infinite values")
    return arrays


if __name__ == "__main__":
    sys.exit(main())
