"""The ``biped-jax`` command line.

``biped-jax reproduce --out DIR`` runs the paper's study (optimal steps of M1-M4, the 20 W question,
the smallest feasible power limits) and writes tables (markdown), figures (PNG) and ``results.json``
into DIR; ``biped-jax solve`` does the same for one problem of the user's own. ``biped-jax kelly --out
DIR`` solves Kelly's five-link biped benchmark with the same optimiser and writes ``kelly.json``.
``biped-jax library`` solves optimal gaits over speeds and step lengths, ``biped-jax top-speed`` the
fastest gaits under power limits and on catalogue drives. ``biped-jax donald`` walks DONALD in MJX,
``biped-jax humanoid`` replays the optimal gait on the 16-DoF humanoid under contact and walks it in 3D
with its drives in the loop, ``biped-jax
codesign`` co-optimises gear ratios and the link masses' split with the gait and compares windings and
total masses. ``biped-jax step`` simulates one heuristic PD-controlled step, ``biped-jax models`` lists
the robots and ``biped-jax view NAME`` opens one in MuJoCo's viewer.
"""

from __future__ import annotations

import argparse
import contextlib
import signal
import sys
from pathlib import Path

from biped_jax import checks, commands
from biped_jax.report import interrupts, outputs
from biped_jax.report.progress import compile_listener, console

#: ``biped_jax.gait.problem.DYNAMICS``, written out so that ``--help`` does not import JAX (a test keeps them equal).
DYNAMICS = ("chain", "mjx")
DYNAMICS_HELP = ("single-support dynamics of the gait rollout: MJX's pipeline, or the closed-form planar "
                 "chain (equal to MJX's to rounding, several times faster)")


def _integer(name: str, low: int, high: int):
    """An argparse type: an integer in [low, high] (the subcommand's usage names a bad one)."""
    def parse(text: str) -> int:
        try:
            return checks.integer_in(f"--{name}", int(text), low, high)
        except ValueError:
            raise argparse.ArgumentTypeError(f"--{name} must be an integer in [{low}, {high}], got {text!r}") from None
    return parse


def _number(name: str, low: float, high: float):
    """An argparse type: a finite number in (low, high] (the subcommand's usage names a bad one)."""
    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = None
        if value is None or not low < value <= high:
            raise argparse.ArgumentTypeError(f"--{name} must be a number in ({low:g}, {high:g}], got {text!r}")
        return value
    return parse


def _drive(text: str) -> tuple[str, str]:
    """An argparse type: MOTOR+GEARHEAD, two catalogue names (checked against the catalogue later)."""
    parts = text.split("+")
    if len(parts) != 2 or not all(parts):
        raise argparse.ArgumentTypeError(f"a drive is MOTOR+GEARHEAD (e.g. RE25-42V+GP32A-66.22), got {text!r}")
    return parts[0], parts[1]


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


def _problem_arguments(parser, speed: str, step_length: str, grid: bool = False) -> None:
    """--mass-class, --speed(s), --step-length(s) and --power-limit: one value each, or with ``grid`` lists
    of speeds and lengths (default None: the command's grid)."""
    parser.add_argument("--mass-class", choices=("12kg", "18kg"), default="12kg", help="the biped (default 12kg)")
    lists = {"nargs": "+", "default": None} if grid else {}
    plural = "s" if grid else ""
    parser.add_argument(f"--speed{plural}", type=_number(f"speed{plural}", 0.0, 5.0),
                        **(lists or {"default": 0.555}), help=speed)
    parser.add_argument(f"--step-length{plural}", type=_number(f"step-length{plural}", 0.0, 1.0),
                        **(lists or {"default": 0.2}), help=step_length)
    parser.add_argument("--power-limit", type=_number("power-limit", 0.0, 1e6), default=20.0,
                        help="bound on every joint's |qdot u|, W (default 20)")


