"""The command line: the heuristic-step command writes its files and the numbers in them hang together,
the other commands at short settings, bad arguments, and the compilation cache they configure."""

import dataclasses
import json
import os
import subprocess
import sys

import numpy as np
import pytest

from biped_jax import cli
from biped_jax.studies import paper as study


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    out = tmp_path_factory.mktemp("out")
    cli.main(["step", "--out", str(out), "--profile-compile"])
    return out, json.loads((out / "results.json").read_text())


@pytest.mark.slow
def test_compile_profile_lists_the_programs_the_command_compiled(results):
    out, _ = results
    profile = json.loads((out / "compile_profile.json").read_text())
    assert profile["distinct_programs"] == len(profile["programs"]) >= 1
    assert profile["compilations"] == sum(row["compiled"] + row["hit"] for row in profile["programs"].values())
    assert profile["seconds"] == pytest.approx(sum(row["seconds"] for row in profile["programs"].values()))
    assert "compile_profile.json" in json.loads((out / "manifest.json").read_text())["files"]


@pytest.mark.slow
def test_step_writes_results_table_and_figure(results):
    out, data = results
    assert (out / "heuristic_step.png").stat().st_size > 10_000
    assert "| touched down |" in (out / "heuristic_step.md").read_text()
    assert [s["mass_class"] for s in data["steps"]] == ["12kg", "18kg"]


@pytest.mark.slow
def test_reported_step_is_physical(results):
    _, data = results
    for step in data["steps"]:
        assert step["finite"] and step["touched_down"]
        weight = step["mass_kg"] * 9.81
        assert step["min_vertical_force_N"] > 0  # the stance foot stays loaded
        # a gentle heuristic step: the foot force stays of the order of the weight
        assert 0.5 * weight < step["max_vertical_force_N"] < 2 * weight
        assert 0.1 < step["step_length_m"] < 0.3
        assert step["energy_lost_at_impact_J"] > 0  # an inelastic impact dissipates
        assert step["old_stance_foot_velocity_after_impact_mps"][1] > 0  # it lifts off
    assert data["steps"][1]["mass_kg"] == pytest.approx(17.998, abs=1e-6)


def test_unknown_command_and_model_are_rejected(capsys):
    with pytest.raises(SystemExit):
        cli.main(["fly"])
    with pytest.raises(SystemExit):
        cli.main(["view", "biped7"])
    assert "biped7" in capsys.readouterr().err


def test_models_command_lists_every_model(capsys):
    from biped_jax.robots.registry import ROBOTS
    assert cli.main(["models"]) == 0
    listed = capsys.readouterr().out
    assert all(name in listed for name in ROBOTS)
    assert np.sum([line.endswith(".xml]") for line in listed.splitlines()]) == len(ROBOTS)


@pytest.mark.slow
@pytest.mark.xdist_group("test_gait")  # its study's solver shares the programs of the gait tests' solver
def test_reproduce_writes_the_study(tmp_path):
    """The main job at a short horizon with the planar-chain dynamics (equal to MJX's,
    tests/test_planar_chain.py; several times faster): files exist and results.json is consistent
    with itself."""
    assert cli.main(["reproduce", "--out", str(tmp_path), "--spans", "4", "--substeps", "4",
                     "--dynamics", "chain"]) == 0
    results = json.loads((tmp_path / "results.json").read_text())
    assert results["settings"]["dynamics"] == "chain"
    assert [m["model"] for m in results["models"]] == ["M1", "M2", "M3", "M4"]
    for record in results["models"]:
        # at 4 knot spans the study's refinement check is enforced: a gait that fails it is reported as
        # grid dependent and gets no smallest power limit (null in strict JSON), never a number
        assert record["status"] in ("converged", "grid dependent"), record["status"]
        assert record["max_violation"] <= 1e-4
        assert record["refinement"]["steps"] == 4 * 16
        assert record["refinement"]["passed"] == (record["status"] == "converged")
        assert set(record["joints"]) == {"H1", "K1", "H2", "K2"}
        for joint in record["joints"].values():
            assert joint["power_max"] <= record["power_limit_W"] + 1e-4
        assert len(record["starts"]) == len(study.STUDY_FAMILIES)
        if record["status"] != "converged":
            assert record["min_power_limit_W"] is None
        elif record["min_power_status"] == "converged":
            # the smallest limit: below the model's own, kept on the solve grid and the finer one
            assert record["min_power_solve_grid_W"] <= record["min_power_limit_W"] < record["power_limit_W"]
            gait_at_minimum = record["min_power_gait"]
            assert gait_at_minimum["power_limit_W"] == record["min_power_limit_W"]
            assert gait_at_minimum["refinement"]["passed"]
        else:
            assert record["min_power_limit_W"] is None
    assert [m["power_limit_W"] for m in results["at_20W"]] == [20.0] * 4
    for name in ("tables.md", "fig2_trajectories.png", "fig3_torque_rpm.png", "convergence.png"):
        assert (tmp_path / name).stat().st_size > 1000
    assert "| Max. (W) |" in (tmp_path / "tables.md").read_text()


