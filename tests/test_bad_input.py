"""Bad input gets a named error before any computing, and no result file is ever wrong.

Table-driven over the command line (each row: the arguments, a text the error must contain) and over
the files a command reads; a fault test interrupts a run and checks what the folder says about it.
"""

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from biped_jax import cli, commands
from biped_jax.report import outputs


def _error(capsys, argv) -> str:
    with pytest.raises(SystemExit) as stop:
        cli.main(argv)
    assert stop.value.code == 2
    return capsys.readouterr().err


@pytest.fixture
def a_file(tmp_path):
    path = tmp_path / "a_file"
    path.write_text("not a folder")
    return path


CLI_ROWS = [
    (["reproduce", "--spans", "0"], "--spans must be an integer in [1, 200], got '0'"),
    (["reproduce", "--spans", "2.5"], "got '2.5'"),
    (["reproduce", "--degree", "100"], "--degree must be an integer in [2, 7], got '100'"),
    (["reproduce", "--substeps", "3"], "--substeps must be even"),
    (["kelly", "--degree", "1"], "--degree must be an integer in [2, 7], got '1'"),
    (["donald", "--steps", "-1"], "--steps must be an integer in [1, 1000], got '-1'"),
    (["humanoid", "--model", "M9"], "'M9'"),
    (["humanoid", "--walk-models", "M5"], "'M5'"),
    (["humanoid", "--walk-steps", "0"], "--walk-steps must be an integer in [1, 1000], got '0'"),
    (["humanoid", "--push-batch", "-1"], "--push-batch must be an integer in [0, 4096], got '-1'"),
    (["humanoid", "--law", "fast"], "invalid choice: 'fast'"),
    (["codesign", "--iterations", "0"], "--iterations must be an integer in [1, 1000], got '0'"),
    (["codesign", "--starts", "1"], "--starts must be an integer in [2, 4096], got '1'"),
    (["codesign", "--lanes", "0"], "--lanes must be an integer in [1, 4096], got '0'"),
    (["reproduce", "--dynamics", "euler"], "'euler'"),
    (["solve", "--speed", "0"], "--speed must be a number in (0, 5], got '0'"),
    (["solve", "--power-limit", "nan"], "--power-limit must be a number in (0, 1e+06], got 'nan'"),
    (["solve", "--step-length", "-0.2"], "--step-length must be a number in (0, 1], got '-0.2'"),
    (["solve", "--step-length", "0.7"], "step_length 0.7 m is beyond the legs' reach"),
    (["solve", "--mass-class", "30kg"], "'30kg'"),
    (["solve", "--free-step-length", "0.25", "0.3"], "bounds (0.25, 0.3) m must hold every model's step length"),
    (["library", "--speeds", "0.5", "0.4"], "speeds must increase, got [0.5, 0.4]"),
    (["library", "--step-lengths", "0.1", "0.9"], "step_length 0.9 m is beyond the legs' reach"),
    (["library", "--rounds", "99"], "--rounds must be an integer in [0, 20], got '99'"),
    (["library", "--drive", "RE25-42V"], "a drive is MOTOR+GEARHEAD"),
    (["library", "--drive", "RE25-42V+GP32A-7"], "unknown gearhead part 'GP32A-7'"),
    (["library", "--supply-voltage", "24"], "supply_voltage 24.0 applies to a drive"),
    (["library", "--space-factor", "1"], "--space-factor must be 0 (no space check) or at least 2, got 1"),
    (["library", "--space-factor", "9"], "--space-factor must be an integer in [0, 8], got '9'"),
    (["top-speed", "--drives", "RE99+GP32A-51"], "unknown motor part 'RE99'"),
    (["top-speed", "--power-limits", "-3"], "--power-limits must be a number in (0, 1e+06], got '-3'"),
    (["top-speed", "--power-limits", "--drives"], "--power-limits and --drives are both empty"),
    (["top-speed", "--mass-classes", "20kg"], "'20kg'"),
    (["top-speed", "--power-limits", "10", "--drives", "--supply-voltage", "30"],
     "--supply-voltage 30 applies to drives"),
    (["solve", "--fastest", "--step-length", "0.4"], "bounds (0.1, 0.35) m must hold every model's step length"),
    (["solve", "--free-step-length", "0.1", "-1"], "--free-step-length must be a number in (0, 1], got '-1'"),
    (["solve", "--spans", "6", "--segments", "4"], "segments must divide spans"),
    (["solve", "--motor", "RE99"], "unknown motor part 'RE99'"),
    (["solve", "--gearhead", "GP32A-7"], "unknown gearhead part 'GP32A-7'"),
    (["solve", "--supply-voltage", "24"], "supply_voltage 24.0 applies to a drive"),
    (["solve", "--motor", "RE25-42V", "--supply-voltage", "-5"], "--supply-voltage must be a number in (0, 10000]"),
]