def _space_arguments(parser, when: str = "", substeps: int = 8, segments: bool = False, spans: int = 16) -> None:
    """The gait problem's reference space and grid (``biped_jax.gait.problem.GaitSettings``); ``segments``
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
    subcommands = parser.add_subparsers(dest="command", required=True)
    run = subcommands.add_parser("reproduce", help="run the paper's study and write results")
    _out_argument(run)
    _space_arguments(run, substeps=STUDY_SUBSTEPS, segments=True, spans=STUDY_SPANS)
    run.add_argument("--quick", action="store_true",
                     help="a coarse first look in a few minutes (8 knot spans, 3 start families; overrides "
                          "--spans/--substeps/--segments); every file it writes says so")
    run.add_argument("--dynamics", choices=DYNAMICS, default="chain", help=DYNAMICS_HELP + " (default chain)")
    run.add_argument("--resume", action="store_true",
                     help="continue an interrupted study in --out from its finished stages (OUT/stages)")
    own = subcommands.add_parser("solve", help="one gait problem of your own (mass class, speed, step length, "
                                 "power limit), solved as the study solves its models")
    _out_argument(own)
    _problem_arguments(own, speed="average walking speed, m/s, in (0, 5] (default 0.555)",
                       step_length="step length, m (default 0.2; at most the legs' reach)")
    own.add_argument("--smallest-power-limit", action="store_true",
                     help="also find the smallest power limit at which the model still walks")
    own.add_argument("--free-step-length", type=_number("free-step-length", 0.0, 1.0), nargs=2, default=None,
                     metavar=("LOW", "HIGH"),
                     help="then free the step length within [LOW, HIGH] m (holding --step-length, the start): "
                          "the gait and step length of least energy per metre at --speed")
    own.add_argument("--fastest", action="store_true",
                     help="also find the fastest gait within the same limits (power, and with a drive its "
                          "voltage and gears), the step length free within --free-step-length (default 0.1-0.35 m)")
    own.add_argument("--motor", default=None,
                     help="catalogue motor at every joint (e.g. RE25-42V; default: ideal drives, the paper's "
                          "problem; with --gearhead alone RE25-42V): the robot carries the drives, J is the "
                          "motors' Joule energy, the gait keeps within the supply voltage, and results say "
                          "whether each joint's drive passes the catalogue check")
    own.add_argument("--gearhead", default=None,
                     help="catalogue gearhead at every joint (e.g. GP32A-66.22; with --motor alone GP32A-66.22)")
    own.add_argument("--supply-voltage", type=_number("supply-voltage", 0.0, 1e4), default=None,
                     help="the drives' supply voltage, V (with --motor or --gearhead; default the catalogue's 38)")
    _space_arguments(own, substeps=STUDY_SUBSTEPS, segments=True, spans=STUDY_SPANS)
    own.add_argument("--dynamics", choices=DYNAMICS, default="chain", help=DYNAMICS_HELP + " (default chain)")
    library = subcommands.add_parser("library", help="optimal gaits over a grid of speeds and step lengths, the "
                                     "optimal step length at every speed and the drives' demand (figures, JSON, npz)")
    _out_argument(library)
    _problem_arguments(library, speed="walking speeds, m/s, increasing (default 0.3 0.45 0.6 0.75)",
                       step_length="step lengths, m, increasing (default 0.1 0.175 0.25)", grid=True)
    library.add_argument("--drive", type=_drive, default=None, metavar="MOTOR+GEARHEAD",
                         help="a catalogue drive at every joint, e.g. RE25-42V+GP32A-66.22 (default: ideal drives, the "
                              "paper's problem): the robot carries it, J is the motors' Joule energy, the gaits keep "
                              "its voltage and gear limits, and every point gets its catalogue check and walk time")
    library.add_argument("--supply-voltage", type=_number("supply-voltage", 0.0, 1e4), default=None,
                         help="the drive's supply voltage, V (with --drive; default the catalogue's 38)")
    library.add_argument("--all-families", action="store_true",
                         help="start every point from all nine start families of the study (default three)")
    library.add_argument("--rounds", type=_integer("rounds", 0, 20), default=3,
                         help="rounds of re-solving points that did not converge from their neighbours (default 3)")
    library.add_argument("--quick", action="store_true",
                         help="a first look: 3 speeds x 3 step lengths (overrides --speeds, --step-lengths and "
                              "the space); every file it writes says so")
    _space_arguments(library, substeps=4, spans=16)
    library.add_argument("--space-factor", type=_integer("space-factor", 0, 8), default=3,
                         help="the space check: every optimum solved again in this many times the knot spans and "
                              "reported there, with the estimated error of the space (default 3: 48 spans; "
                              "0: none; --quick: none)")
    fast = subcommands.add_parser("top-speed", help="how fast it can walk: the fastest gait under each power limit "
                                  "(v_max(M_W) per mass class) and on catalogue drives (figure, JSON)")
    _out_argument(fast)
    fast.add_argument("--mass-classes", choices=("12kg", "18kg"), nargs="+", default=["12kg", "18kg"],
                      help="the bipeds (default both)")
    fast.add_argument("--power-limits", type=_number("power-limits", 0.0, 1e6), nargs="*", default=None,
                      help="bounds on every joint's |qdot u|, W, with ideal drives (default 5 10 20 40; "
                           "none: drives only)")
    fast.add_argument("--drives", type=_drive, nargs="*", default=None, metavar="MOTOR+GEARHEAD",
                      help="catalogue drives at every joint, e.g. RE25-42V+GP32A-66.22 (default the paper's "
                           "RE25-42V on GP32A-51, -66.22 and -79; none: power limits only)")
    fast.add_argument("--supply-voltage", type=_number("supply-voltage", 0.0, 1e4), default=None,
                      help="the drives' supply voltage, V (default the catalogue's 38)")
    fast.add_argument("--quick", action="store_true",
                      help="a first look: 10 and 20 W and the paper's drive (overrides --power-limits and --drives); "
                           "every file it writes says so")
    _space_arguments(fast, substeps=4, spans=16)
    bench = subcommands.add_parser("kelly", help="solve Kelly's five-link biped benchmark (SIAM Review 2017)")
    _out_argument(bench)
    _space_arguments(bench)
    walker = subcommands.add_parser("donald", help="DONALD's statically stable walk in MJX (figures, JSON)")
    _out_argument(walker)
    walker.add_argument("--steps", type=_integer("steps", 1, 1000), default=8, help="steps to walk, 1-1000 (default 8)")
    walker.add_argument("--faster", action="store_true",
                        help="first optimise the gait for speed (tens of minutes), then walk the optimum")
    walker.add_argument("--resume", action="store_true",
                        help="with --faster: continue from the finished optimisation in --out (OUT/stages)")
    replay = subcommands.add_parser("humanoid", help="the optimal sagittal gait replayed on the 16-DoF humanoid "
                                 "under contact in MJX, then the humanoid walking in 3D with its drives in the "
                                 "loop, pushed (figures, JSON, animations)")
    _out_argument(replay)
    replay.add_argument("--model", default="M2", choices=("M1", "M2", "M3", "M4"),
                        help="which of the paper's models (default M2)")
    replay.add_argument("--steps", type=_integer("steps", 1, 1000), default=10,
                        help="steps to walk, 1-1000 (default 10)")
    replay.add_argument("--gaits", type=_input_folder, default=None,
                        help="folder with results.json from `biped-jax reproduce` (default: solve the model here)")
    replay.add_argument("--walk-models", nargs="*", default=["M2", "M4"], choices=("M1", "M2", "M3", "M4"),
                        help="models walked in 3D on the free-base humanoid with the drives in the loop "
                             "(default M2 M4; none: the sagittal replay alone)")
    replay.add_argument("--walk-steps", type=_integer("walk-steps", 1, 1000), default=20,
                        help="steps of each 3D walk after its start, 1-1000 (default 20)")
    replay.add_argument("--law", choices=("tracker", "walker"), default="tracker",
                        help="the 3D walk's law: tracker (the optimal step itself: its own inverse dynamics as "
                             "feed-forward, phased by the stance angle; two drives at each hip roll) or walker "
                             "(Raibert foot placement from rest; slower than the gait, sturdier) (default tracker)")
    replay.add_argument("--push-batch", type=_integer("push-batch", 0, 4096), default=64,
                        help="runs in each push trial of the 3D walks (default 64; 0: none)")
    _space_arguments(replay, " when solving here")
    design = subcommands.add_parser("codesign", help="co-design studies: gear ratios, windings and mass split "
                                 "optimised with the gait, windings and masses compared (figures, JSON; hours on "
                                 "2 cores, --quick in minutes)")
    _out_argument(design)
    _space_arguments(design)
    design.add_argument("--iterations", type=_integer("iterations", 1, 1000), default=5,
                        help="co-optimisation iterations, 1-1000 (default 5)")
    design.add_argument("--starts", type=_integer("starts", 2, 4096), default=64,
                        help="starting designs per problem of the co-optimisation, 2-4096 (default 64; a power of "
                             "two keeps the Sobol sequence balanced)")
    design.add_argument("--lanes", type=_integer("lanes", 1, 4096), default=None,
                        help="designs the co-optimisation iterates at once, 1-4096; a design that finishes hands "
                             "its lane to the next (default 8 on a CPU, the whole batch on a GPU)")
    design.add_argument("--quick", action="store_true",
                        help="a first look in minutes: only the co-optimisation, 8 starts per problem, 2 iterations "
                             "(overrides --starts/--iterations); every file it writes says so")
    design.add_argument("--dynamics", choices=DYNAMICS, default="chain", help=DYNAMICS_HELP + " (default chain)")
    design.add_argument("--resume", action="store_true",
                        help="continue interrupted studies in --out from their finished parts (OUT/stages)")
    drive = subcommands.add_parser("drives", help="drive-train selection (Table 6, Figs. 4-5) from solved gaits")
    _out_argument(drive)
    drive.add_argument("--gaits", type=_input_folder, default=None,
                       help="folder with trajectories.npz from `biped-jax reproduce` (default: --out)")
    step = subcommands.add_parser("step", help="simulate one heuristic PD-controlled step per mass class")
    _out_argument(step)
    subcommands.add_parser("models", help="list the robot models")
    view = subcommands.add_parser("view", help="open a model in MuJoCo's viewer (needs a display)")
    view.add_argument("name")
    view.add_argument("--replay", type=Path, default=None,
                      help="an .npz with t and qpos (e.g. out/donald_replay.npz) to play back")
    view.add_argument("--gif", type=Path, default=None,
                      help="render the --replay headless into this animated GIF instead of opening the viewer "
                           "(no display needed: EGL or OSMesa)")
    view.add_argument("--fps", type=_number("fps", 0.0, 100.0), default=30.0,
                      help="frames per second of the --gif, in real time (default 30)")
    for name, sub in subcommands.choices.items():
        sub.set_defaults(parser=sub, run=RUNS[name])
    return parser


#: What each command runs (:mod:`biped_jax.commands`).
RUNS = {"reproduce": commands.run_reproduce, "solve": commands.run_solve, "library": commands.run_library,
        "top-speed": commands.run_top_speed,
        "kelly": commands.run_kelly,
        "donald": commands.run_donald, "humanoid": commands.run_humanoid, "codesign": commands.run_codesign,
        "drives": commands.run_drives, "step": commands.run_step, "models": commands.run_models,
        "view": commands.run_view}


def main(argv: list[str] | None = None) -> int:
    """The command line; returns the exit status: 130 after Ctrl-C, 143 after SIGTERM (each stops the
    run at the next safe point, with one line saying what was kept), 1 when the output folder cannot
    be written to (one line naming it)."""
    args = _parser().parse_args(argv)
    if args.command == "donald" and args.resume and not args.faster:
        args.parser.error("--resume continues the --faster optimisation; give both or neither")
    if args.command == "solve":
        args.checked = commands.check_solve(args)  # the problem's own checks, before the output folder is made
    if args.command == "library":
        args.checked = commands.check_library(args)
    if args.command == "top-speed":
        args.checked = commands.check_top_speed(args)
    if not hasattr(args, "out"):
        return args.run(args)
    with interrupts.handled():
        try:
            return _run_in(args, ["biped-jax"] + (sys.argv[1:] if argv is None else list(argv)))
        except KeyboardInterrupt as error:
            number = getattr(error, "signal_number", signal.SIGINT)
            console.print(_kept(args.out, f"{'interrupted' if number == signal.SIGINT else 'terminated'}: "),
                          soft_wrap=True)
            return interrupts.EXIT_STATUS[number]
        except outputs.FolderInUse as error:
            console.print(f"error: {error}", soft_wrap=True)
            return 1
        except OSError as error:  # the disk full, the folder removed or made read-only under the run
            console.print(_kept(args.out, f"error: cannot write to {args.out} ({error.strerror or error}); "
                                          f"files written before are intact; "), soft_wrap=True)
            return 1


def _run_in(args, command: list[str]) -> int:
    """Runs the command under its manifest in ``args.out``; a stop request that no safe point saw
    still ends the run as interrupted."""
    with outputs.run_manifest(args.out, command, resume=getattr(args, "resume", False), say=console.print):
        with _user_stream():
            from biped_jax.report.compile_profile import profile_compiles
            with profile_compiles(compile_listener) as profile:  # names what is compiling
                status = args.run(args)
            interrupts.checkpoint()
            if args.profile_compile:
                _report_compiles(profile.summary(), args.out)
            return status


def _kept(out: Path, first: str) -> str:
    """One line: ``first``, then what the run finished and kept in ``out`` (its manifest's list)."""
    listed = outputs.last_run() or outputs.read_manifest(out)
    kept = ", ".join(listed["files"]) if listed and listed["files"] else "nothing"
    hint = ""
    if listed and any(name.startswith("stages/") for name in listed["files"]):
        hint = "; the same command with --resume continues from the finished stages"
    return f"{first}finished and kept in {out}: {kept} (see {out / outputs.MANIFEST})" + hint


@contextlib.contextmanager
def _user_stream():
    """XLA's slow-compile alarm filtered out of standard error (:mod:`biped_jax.report.xla_alarm`), the
    console writing to the real terminal meanwhile (so the live progress line still shows)."""
    from biped_jax.report.xla_alarm import quiet_compile_alarm
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


if __name__ == "__main__":
    sys.exit(main())
