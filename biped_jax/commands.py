"""What each ``biped-jax`` command runs and prints: the study of its module in :mod:`biped_jax.studies`
under a live display, then a summary of the results (:mod:`biped_jax.cli` parses the arguments and
dispatches here). Each ``run_*`` takes the parsed arguments and returns the exit status; the studies
import JAX only when a command runs."""

from __future__ import annotations

import contextlib
import dataclasses
import os
import sys
import time
from pathlib import Path

import numpy as np

from biped_jax.report import outputs
from biped_jax.report.progress import console, live_progress


def configure_jax(cache_dir: str | None = None) -> None:
    """float64 and the persistent compilation cache (set by the entry point, never on import)."""
    import jax
    jax.config.update("jax_enable_x64", True)
    cache = cache_dir or os.environ.get("BIPED_JAX_CACHE",
                                        str(Path.home() / ".cache" / "biped_jax" / "jax"))
    jax.config.update("jax_compilation_cache_dir", cache)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    if jax.default_backend() == "cpu":
        # JAX puts the GPU autotuning cache's directory into every program's cache key by default, so a
        # cache copied or moved to another path would never hit; it serves GPUs only.
        jax.config.update("jax_persistent_cache_enable_xla_caches", "none")


def heuristic_steps(out: Path) -> dict:
    """One heuristic PD-controlled step per mass class, reported; see :mod:`biped_jax.studies.step`."""
    from biped_jax.gait.heuristic_step import HeuristicGait
    from biped_jax.studies import step as step_study

    out.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    summaries, arrays = [], {}
    for mass_class in step_study.MASS_CLASSES:
        with console.status(f"simulating a heuristic step of the {mass_class} biped "
                            "(the first run compiles for a few seconds)"):
            summary, arrays[mass_class] = step_study.step_report(mass_class, HeuristicGait())
        summaries.append(summary)
        console.print(f"[green]done[/] {mass_class}: touched down = {summary['touched_down']}")
    results = step_study.write_report(out, summaries, arrays, time.perf_counter() - started)
    console.print(f"wrote {out / 'results.json'}, {out / 'heuristic_step.md'}, {out / 'heuristic_step.png'}")
    return results


def reproduce(out: Path, settings, resume: bool = False, quick: bool = False) -> dict:
    """The paper's study with a live progress display; see :func:`biped_jax.studies.paper.run_study`. ``quick``:
    the coarse look of :data:`biped_jax.studies.paper.QUICK_SETTINGS` (``settings`` ignored), every file stamped."""
    from biped_jax.studies import paper as paper_study

    started = time.perf_counter()
    stamp = outputs.stamped(paper_study.QUICK_STAMP) if quick else contextlib.nullcontext()
    with live_progress(("M1-M4", "20 W:", "restart:", "smallest power limit")) as progress, stamp:
        if quick:
            console.log(paper_study.QUICK_STAMP)
            results = paper_study.run_study(out, paper_study.QUICK_SETTINGS, progress, resume=resume,
                                      families=paper_study.QUICK_FAMILIES)
        else:
            results = paper_study.run_study(out, settings, progress, resume=resume)
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
    """Kelly's benchmark with a live progress line; see :func:`biped_jax.studies.kelly.run_kelly`."""
    import dataclasses

    from biped_jax.studies import kelly as kelly_study

    # a shooting segment per knot span, as the benchmark's own settings
    settings = dataclasses.replace(kelly_study.KELLY_SETTINGS, spans=spans, degree=degree, substeps=substeps,
                                   segments=spans)
    started = time.perf_counter()
    with live_progress(("interior-point iteration",)) as progress:
        record = kelly_study.run_kelly(out, settings, progress)
    console.print(f"Kelly's five-link biped: {record['status']}, J = {record['cost']:.4g} N^2 m^2 s on "
                  f"{record['steps']} Runge-Kutta steps ({record['cost_coarse']:.4g} on {record['steps_coarse']}, "
                  f"{record['cost_refined']:.4g} on {record['steps_refined']}), largest violation "
                  f"{record['max_violation']:.1e}; active: {', '.join(record['active_constraints'])}")
    console.print(f"wrote {out}/kelly.json, kelly_step.png in {time.perf_counter() - started:.0f} s")
    return record