@pytest.mark.parametrize("argv, message", CLI_ROWS, ids=[" ".join(r[0]) for r in CLI_ROWS])
def test_bad_arguments_are_named_with_the_subcommands_usage(capsys, tmp_path, argv, message):
    out = tmp_path / "never"
    error = _error(capsys, argv + ["--out", str(out)])
    assert message in error
    assert f"usage: biped-jax {argv[0]}" in error  # the subcommand's usage, not the top level's
    assert not out.exists()  # refused before anything was made


@pytest.mark.parametrize("below", [False, True], ids=["a file", "below a file"])
def test_an_output_folder_that_cannot_exist_is_refused_first(capsys, a_file, below):
    target = a_file / "sub" if below else a_file
    error = _error(capsys, ["reproduce", "--out", str(target)])
    assert str(target) in error and "is a file" in error


def test_an_unwritable_output_folder_is_refused_first(capsys, tmp_path, monkeypatch):
    locked = tmp_path / "locked"
    locked.mkdir(mode=0o500)
    if os.access(locked, os.W_OK):  # root writes anywhere: let the permission check say what it would
        real_access = os.access
        monkeypatch.setattr(os, "access", lambda path, mode: False if Path(path) == locked else real_access(path, mode))
    error = _error(capsys, ["reproduce", "--out", str(locked / "out")])
    assert "not writable" in error and str(locked) in error
    assert not (locked / "out").exists()


def test_the_argument_check_runs_before_jax_is_imported():
    code = ("import sys\nfrom biped_jax import cli\ntry:\n    cli.main(['reproduce', '--spans', '0'])\n"
            "except SystemExit:\n    pass\nassert 'jax' not in sys.modules, 'jax imported'\n")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert run.returncode == 0, run.stderr


def _gait_file(path, **changes):
    """A drive-study input in the layout `biped-jax reproduce` writes, with entries changed/removed."""
    t = np.linspace(0.0, 0.36, 50)
    arrays = {"M2_t": t, "M2_speed": np.ones((50, 4)), "M2_torque": np.ones((50, 4)),
              "M2_meta": np.array([0.36, 12.0, 0.555, 1.0])}
    for key, value in changes.items():
        if value is None:
            arrays.pop(key)
        else:
            arrays[key] = value
    np.savez(path / "trajectories.npz", **arrays)


def _nan_torque():
    torque = np.ones((50, 4))
    torque[7, 2] = np.nan
    return torque


GAIT_FILE_ROWS = [
    ({"M2_torque": _nan_torque()}, "1 NaN or infinite values in M2_torque"),
    ({"M2_meta": None}, "no gait in it"),
    ({"M2_speed": None}, "gait M2 lacks M2_speed"),
    ({"M2_t": np.zeros(0), "M2_speed": np.zeros((0, 4)), "M2_torque": np.zeros((0, 4))}, "T >= 2"),
    ({"M2_meta": np.array([0.36, -12.0, 0.555, 1.0])}, "mass -12.0 kg"),
]


@pytest.mark.parametrize("changes, message", GAIT_FILE_ROWS, ids=[r[1] for r in GAIT_FILE_ROWS])
def test_a_broken_gait_file_is_named_and_nothing_is_written(capsys, tmp_path, changes, message):
    gaits, out = tmp_path / "gaits", tmp_path / "out"
    gaits.mkdir()
    _gait_file(gaits, **changes)
    error = _error(capsys, ["drives", "--gaits", str(gaits), "--out", str(out)])
    assert message in error and "trajectories.npz" in error
    assert not (out / "drives.json").exists()
    assert outputs.read_manifest(out)["state"] == "failed"


def test_a_file_that_is_not_npz_is_named(capsys, tmp_path):
    (tmp_path / "trajectories.npz").write_text("hello")
    error = _error(capsys, ["drives", "--gaits", str(tmp_path), "--out", str(tmp_path / "out")])
    assert "not a readable .npz" in error and "pickled" not in error