@pytest.mark.xdist_group("test_gait")  # paper_solutions: the gait tests' fixture, on their worker
def test_solve_poses_ones_own_problem_and_writes_its_files(tmp_path, monkeypatch, paper_solutions):
    """``biped-jax solve`` hands the study's multistart the problem asked for (mass class, speed, step
    length, power limit) in the space asked for, from every start family, and writes its solution's
    files. The multistart is a stand-in returning a solved gait (its own tests and the study's cover
    it; solving here would compile the study's programs a second time in the suite)."""
    from biped_jax.gait import multistart
    solved = paper_solutions[0]
    asked = {}

    def stand_in(fine, names, models, families, coarse, progress=None, finished=None):
        asked.update(settings=fine.settings, coarse=coarse.settings, families=families, model=models[0])
        return [dataclasses.replace(solved, name=names[0])]
    monkeypatch.setattr(multistart, "solve_multistart", stand_in)
    assert cli.main(["solve", "--out", str(tmp_path), "--speed", "0.45", "--step-length", "0.22",
                     "--power-limit", "15", "--spans", "8", "--substeps", "2", "--segments", "4"]) == 0
    model = asked["model"]
    assert (float(model.speed), float(model.step_length), float(model.power_limit)) == (0.45, 0.22, 15.0)
    assert float(model.design.total_mass) == pytest.approx(12.0, abs=1e-2)
    assert (asked["settings"].spans, asked["settings"].substeps, asked["settings"].segments) == (8, 2, 4)
    assert asked["coarse"].spans == 2 and asked["families"] == study.STUDY_FAMILIES
    results = json.loads((tmp_path / "results.json").read_text())
    assert results["problem"] == {"mass_class": "12kg", "speed": 0.45, "step_length": 0.22, "power_limit": 15.0,
                                  "motor": None, "gearhead": None, "supply_voltage": None}
    assert results["settings"]["spans"] == 8 and "smallest_power_limit" not in results and "drives" not in results
    assert results["solution"]["cost"] == pytest.approx(solved.cost, rel=1e-12)
    assert results["solution"]["status"] == solved.status
    assert "12kg, 0.45 m/s, L = 0.22 m, M_W = 15 W" in (tmp_path / "tables.md").read_text()
    for name in ("fig2_trajectories.png", "fig3_torque_rpm.png", "trajectories.npz"):
        assert (tmp_path / name).stat().st_size > 1000


@pytest.mark.xdist_group("test_gait")  # paper_solutions: the gait tests' fixture, on their worker
def test_solve_with_a_drive_carries_it_and_checks_it_per_joint(tmp_path, monkeypatch, paper_solutions):
    """With ``--motor``/``--gearhead``/``--supply-voltage`` the problem is the co-design's gait problem
    of that catalogue drive (its masses carried, its winding and voltage in the drives), and results
    and tables say per joint whether the drive passes the catalogue check on the gait (here a stand-in
    gait: M2's, whose own check is in test_codesign)."""
    from biped_jax import codesign
    from biped_jax.drives import model as drive_model
    from biped_jax.gait import multistart
    asked = {}

    def stand_in(fine, names, models, families, coarse, progress=None, finished=None):
        asked.update(model=models[0])
        return [dataclasses.replace(paper_solutions[1], name=names[0])]
    monkeypatch.setattr(multistart, "solve_multistart", stand_in)
    assert cli.main(["solve", "--out", str(tmp_path), "--motor", "RE25-48V", "--gearhead", "GP32A-51",
                     "--supply-voltage", "30", "--spans", "8", "--substeps", "2", "--segments", "4"]) == 0
    drives, catalogue = asked["model"].drives, drive_model.load_catalogue()
    np.testing.assert_allclose(drives.ratio, catalogue.gearhead("GP32A-51").ratio)
    np.testing.assert_allclose(drives.torque_constant, catalogue.motor("RE25-48V").torque_constant)
    np.testing.assert_allclose(drives.supply_voltage, 30.0)
    design = codesign.catalogue_design("RE25-48V", "GP32A-51", "12kg", supply_voltage=30.0)
    expected = codesign.design_gait_model(design, 0.555, 20.0)
    np.testing.assert_allclose(asked["model"].design.drive_mass, expected.design.drive_mass)
    results = json.loads((tmp_path / "results.json").read_text())
    assert results["problem"]["motor"] == "RE25-48V" and results["drives"]["supply_voltage_V"] == 30.0
    joints = results["drives"]["joints"]
    assert [v["joint"] for v in joints] == ["H1", "K1", "H2", "K2"]
    assert results["drives"]["passes_catalogue_check"] == all(v["feasible"] for v in joints)
    assert all(v["gearhead"] == "GP32A-51" and v["reason"] for v in joints)
    assert "## The drive's catalogue check per joint" in (tmp_path / "tables.md").read_text()