def donald_walk(out: Path, steps: int, faster: bool = False, resume: bool = False) -> dict:
    """DONALD's walk (or the optimised one); see :mod:`biped_jax.studies.donald`."""
    from biped_jax.studies import donald as donald_study

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


def humanoid_walk(out: Path, model: str, steps: int, settings, gaits: Path | None,
                  walk_models: tuple[str, ...] = ("M2", "M4"), walk_steps: int = 20, push_batch: int = 64,
                  law: str = "tracker") -> dict:
    """The optimal gait replayed on the humanoid, and the 3D walks; see :mod:`biped_jax.studies.humanoid`."""
    from biped_jax.studies import humanoid as humanoid_study

    started = time.perf_counter()
    with live_progress(("humanoid: t =", f"{model}: outer", "3D walk")) as progress:
        report = humanoid_study.run_humanoid(out, model, steps, settings, gaits, progress, walk_models, walk_steps,
                                             push_batch, law)
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
    for name, walk in report.get("models", {}).items():
        console.print(_walk_3d_line(name, walk))
    console.print(f"wrote {out}/humanoid.json, humanoid_walk.png, humanoid_tracking.png, humanoid_torque_speed.png, "
                  f"humanoid_replay.npz, humanoid_walk3d_*.npz in {time.perf_counter() - started:.0f} s")
    return report


def _walk_3d_line(name: str, walk: dict) -> str:
    """One model's 3D walk in a line: steps, fall, speed and step length against the gait's, the drives."""
    line = f"3D walk of {name} ({walk['mass_class']}): {walk['steps_after_transient']} steps ({walk['law']}), " + (
        "fell" if walk["fell"] else "did not fall")
    if "speed_ratio" in walk:
        line += (f"; {walk['speed_mps']:.3f} m/s ({walk['speed_ratio']:.0%} of the gait's), step "
                 f"{walk['step_length_m']:.3f} m ({walk['step_length_ratio']:.0%}), {walk['rebounds']} rebounds "
                 f"({walk['contact_losses']} stance feet losing the ground's force for up to "
                 f"{1e3 * walk['longest_contact_loss_s']:.0f} ms), "
                 f"slip {1e3 * walk['slip_max_m']:.1f} mm, torque up to {walk['max_drive_torque_ratio']:.2f}x the "
                 f"drive line, cost of transport {walk['cost_of_transport']:.3f} (optimal step "
                 f"{walk['gait_cost_of_transport']:.3f})")
    if "push_success_rate" in walk:
        from biped_jax.studies.humanoid import PUSH_IMPULSE, PUSH_SWEEP
        half = walk["push_half_fall_impulse_Ns"]
        line += (f"; pushed ({PUSH_IMPULSE} N s each way): {walk['push_success_rate']:.0%} stayed up, "
                 "half fall " + (f"beyond {PUSH_SWEEP} N s" if half is None else f"from {half:.2f} N s on"))
    return line



