"""Test configuration: float64 (finite differences and physics checks need it) and JAX's persistent
compilation cache, so a second run of the suite skips most compilation; XLA's CPU backend without its
LLVM optimisation passes (below)."""

import dataclasses
import os
import pickle
from pathlib import Path

#: On an empty cache the suite's time is mostly XLA compiling its programs, which then run for a few
#: seconds each: without the backend's optimisation passes the suite took 517 s instead of about 610 s
#: on 2 cores (2026-12-05, the same 282 tests passing). Set before JAX starts its backend; XLA_FLAGS is
#: part of the persistent cache's key, so these programs never stand in for `biped-jax`'s own.
#: One LLVM module per program, not split for parallel code generation: at this optimisation level the
#: split cost more than it saved (a rollout gradient's test 38.5 s instead of 44.5 s, M1-M4's first solve in
#: a fresh process 45 s instead of 50 s on an empty cache, 2 cores, 2026-12-06).
#: (XLA's elemental emitters instead of its fusion emitters, which compile the interior point's iteration
#: in 12.8 s instead of 17.5 s at this level, are set by the package itself on import: biped_jax/__init__.py.)
from biped_jax import default_xla_flag  # noqa: E402  (importing biped_jax does not start JAX's backend)

for flag in ("--xla_backend_optimization_level=0", "--xla_cpu_parallel_codegen_split_count=1"):
    default_xla_flag(flag)

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from biped_jax.commands import configure_jax  # noqa: E402

configure_jax()  # what `biped-jax` sets: float64, the persistent cache (BIPED_JAX_CACHE), every program cached


def short_settings():
    """The tests' reference space and grid: 4 cubic knot spans, 4 Runge-Kutta steps each."""
    from biped_jax.gait import problem as gait_problem
    return gait_problem.GaitSettings(spans=4, substeps=4)


@pytest.fixture(scope="session")
def biped12():
    from biped_jax.dynamics import mjx_biped
    return mjx_biped.load_planar_biped("12kg")


@pytest.fixture(scope="session")
def biped18():
    from biped_jax.dynamics import mjx_biped
    return mjx_biped.load_planar_biped("18kg")


#: The single-support rollouts' horizon in every test and the README's quickstart: one compiled program.
ROLLOUT_STEPS = 50


#: The walking step's backends (:mod:`biped_jax.dynamics.interface`): the physics tests run against each.
BACKENDS = ("mjx", "chain", "mujoco")


def backend(biped, name: str, dt: float | None = None):
    """The backend ``name`` of ``biped``, its pinned model stepping ``dt`` s where given."""
    from biped_jax.dynamics import interface, mjx_biped
    if dt is not None:
        biped = dataclasses.replace(biped, pinned=mjx_biped.with_timestep(biped.pinned, dt))
    return interface.stance_dynamics(biped, name)


@pytest.fixture(scope="session")
def rollout():
    """One single-support rollout per backend shared by every test (controls of :data:`ROLLOUT_STEPS`
    steps; MJX's is the program the README's quickstart compiles): ``rollout(dynamics, q0, qd0,
    controls)``, jitted for the JAX backends, MuJoCo C's as it is."""
    from biped_jax.dynamics import interface
    jitted = jax.jit(interface.stance_rollout)

    def run(dynamics, q0, qd0, controls):
        numpy_backend = getattr(dynamics, "xp", None) is np
        return (interface.stance_rollout if numpy_backend else jitted)(dynamics, q0, qd0, controls)
    return run


#: The differentiated rollout: 20 Euler steps of 1.8 ms from a mid-step state (no damping, so the
#: closed-form chain's explicit Euler equals MJX's).
GRADIENT_STEPS, GRADIENT_DT = 20, 1.8e-3
GRADIENT_START = (np.array([-0.35, 0.0, -0.35, 0.35, 0.0]), np.array([2.5, 0.0, 2.5, -4.0, 0.0]))


def rollout_cost(q, qd, qdd, u, force, foot, foot_velocity):
    """A scalar of everything a rollout returns (final state and acceleration, torques, the ground force
    of every step: MJX's Newton-Euler pass) and of the swing foot's position and velocity at its end."""
    return (jnp.sum(q[-1] ** 2) + 0.1 * jnp.sum(qd[-1] ** 2) + 1e-2 * jnp.sum(qdd[-1]) + 1e-2 * jnp.sum(u ** 2)
            + 1e-4 * jnp.sum(force[:, 1] ** 2) + 1e-2 * jnp.sum(force[-1]) + foot[1] + jnp.sum(foot_velocity))