def test_missing_inputs_are_named(capsys, tmp_path):
    assert "does not exist" in _error(capsys, ["drives", "--gaits", str(tmp_path / "nowhere")])
    assert "does not exist" in _error(capsys, ["humanoid", "--gaits", str(tmp_path / "nowhere")])
    error = _error(capsys, ["view", "donald", "--replay", str(tmp_path / "missing.npz")])
    assert "missing.npz" in error and "does not exist" in error


def test_json_is_strict_and_missing_values_are_null(tmp_path):
    record = {"a": math.nan, "b": [1.0, math.inf, np.float64(-np.inf)], "c": np.array([1.0, np.nan]),
              "d": {"e": np.float32(2.5), "f": np.int64(3)}, "g": (math.nan,)}
    path = outputs.write_json(tmp_path / "r.json", record)
    text = path.read_text()
    assert "NaN" not in text and "Infinity" not in text
    assert json.loads(text) == {"a": None, "b": [1.0, None, None], "c": [1.0, None],
                                "d": {"e": 2.5, "f": 3}, "g": [None]}
    assert [p.name for p in tmp_path.iterdir()] == ["r.json"]  # no temporary left behind


@pytest.mark.parametrize("umask, mode", [(0o022, 0o644), (0o077, 0o600), (0o002, 0o664)])
def test_result_files_are_as_readable_as_the_umask_says(tmp_path, umask, mode):
    old = os.umask(umask)
    try:
        paths = [outputs.write_json(tmp_path / "r.json", {"a": 1}), outputs.write_text(tmp_path / "t.md", "x\n"),
                 outputs.write_bytes(tmp_path / "b.bin", b"x")]
    finally:
        os.umask(old)
    assert [oct(p.stat().st_mode & 0o777) for p in paths] == [oct(mode)] * 3


def test_a_quick_look_says_so_in_every_file_it_writes(tmp_path):
    """`reproduce --quick` runs its study inside outputs.stamped(QUICK_STAMP): JSON, markdown, the
    figures, the npz and the manifest all carry the stamp; a file written after the block does not."""
    import matplotlib
    matplotlib.use("Agg")
    from matplotlib import pyplot as plt
    stamp = "QUICK LOOK: a test"
    with outputs.run_manifest(tmp_path, ["biped-jax", "reproduce", "--quick"]):
        with outputs.stamped(stamp):
            outputs.write_json(tmp_path / "results.json", {"models": []})
            outputs.write_text(tmp_path / "tables.md", "# Tables\n")
            outputs.save_npz(tmp_path / "trajectories.npz", M1_t=np.zeros(3))
            figure = plt.figure()
            outputs.save_figure(figure, tmp_path / "fig.png")
            assert stamp in [text.get_text() for text in figure.texts]
            plt.close(figure)
        outputs.write_json(tmp_path / "later.json", {"models": []})
    assert json.loads((tmp_path / "results.json").read_text()) == {"stamp": stamp, "models": []}
    assert (tmp_path / "tables.md").read_text().startswith(f"**{stamp}**")
    assert str(outputs.read_npz(tmp_path / "trajectories.npz")["stamp"]) == stamp
    assert outputs.read_manifest(tmp_path)["stamp"] == stamp
    assert "stamp" not in json.loads((tmp_path / "later.json").read_text())


def test_a_failed_write_leaves_the_old_file(tmp_path):
    path = outputs.write_json(tmp_path / "r.json", {"old": 1})

    class Unserialisable:
        pass
    with pytest.raises(TypeError):
        outputs.write_json(path, {"new": Unserialisable()})
    assert json.loads(path.read_text()) == {"old": 1}
    assert [p.name for p in tmp_path.iterdir()] == ["r.json"]