def codesign(out: Path, settings, iterations: int, resume: bool = False, starts: int = 64,
             quick: bool = False, lanes: int | None = None) -> dict:
    """The co-design studies; see :mod:`biped_jax.studies.codesign`. ``quick``: study (d) alone with
    :data:`~biped_jax.studies.codesign.QUICK_STARTS` starts and ``QUICK_ITERATIONS`` iterations
    (``starts`` and ``iterations`` ignored), every file stamped."""
    from biped_jax.studies import codesign as codesign_study

    started = time.perf_counter()
    if quick:
        starts, iterations = codesign_study.QUICK_STARTS, codesign_study.QUICK_ITERATIONS
    stamp = outputs.stamped(codesign_study.QUICK_STAMP) if quick else contextlib.nullcontext()
    with live_progress() as progress, stamp:
        if quick:
            console.log(codesign_study.QUICK_STAMP)
        results = codesign_study.run_codesign(out, settings, iterations, progress, resume=resume, starts=starts,
                                              optimisation_only=quick, lanes=lanes)
    if not quick:
        for speed, fit in results["mass_scaling"]["fits"].items():
            console.print(f"(a) {speed} m/s: peak joint power ~ M^{fit['peak_power_exponent']:.2f}, Joule energy per "
                          f"metre ~ M^{fit['joule_per_metre_exponent']:.2f} ({fit['converged']} of 8 masses "
                          "converged)")
        limits = results["speed_limits"]
        best = int(np.argmax(np.nan_to_num(limits["max_speed_mps"], nan=-1.0)))
        console.print(f"(b) fastest: {limits['max_speed_mps'][best]:.3f} m/s with {limits['gearheads'][best]}")
        front = [results["pareto"]["designs"][i] for i in results["pareto"]["pareto"]]
        console.print("(c) Pareto front: " + ", ".join(
            f"{r['winding']} + {r['gearhead']} ({r['total_mass_kg']:.2f} kg, "
            f"{r['joule_energy_per_metre_J_per_m']:.3g} J/m)" for r in front))
    for name, entry in results["co_optimisation"]["per_problem"].items():
        if entry["best"] is None:
            console.print(f"(d) {name}: no snapped design has a converged gait")
            continue
        record, reduction = entry["best_design"], entry["energy_reduction_vs_paper"]
        against = (f"{reduction['reduction']:.0%} below the paper's design" if reduction["reduction"] is not None
                   else reduction["reason"])
        console.print(f"(d) {name}: best catalogue design {' / '.join(record['gearheads'])}, "
                      f"{' / '.join(record['motors'])}: {record['joule_energy_per_metre_J_per_m']:.4g} J/m, "
                      f"{against}; " + ("passes the catalogue check" if record["passes_catalogue_check"] else
                                        "fails the catalogue check: " + "; ".join(
                                            f"{v['joint']} {v['reason']}" for v in record["drive_verdicts"]
                                            if not v["feasible"])))
        passing = entry["best_passing_catalogue_check"]
        if passing is not None and passing["index"] != entry["best"]:
            console.print(f"    the best passing the catalogue check: {' / '.join(passing['gearheads'])}, "
                          f"{' / '.join(passing['motors'])}: {passing['joule_energy_J']:.4g} J per step")
        elif passing is None:
            console.print("    no converged design passes the catalogue check (gear torque and speed, thermal)")
    figures = "codesign_optimisation.png" if quick else "four figures"
    console.print(f"wrote {out}/codesign.json and {figures} in {time.perf_counter() - started:.0f} s")
    return results


def _settings(args):
    """The gait space and grid of the command line's --spans/--degree/--substeps (--dynamics,
    --segments where the command has them)."""
    from biped_jax.gait.problem import GaitSettings
    try:
        return GaitSettings(spans=args.spans, degree=args.degree, substeps=args.substeps,
                            dynamics=getattr(args, "dynamics", "chain"),
                            segments=getattr(args, "segments", None))
    except ValueError as error:
        args.parser.error(str(error))


def run_models(args) -> int:
    from biped_jax import robots
    for name, (file_name, description) in robots.ROBOTS.items():
        print(f"{name:28s} {description}  [{robots.models_dir() / file_name}]")
    return 0