@pytest.fixture(scope="session")
def mjx_rollout_gradient(biped12):
    """``(q0, qd0, controls) -> ((cost, trajectory), gradient)`` of :func:`rollout_cost` through MJX's
    rollout (its ground force per step) and swing foot on the 12 kg biped at :data:`GRADIENT_DT`: one compiled
    program that the finite-difference check (test_dynamics) and the closed-form chain's gradient
    (test_planar_chain) both use."""
    from biped_jax.dynamics import interface, mjx_biped
    dynamics = backend(biped12, "mjx", GRADIENT_DT)
    pinned = dynamics.pinned

    def cost(params):
        trajectory = interface.stance_rollout(dynamics, *params)
        q, qd, qdd = trajectory.q, trajectory.qd, trajectory.qdd
        foot, foot_velocity = mjx_biped.swing_foot(pinned, q[-1], qd[-1])
        return rollout_cost(q, qd, qdd, trajectory.u, trajectory.ground_force, foot, foot_velocity), trajectory
    return jax.jit(jax.value_and_grad(cost, has_aux=True))


@pytest.fixture(scope="session")
def short_solver():
    """The gait solver at the tests' short horizon (:data:`TEST_SETTINGS`): the same code as the study;
    every test that solves gaits shares its compiled programs."""
    from biped_jax.gait import solver as gait_solver
    # the check is recorded but not enforced at this deliberately coarse grid (see GaitSolver)
    return gait_solver.GaitSolver(short_settings(), require_refinement=False)


@pytest.fixture(scope="session")
def paper_solutions(short_solver, tmp_path_factory, worker_id):
    """M1-M4 in one batch from the default start family (the program `biped-jax reproduce --spans 4
    --substeps 4` compiles for its refined-space stage). Solved once per run: under pytest-xdist the
    first worker to ask solves and saves them beside the workers' temporary folders, the others load
    them (about 45 s each on 2 cores, most of it tracing and compiling the solver's programs)."""
    from biped_jax.studies import paper as study

    def solve():
        return short_solver.solve([r.name for r in study.PAPER_MODELS], study.paper_gait_models(study.PAPER_MODELS))
    if worker_id == "master":
        return solve()
    from filelock import FileLock
    shared = tmp_path_factory.getbasetemp().parent / "paper_solutions.pickle"
    with FileLock(f"{shared}.lock"):
        if shared.is_file():
            return pickle.loads(shared.read_bytes())
        solutions = solve()
        shared.write_bytes(pickle.dumps(solutions))
        return solutions


#: The costliest xdist groups first (pytest-xdist hands out groups in collection order with
#: --no-loadscope-reorder): the last group to start should be a short one. Seconds of compiling on an empty
#: cache, two workers, measured 2026-12-03 (commit c0b4a4c, BIPED_JAX_TEST_COMPILES): the quickstart's
#: programs and single support 97, the gait 84, the rollout gradient 62, mjx.forward 54, the design (with the
#: variants check) 43, DONALD 43, the command line 40, the humanoid 29, the rest under 26; the interior
#: point (its gait check) about 45, measured 2026-12-03 in a full run; with the smallest power limit's KKT
#: check about 120 (2026-12-04, 72 s of it compiling; first in the order measured no faster, 604 s against 595 s).
HEAVY_FIRST = ("mjx_quickstart", "test_gait", "mjx_gradient", "mjx_forward", "test_interior_point", "test_design",
               "test_local_derivatives",
               "donald", "test_cli",
               "test_humanoid", "test_dynamics", "test_codesign", "test_readme",
               "test_planar_chain", "test_models")


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config, items):
    """Every test without an explicit xdist_group is grouped with its module (a module's fixtures compile
    once, on one worker; what pytest-xdist's loadfile does), and the groups are ordered heaviest first."""
    for item in items:
        if item.get_closest_marker("xdist_group") is None:
            item.add_marker(pytest.mark.xdist_group(item.path.stem))

    def rank(item):
        group = item.get_closest_marker("xdist_group").args[0]
        return HEAVY_FIRST.index(group) if group in HEAVY_FIRST else len(HEAVY_FIRST)
    items.sort(key=rank)  # stable: each group keeps its tests' order


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    """With BIPED_JAX_TEST_COMPILES=DIR, each test's compilations (program names, compile or cache-load
    seconds; a fixture's in the test that first sets it up) and its start and end (Unix time, s: the
    workers' schedule, their idle time) are appended to DIR/<worker>.jsonl: where the suite's time goes on
    an empty cache. Off by default."""
    folder = os.environ.get("BIPED_JAX_TEST_COMPILES")
    if not folder:
        yield
        return
    import json
    import time

    from biped_jax.report.compile_profile import profile_compiles
    started = time.time()
    with profile_compiles() as profile:
        yield
    summary = profile.summary()
    row = {"test": item.nodeid, "started": started, "ended": time.time(), "compilations": summary["compilations"],
           "seconds_compiled": summary["seconds_compiled"], "seconds": summary["seconds"],
           "programs": {name: round(p["seconds"], 2) for name, p in summary["programs"].items() if p["seconds"] > 0.5}}
    Path(folder).mkdir(parents=True, exist_ok=True)
    with open(Path(folder) / f"{os.environ.get('PYTEST_XDIST_WORKER', 'main')}.jsonl", "a") as file:
        file.write(json.dumps(row) + "\n")