def test_an_interrupted_run_says_so_and_sets_earlier_results_aside(capsys, tmp_path, monkeypatch):
    # an earlier, completed run left a results file
    with outputs.run_manifest(tmp_path, ["earlier"]):
        outputs.write_json(tmp_path / "results.json", {"from": "earlier"})
    assert outputs.read_manifest(tmp_path)["state"] == "completed"

    def interrupted_study(out):
        outputs.write_json(out / "results.json", {"from": "this run"})
        raise KeyboardInterrupt
    monkeypatch.setattr(commands, "heuristic_steps", interrupted_study)
    monkeypatch.setattr(commands, "configure_jax", lambda: None)
    assert cli.main(["step", "--out", str(tmp_path)]) == 130
    error = capsys.readouterr().err
    assert "interrupted" in error and "results.json" in error and "Traceback" not in error
    manifest = outputs.read_manifest(tmp_path)
    assert manifest["state"] == "interrupted" and manifest["files"] == ["results.json"]
    assert manifest["command"] == ["biped-jax", "step", "--out", str(tmp_path)] and manifest["ended"]
    assert json.loads((tmp_path / "results.json").read_text()) == {"from": "this run"}
    earlier = tmp_path / outputs.PREVIOUS
    assert json.loads((earlier / "results.json").read_text()) == {"from": "earlier"}
    assert json.loads((earlier / outputs.MANIFEST).read_text())["command"] == ["earlier"]


def _api_rows():
    """(label, call, text the message must contain); built lazily (the calls import JAX)."""
    import dataclasses

    from biped_jax import codesign
    from biped_jax.drives import model as drive_model
    from biped_jax.drives import selection
    from biped_jax.dynamics import mjx_biped
    from biped_jax.gait import problem as gait_problem
    from biped_jax.robots import registry
    biped, design = mjx_biped.load_planar_biped("12kg"), mjx_biped.planar_design("12kg")
    masses = lambda *m: dataclasses.replace(design, link_mass=np.array(m, dtype=float))  # noqa: E731
    motor = drive_model.load_catalogue().motor("RE25-42V")
    reference = codesign.catalogue_design()
    return [
        ("zero link mass", lambda: mjx_biped.with_design(biped, masses(0, 1, 1, 1, 1)), "link_mass must be positive"),
        ("NaN link mass", lambda: mjx_biped.with_design(biped, masses(np.nan, 1, 1, 1, 1)),
         "link_mass must be finite"),
        ("wrong-length q", lambda: mjx_biped.center_of_mass(biped.pinned, np.zeros(3)), "q must have shape (5,)"),
        ("wrong-length q (foot)", lambda: mjx_biped.swing_foot(biped.pinned, np.zeros(4), np.zeros(5)), "shape (5,)"),
        ("negative timestep", lambda: mjx_biped.with_timestep(biped.pinned, -0.005), "got -0.005"),
        ("zero timestep", lambda: mjx_biped.with_timestep(biped.pinned, 0.0), "timestep must be"),
        ("negative supply", lambda: drive_model.no_load_speed(motor, -38.0), "supply_voltage must be finite and > 0 V"),
        ("negative ratio", lambda: drive_model.motor_torque(1.0, 1.0, -66.0, 0.7), "gear ratio must be finite"),
        ("efficiency above 1", lambda: drive_model.motor_torque(1.0, 1.0, 66.0, 1.5), "got 1.5"),
        ("ratio far off the catalogue", lambda: codesign.nearest_gearhead(1e9), "far outside the catalogue"),
        ("MJCF folder", lambda: registry.load_mj_model_from_path(registry.models_dir()), "is a folder"),
        ("negative speed", lambda: codesign.design_gait_model(reference, -1.0, 20.0), "speed must be positive"),
        ("NaN speed", lambda: codesign.design_gait_model(reference, math.nan, 20.0), "got nan"),
        ("step beyond reach", lambda: codesign.solve_designs(None, [reference], 0.5, 20.0, step_length=5.0),
         "beyond the legs' reach"),
        ("no structure", lambda: codesign.robot_design(dataclasses.replace(reference, structure_mass=np.zeros(5))),
         "link_mass must be positive"),
        ("settings: negative friction", lambda: gait_problem.GaitSettings(friction=-0.1), "friction"),
        ("settings: steps as float", lambda: gait_problem.GaitSettings(spans=2.5), "got 2.5"),
        ("gait_model: a string speed", lambda: gait_problem.gait_model("12kg", "fast", 20.0), "speed must be a number"),
        ("gait_model: a vector speed", lambda: gait_problem.gait_model("12kg", np.ones(2), 20.0),
         "speed must be a number"),
        ("co-design: no designs", lambda: codesign.solve_designs(None, [], 0.5, 20.0), "designs is empty"),
        ("co-design: a negative gradient tolerance", lambda: codesign.co_optimise(None, [reference], 0.5, 20.0,
                                                                                 gradient_tolerance=-1.0),
         "gradient_tolerance must be"),
        ("co-design: windings bounds reversed", lambda: codesign.co_optimise(
            None, [reference], 0.5, 20.0, torque_constant_bounds=(0.05, 0.02)), "torque_constant_bounds must be"),
        ("co-design: a winding of no torque constant", lambda: codesign.nearest_winding(0.0),
         "torque_constant must be positive"),
        ("co-design: three motors", lambda: codesign.catalogue_design(("RE25-42V",) * 3), "give one motor or four"),
        ("co-design: gradient check steps", lambda: codesign.gradient_check(None, [reference], [None], 0.5, 20.0,
                                                                           steps=(0.01,) * 9),
         "steps must be 11 positive numbers"),
        ("co-design: gradient check refinement", lambda: codesign.gradient_check(None, [reference], [None], 0.5, 20.0,
                                                                                refinement=0.0),
         "refinement must be a number in"),
        ("co-design: gradient check bounds", lambda: codesign.gradient_check(None, [reference], [None], 0.5, 20.0,
                                                                            bounds=(np.zeros(11), np.ones(3))),
         "bounds must be (low, high) with 11 values each"),
        ("co-design: speeds for another batch", lambda: codesign.solve_designs(None, [reference] * 3, [0.5, 0.6],
                                                                                20.0), "one value per design (3)"),
        ("co-design: names for another batch", lambda: codesign.solve_designs(None, [reference], 0.5, 20.0,
                                                                              names=["a", "b"]), "2 names"),
        ("co-design: negative iterations", lambda: codesign.co_optimise(None, [reference], 0.5, 20.0, iterations=-1),
         "iterations must be an integer"),
        ("co-design: inverted ratio bounds", lambda: codesign.co_optimise(None, [reference], 0.5, 20.0,
                                                                          ratio_bounds=(190, 14)), "ratio_bounds"),
        ("co-design: a mass split bound past 1", lambda: codesign.co_optimise(
            None, [reference], 0.5, 20.0, mass_split_bounds=((0.2, 0.25), (1.5, 0.75))),
         "high < 1 (fractions), got ((0.2, 0.25), (1.5"),
        ("co-design: one mass split bound", lambda: codesign.co_optimise(
            None, [reference], 0.5, 20.0, mass_split_bounds=(0.2, 0.5)), "two values each"),
        ("drives: negative supply", lambda: drive_model.catalogue_drives("RE25-42V", "GP32A-66", -1.0),
         "supply_voltage"),
        ("drives: ragged workspace", lambda: selection.JointWorkspace(np.linspace(0, 1, 5), np.zeros((4, 4)),
                                                                      np.zeros((4, 4)), 1.0), "shape (5, any)"),
        ("drives: no workspaces", lambda: selection.select_drive([], drive_model.load_catalogue()),
         "workspaces is empty"),
    ]