def run_view(args) -> int:
    from biped_jax import robots
    try:
        model = robots.load_mj_model(args.name)
        replay = None if args.replay is None else load_replay(args.replay)
    except ValueError as error:
        args.parser.error(str(error))
    if replay is not None and replay["qpos"].shape[1] != model.nq:
        args.parser.error(f"--replay {args.replay}: qpos has {replay['qpos'].shape[1]} columns, "
                          f"{args.name} has {model.nq} coordinates")
    if args.gif is not None:
        if replay is None:
            args.parser.error("--gif needs --replay (the motion to render)")
        from biped_jax.report import animation
        try:
            path = animation.write_gif(args.gif, model, replay["t"], replay["qpos"], fps=args.fps)
        except RuntimeError as error:
            print(f"biped-jax view: {error}", file=sys.stderr)
            return 1
        print(f"wrote {path} ({len(animation.frame_indices(replay['t'], args.fps))} frames)")
        return 0
    import mujoco
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


def run_drives(args) -> int:
    from biped_jax.drives import selection as drive_selection
    from biped_jax.studies import drive_train
    source = (args.gaits or args.out) / "trajectories.npz"
    if not source.is_file():
        args.parser.error(f"no gait trajectories at {source}: run `biped-jax reproduce --out "
                          f"{args.gaits or args.out}` first")
    try:
        workspaces = drive_selection.load_workspaces(source)
    except ValueError as error:
        args.parser.error(str(error))
    drive_train.run_drive_study(args.out, workspaces)
    console.print(f"wrote into {args.out}: " + ", ".join(outputs.read_manifest(args.out)["files"]))
    return 0


def run_step(args) -> int:
    configure_jax()
    heuristic_steps(args.out)
    return 0


def check_library(args):
    """The grid and space of ``biped-jax library``, checked before the output folder is touched."""
    from biped_jax.studies import library as library_study
    configure_jax()
    try:
        library_study.check_space_factor(args.space_factor, "--space-factor")
        drive = {"drive": args.drive, "supply_voltage": args.supply_voltage}
        if args.quick:
            return (library_study.LibraryGrid(args.mass_class, library_study.QUICK_SPEEDS,
                                              library_study.QUICK_STEP_LENGTHS, args.power_limit, **drive),
                    library_study.QUICK_SETTINGS)
        defaults = library_study.LibraryGrid()
        grid = library_study.LibraryGrid(args.mass_class, tuple(args.speeds or defaults.speeds),
                                         tuple(args.step_lengths or defaults.step_lengths), args.power_limit, **drive)
    except ValueError as error:
        args.parser.error(str(error))
    return grid, _settings(args)


def _walk_words(check: dict | None) -> str:
    """A drive check's verdict and walk time, in words ('' without a drive)."""
    if check is None:
        return ""
    walk = check["walk_time_s"]
    return ("; catalogue check: " + ("passes" if check["passes_catalogue_check"] else "fails")
            + (", walks indefinitely" if walk is None else f", walks {walk / 60:.1f} min from 25 C"))


def _spans_used(points: list[dict]) -> str:
    """How many library points are reported in each space ("8 in 48, 3 in 96 knot spans")."""
    spans = [p["space"]["spans"][-1] for p in points if p["space"] and "spans" in p["space"]]
    return ", ".join(f"{spans.count(n)} in {n}" for n in sorted(set(spans))) + " knot spans"