@pytest.mark.slow
@pytest.mark.xdist_group("donald")  # the walker of tests/test_donald.py
def test_donald_command_writes_its_report(tmp_path):
    assert cli.main(["donald", "--out", str(tmp_path), "--steps", "2"]) == 0
    report = json.loads((tmp_path / "donald.json").read_text())
    assert report["steps"] == 2 and not report["fell"] and report["distance_m"] > 0.04
    assert report["speed_mps"] == pytest.approx(report["distance_m"] / (2 * sum(
        report["gait"][f"{phase}_time"] for phase in ("shift", "lift", "swing", "lower"))))
    assert set(report["joints"]) == {"ankle1", "hip1", "hip2", "ankle2", "pendulum"}
    replay = np.load(tmp_path / "donald_replay.npz")
    assert replay["qpos"].shape == (len(replay["t"]), 12)
    for name in ("donald_walk.png", "donald_torque_speed.png"):
        assert (tmp_path / name).stat().st_size > 1000


def test_reproduce_defaults_are_the_study_settings():
    """The parser (no JAX imported) states the study's space and grid as defaults of its own."""
    args = cli._parser().parse_args(["reproduce"])
    assert (args.spans, args.substeps) == (study.STUDY_SETTINGS.spans, study.STUDY_SETTINGS.substeps)
    assert cli.STUDY_SPANS == study.STUDY_SETTINGS.spans
    assert not args.quick and cli._parser().parse_args(["reproduce", "--quick"]).quick


def test_reproduce_rejects_bad_settings():
    with pytest.raises(SystemExit):
        cli.main(["reproduce", "--spans", "0"])
    with pytest.raises(SystemExit):
        cli.main(["reproduce", "--substeps", "7"])


ALARM = ("2025-03-19 07:30:02.045318: E external/xla/xla/service/slow_operation_alarm.cc:73] \n"
         "********************************\n"
         "[Compiling module jit_lagrangian] Very slow compile? If you want to file a bug, run with envvar "
         "XLA_FLAGS=--xla_dump_to=/tmp/foo and attach the results.\n"
         "********************************\n")


def test_the_xla_slow_compile_alarm_is_replaced_by_one_line_and_errors_pass():
    import subprocess
    import sys
    code = ("import os, sys\nfrom biped_jax.report.xla_alarm import quiet_compile_alarm\n"
            "with quiet_compile_alarm():\n"
            f"    os.write(2, {ALARM.encode()!r})\n"
            "    os.write(2, b'E0000 a real error\\n')\n"
            f"    os.write(2, {ALARM.encode()!r})\n"
            "    print('python error line', file=sys.stderr)\n")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    lines = run.stderr.splitlines()
    assert run.returncode == 0
    assert not any("Very slow compile" in line or line.startswith("****") for line in lines), lines
    assert lines.count("E0000 a real error") == 1 and lines.count("python error line") == 1
    assert sum("a compilation is taking minutes" in line for line in lines) == 2


def test_the_compilation_cache_can_be_moved(tmp_path):
    """`configure_jax` keeps the cache folder's path out of JAX's cache keys (by default JAX writes the GPU
    autotuning cache's folder into every key, so a cache copied elsewhere never hit): one program run
    with the cache in two folders gets the same entry in both."""
    script = ("from biped_jax.commands import configure_jax; configure_jax(); import jax; "
              "jax.jit(lambda x: 2.0 * x + 1.0)(1.0)")
    entries = []
    for folder in (tmp_path / "here", tmp_path / "moved" / "elsewhere"):
        subprocess.run([sys.executable, "-c", script], env={**os.environ, "BIPED_JAX_CACHE": str(folder)},
                       check=True, timeout=300)
        entries.append(sorted(p.name for p in folder.iterdir() if p.name.startswith("jit_")))
    assert entries[0] and entries[0] == entries[1]


def test_importing_the_package_sets_the_xla_flags_that_avoid_its_hangs_unless_the_user_chose():
    """XLA's multi-threaded Eigen pool and (on jaxlib 0.10) its fusion emitters hung batched solves
    (biped_jax/__init__.py); the flags must be in XLA_FLAGS before JAX starts its backend, and a user's
    own choice of either stays."""
    from importlib.metadata import version

    def flags(value):
        env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
        env |= {} if value is None else {"XLA_FLAGS": value}
        return subprocess.run([sys.executable, "-c", "import os, biped_jax; print(os.environ['XLA_FLAGS'])"],
                              env=env, capture_output=True, text=True, check=True).stdout.strip()
    emitters = " --xla_cpu_use_fusion_emitters=false" if version("jaxlib").startswith("0.10.") else ""
    assert flags(None) == "--xla_cpu_multi_thread_eigen=false" + emitters
    assert flags("--xla_dump_to=/tmp/x") == "--xla_dump_to=/tmp/x --xla_cpu_multi_thread_eigen=false" + emitters
    assert flags("--xla_cpu_multi_thread_eigen=true") == "--xla_cpu_multi_thread_eigen=true" + emitters
    assert flags("--xla_cpu_use_fusion_emitters=true") == ("--xla_cpu_use_fusion_emitters=true "
                                                           "--xla_cpu_multi_thread_eigen=false")