def test_every_impossible_api_value_is_named():
    for label, call, message in _api_rows():
        with pytest.raises(ValueError) as error:
            call()
        assert message in str(error.value), (label, str(error.value))


def _solver_rows(solver, model):
    """(label, call, error type, text): the solver's batch API, each refused before anything compiles."""
    import jax

    from biped_jax.dynamics import mjx_biped
    from biped_jax.gait import problem as gait_problem
    from biped_jax.gait.multistart import solve_multistart
    from biped_jax.gait.spaces import finer_solver, space_check
    from biped_jax.robots.design import design_layout
    n = solver.settings.size
    return [
        ("two names, one model", lambda: solver.solve(["M2", "X"], [model]), ValueError, "2 names, 1 models"),
        ("an empty batch", lambda: solver.solve([], []), ValueError, "names is empty"),
        ("one name as a string", lambda: solver.solve("M2", [model]), TypeError, "names must be a list or tuple"),
        ("not a model", lambda: solver.solve(["M2"], [3.0]), TypeError, "models[0] must be a GaitModel"),
        ("x0 of the wrong shape", lambda: solver.solve(["M2"], [model], x0=np.zeros(5)), ValueError,
         f"x0 must have shape (1, {n})"),
        ("x0 with NaN", lambda: solver.solve(["M2"], [model], x0=np.full((1, n), np.nan)), ValueError,
         "x0 must be finite"),
        ("multipliers not a pair", lambda: solver.solve(["M2"], [model], multipliers=np.zeros(3)), TypeError,
         "multipliers must be a pair"),
        ("multipliers for two", lambda: solver.solve(["M2"], [model], multipliers=(np.zeros((2, 3)),
                                                                                    np.zeros((2, 4)))),
         ValueError, "multipliers[0] (equalities) must have shape (1, any)"),
        ("power limit without starts", lambda: solver.minimise_power_limit(["M2"], [model], None), ValueError,
         "x0 is None"),
        ("power limit, starts for two", lambda: solver.minimise_power_limit(["M2"], [model], np.zeros((2, n))),
         ValueError, f"x0 must have shape (1, {n})"),
        ("power limit, a negative weight", lambda: solver.minimise_power_limit(
            ["M2"], [model], np.zeros((1, n)), energy_weights=(0.1, -1.0)), ValueError, "energy_weights must be"),
        ("power limit, no weights", lambda: solver.minimise_power_limit(
            ["M2"], [model], np.zeros((1, n)), energy_weights=()), ValueError, "energy_weights must be"),
        ("step length, bounds not a pair", lambda: solver.solve_step_length(["M2"], [model], 0.3), ValueError,
         "bounds must be a pair (low, high)"),
        ("step length, bounds beside the start", lambda: solver.solve_step_length(["M2"], [model], (0.1, 0.15)),
         ValueError, "bounds (0.1, 0.15) m must hold every model's step length"),
        ("step length, beyond the reach", lambda: solver.solve_step_length(["M2"], [model], (0.1, 2.0)),
         ValueError, "below the legs' reach"),
        ("fastest gait without starts", lambda: solver.fastest_gait(["M2"], [model], None, (0.1, 0.3)), ValueError,
         "x0 is None"),
        ("fastest gait, bounds beside the start", lambda: solver.fastest_gait(["M2"], [model], np.zeros((1, n)),
                                                                              (0.25, 0.3)),
         ValueError, "must hold every model's step length"),
        ("too many tightening rounds", lambda: solver.solve(["M2"], [model], tightening=11), ValueError,
         "tightening must be"),
        ("tightening without the check", lambda: type(solver)(
            solver.settings, check_refinement=False).solve(["M2"], [model], tightening=1), ValueError,
         "tightening=1 needs the refinement check"),
        ("multistart: names and models", lambda: solve_multistart(solver, ["M2"], [model, model]), ValueError,
         "1 names, 2 models"),
        ("multistart: no families", lambda: solve_multistart(solver, ["M2"], [model], families=()), ValueError,
         "families is empty"),
        ("space check into no finer space", lambda: space_check(solver, solver, ["M2"], [model], [None]),
         ValueError, "the finer space has 4 knot spans, the gaits' 4"),
        ("space check, a tolerance of 2", lambda: space_check(solver, solver, ["M2"], [model], [None], tolerance=2.0),
         ValueError, "tolerance must be a number in (0, 1]"),
        ("space check, a factor of 1", lambda: finer_solver(solver, 1), ValueError,
         "factor must be an integer in [2, 8], got 1"),
        ("gait_model under jit", lambda: jax.jit(lambda v: gait_problem.gait_model("12kg", v, 20.0).speed)(0.5),
         TypeError, "speed is traced"),
        ("solver settings", lambda: type(solver)(settings={"spans": 4}), TypeError, "settings must be a GaitSettings"),
        ("a design that is not one", lambda: mjx_biped.with_design(solver.biped, 3), TypeError,
         "design must be a Design"),
        ("a biped that is not one", lambda: mjx_biped.with_design(3, model.design), TypeError,
         "biped must be a PlanarBiped"),
        ("a layout of no model", lambda: design_layout(3), TypeError, "mj_model must be a mujoco.MjModel"),
        ("an unknown mass class", lambda: mjx_biped.load_planar_biped("20kg"), ValueError,
         "unknown mass class '20kg'"),
    ]