def run_library(args) -> int:
    """A gait library with a live progress line; see :mod:`biped_jax.studies.library`."""
    from biped_jax.studies import library as library_study
    from biped_jax.studies import paper
    grid, settings = getattr(args, "checked", None) or check_library(args)
    started = time.perf_counter()
    stamp = outputs.stamped(library_study.QUICK_STAMP) if args.quick else contextlib.nullcontext()
    with live_progress(("starts", "grid:", "round", "step length free", "space check")) as progress, stamp:
        families = paper.STUDY_FAMILIES if args.all_families else library_study.LIBRARY_FAMILIES
        record = library_study.run_library(args.out, grid, settings, args.rounds, progress, families=families,
                                           space_factor=0 if args.quick else args.space_factor)
    points = record["points"]
    converged = sum(p["status"] == "converged" for p in points)
    console.print(f"{grid.mass_class}, {grid.power_limit:g} W: {converged} of {len(points)} grid points converged, "
                  f"{sum(bool(p['refinement_passed']) for p in points)} kept on the 4x grid"
                  + ("" if record["space_check"] is None else
                     f", reported {_spans_used(points)}, "
                     f"{sum(bool((p['space'] or {}).get('passed')) for p in points)} with the space's estimated "
                     f"error within {100 * record['space_check']['tolerance']:g} %"))
    for best in record["optimal_step"]:
        if best is not None:
            console.print(f"  {best['speed_mps']:g} m/s: optimal step {best['step_length_m']:.3f} m "
                          f"({best['status']}), J/L {best['cost_per_metre']:.4g}, "
                          f"peak torque {max(best['torque_peak_Nm']):.2f} N m"
                          + _walk_words(best.get("drive_check")))
    lasting = record.get("indefinite_walk")
    if lasting is not None:
        console.print(f"on {' + '.join(grid.drive)}: walks indefinitely (the thermal check) at up to "
                      + ("no speed of the grid" if lasting["up_to_mps"] is None else f"{lasting['up_to_mps']:g} m/s")
                      + ("" if lasting["not_at_mps"] is None else f", not at {lasting['not_at_mps']:g} m/s"))
    console.print(f"wrote {args.out}/library.json, library.npz, library_map.png, library_drives.png in "
                  f"{time.perf_counter() - started:.0f} s")
    return 0


def check_top_speed(args):
    """The problems and space of ``biped-jax top-speed``, checked before the output folder is touched."""
    from biped_jax.studies import top_speed as study
    configure_jax()
    limits = study.QUICK_POWER_LIMITS if args.quick else (
        study.POWER_LIMITS if args.power_limits is None else tuple(args.power_limits))
    drives = study.QUICK_DRIVES if args.quick else (study.DRIVES if args.drives is None else tuple(args.drives))
    try:
        chosen = study.problems(tuple(args.mass_classes), limits, drives, args.supply_voltage)
        if not chosen:
            raise ValueError("--power-limits and --drives are both empty: nothing to solve")
        if args.supply_voltage is not None and not drives:
            raise ValueError(f"--supply-voltage {args.supply_voltage:g} applies to drives: give --drives")
    except ValueError as error:
        args.parser.error(str(error))
    settings = dataclasses.replace(_settings(args), drive_limits=True)
    return chosen, settings


def run_top_speed(args) -> int:
    """The fastest gaits with a live progress line; see :mod:`biped_jax.studies.top_speed`."""
    from biped_jax.studies import top_speed as study
    chosen, settings = getattr(args, "checked", None) or check_top_speed(args)
    started = time.perf_counter()
    stamp = outputs.stamped(study.QUICK_STAMP) if args.quick else contextlib.nullcontext()
    with live_progress(("start:", "fastest gait:")) as progress, stamp:
        record = study.run_top_speed(args.out, chosen, settings, say=progress)
    for entry in record["problems"]:
        if entry["top_speed_mps"] is None:
            console.print(f"  {entry['name']}: no top speed (the start at {record['start_speed_mps']:g} m/s: "
                          f"{entry['start']['status']})")
            continue
        line = (f"  {entry['name']}: {entry['top_speed_mps']:.3f} m/s at L = {entry['step_length_m']:.3f} m "
                f"({entry['status']}, kept on the 4x grid: {'yes' if entry['refinement_passed'] else 'no'})")
        console.print(line + _walk_words(entry.get("drive_check")))
    console.print(f"wrote {args.out}/top_speed.json, top_speed.png in {time.perf_counter() - started:.0f} s")
    return 0


def run_kelly(args) -> int:
    configure_jax()
    settings = _settings(args)
    kelly(args.out, settings.spans, settings.degree, settings.substeps)
    return 0


def run_donald(args) -> int:
    configure_jax()
    donald_walk(args.out, args.steps, args.faster, args.resume)
    return 0


def run_humanoid(args) -> int:
    configure_jax()
    settings = _settings(args)
    try:
        humanoid_walk(args.out, args.model, args.steps, settings, args.gaits, tuple(args.walk_models),
                      args.walk_steps, args.push_batch, args.law)
    except (ValueError, FileNotFoundError) as error:
        args.parser.error(str(error))
    return 0


def run_codesign(args) -> int:
    configure_jax()
    codesign(args.out, _settings(args), args.iterations, args.resume, args.starts, args.quick, args.lanes)
    return 0


def solve(out: Path, problem, settings, smallest_power_limit: bool = False, free_step_length=None,
          fastest: bool = False) -> dict:
    """One problem of the user's own with a live progress display; see :mod:`biped_jax.studies.solve`."""
    from biped_jax.studies import solve as solve_study

    started = time.perf_counter()
    stages = ("starts:", "refined space:", "smallest power limit", "free step length", "the fastest gait")
    with live_progress(stages) as progress:
        results = solve_study.run_solve(out, problem, settings, smallest_power_limit, progress,
                                        free_step_length=free_step_length, fastest=fastest)
    record = results["solution"]
    check = record["refinement"]
    console.print(f"{problem.name}: {record['status']}, J = {record['cost']:.4g} ({check['cost']:.4g} on "
                  f"{check['steps']} steps), largest violation {record['max_violation']:.1e}")
    if "smallest_power_limit" in results:
        minimum = results["smallest_power_limit"]
        console.print("smallest feasible M_W " + ("-" if minimum["min_power_limit_W"] is None
                                                  else f"{minimum['min_power_limit_W']:.3f} W")
                      + f" ({minimum['min_power_status']})")
    if "free_step_length" in results:
        free = results["free_step_length"]
        console.print(f"step length free: L = {free['step_length_m']:.4f} m ({free['solution']['status']}), J/L = "
                      f"{free['cost_per_metre']:.4g} against {free['fixed_cost_per_metre']:.4g} at "
                      f"{problem.step_length:g} m")
    if "fastest" in results:
        quickest = results["fastest"]
        console.print(f"fastest gait: v = {quickest['speed_mps']:.4f} m/s at L = {quickest['step_length_m']:.4f} m "
                      f"({quickest['status']})")
    console.print(f"wrote {out}/results.json, tables.md, fig2_trajectories.png, fig3_torque_rpm.png, "
                  f"trajectories.npz in {time.perf_counter() - started:.0f} s")
    return results


def check_solve(args):
    """The problem and the space of ``biped-jax solve``, checked as the API checks them (the legs' reach,
    segments dividing spans) before the output folder is touched; the parser names a bad value."""
    from biped_jax.studies.solve import Problem
    problem = Problem(args.mass_class, args.speed, args.step_length, args.power_limit, motor=args.motor,
                      gearhead=args.gearhead, supply_voltage=args.supply_voltage)
    configure_jax()
    try:
        problem.model()
        if args.free_step_length is not None or args.fastest:
            from biped_jax.gait.settings import check_step_bounds
            from biped_jax.studies.solve import FASTEST_STEP_BOUNDS
            check_step_bounds(tuple(args.free_step_length or FASTEST_STEP_BOUNDS), [problem.step_length],
                              problem.mass_class)
    except ValueError as error:
        args.parser.error(str(error))
    return problem, _settings(args)


def run_solve(args) -> int:
    problem, settings = getattr(args, "checked", None) or check_solve(args)  # checked once by cli.main
    solve(args.out, problem, settings, args.smallest_power_limit, args.free_step_length, args.fastest)
    return 0


def run_reproduce(args) -> int:
    configure_jax()
    reproduce(args.out, _settings(args), args.resume, args.quick)
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