def test_the_solver_api_refuses_a_bad_batch_before_compiling():
    import jax.numpy as jnp

    from biped_jax.gait import problem as gait_problem
    from biped_jax.gait.solver import GaitSolver
    solver = GaitSolver(gait_problem.GaitSettings(spans=4, substeps=2))
    # concrete 0-d arrays are numbers (sweeps build them)
    model = gait_problem.gait_model("12kg", jnp.asarray(0.5), np.float64(20.0), np.asarray(0.2))
    assert float(model.speed) == 0.5 and float(model.power_limit) == 20.0
    from biped_jax.report.compile_profile import profile_compiles
    with profile_compiles() as profile:
        for label, call, kind, message in _solver_rows(solver, model):
            with pytest.raises(kind) as error:
                call()
            assert message in str(error.value), (label, str(error.value))
    assert not profile.events, [event["name"] for event in profile.events]


@pytest.mark.parametrize("content, message", [
    ('{"settings": {}}', "no 'models'"), ("{not json", "not a study result"),
    ('{"models": [{"model": "M2", "status": "converged"}], "settings": {}}', "decision vector")],
    ids=["no models", "corrupt", "no decision vector"])
def test_a_broken_study_result_is_named(capsys, tmp_path, content, message):
    (tmp_path / "results.json").write_text(content)
    error = _error(capsys, ["humanoid", "--gaits", str(tmp_path), "--out", str(tmp_path / "out")])
    assert message in error and "results.json" in error


def test_every_result_file_is_written_through_the_strict_atomic_writers():
    """The property behind 'no JSON the project writes contains NaN': every writer in the package goes
    through biped_jax.report.outputs (strict JSON, atomic). A new direct write would break it."""
    from pathlib import Path

    import biped_jax
    direct = ("json.dump(", "json.dumps(", ".write_text(", ".savefig(", "np.savez", "np.save(")
    offenders = []
    for path in Path(biped_jax.__file__).parent.glob("*.py"):
        if path.name in ("outputs.py", "mjcf.py"):  # mjcf writes the model files, not results
            continue
        for number, line in enumerate(path.read_text().splitlines(), 1):
            if any(call in line.replace("outputs.write_text(", "") for call in direct):
                offenders.append(f"{path.name}:{number}: {line.strip()}")
    assert not offenders, offenders


def test_a_finished_stage_is_kept_and_resumed_only_for_the_same_settings(tmp_path):
    calls = []

    def compute(value):
        return lambda: calls.append(value) or {"x": np.arange(3.0) * value}
    key = {"settings": {"spans": 4}}
    first = outputs.stage(tmp_path, "paper_models", key, compute(1.0), resume=False)
    assert calls == [1.0] and (tmp_path / "stages" / "paper_models.pkl").is_file()
    again = outputs.stage(tmp_path, "paper_models", key, compute(2.0), resume=True)
    assert calls == [1.0]  # taken from the file, not computed
    np.testing.assert_array_equal(again["x"], first["x"])
    other = outputs.stage(tmp_path, "paper_models", {"settings": {"spans": 8}}, compute(3.0), resume=True)
    assert calls == [1.0, 3.0] and other["x"][1] == 3.0  # other settings: computed again
    outputs.stage(tmp_path, "paper_models", key, compute(4.0), resume=False)
    assert calls == [1.0, 3.0, 4.0]  # without --resume a stage is always computed
    (tmp_path / "stages" / "paper_models.pkl").write_bytes(b"truncated")
    assert outputs.stage(tmp_path, "paper_models", key, compute(5.0), resume=True)["x"][1] == 5.0


def test_resume_keeps_the_earlier_runs_files_and_says_so(tmp_path):
    with pytest.raises(KeyboardInterrupt):
        with outputs.run_manifest(tmp_path, ["first"]):
            outputs.write_bytes(tmp_path / "stages" / "paper_models.pkl", b"stage")
            raise KeyboardInterrupt
    with outputs.run_manifest(tmp_path, ["second", "--resume"], resume=True):
        pass
    manifest = outputs.read_manifest(tmp_path)
    assert (tmp_path / "stages" / "paper_models.pkl").is_file() and not (tmp_path / outputs.PREVIOUS).exists()
    assert manifest["resumed_from"]["state"] == "interrupted"
    assert manifest["resumed_from"]["files"] == ["stages/paper_models.pkl"]


def test_resume_is_a_reproduce_option_checked_before_any_work(capsys):
    assert "--resume" in _error(capsys, ["kelly", "--resume"])  # only the long studies have stages
    assert "give both or neither" in _error(capsys, ["donald", "--resume"])


def test_the_committed_benchmark_results_are_strict_json():
    """Every JSON under benchmarks/results parses without NaN or Infinity (benchmarks save through
    benchmarks/_results.py, which writes with biped_jax.report.outputs)."""
    folder = Path(__file__).resolve().parent.parent / "benchmarks" / "results"

    def refuse(constant):
        raise ValueError(f"non-JSON constant {constant}")
    files = sorted(folder.glob("*.json"))
    assert files
    for path in files:
        json.loads(path.read_text(), parse_constant=refuse)  # raises, naming the constant
