"""Test configuration: float64 (finite differences and physics checks need it) and JAX's persistent
compilation cache, so a second run of the suite skips most compilation."""

import os
from pathlib import Path

import jax
import pytest

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_compilation_cache_dir",
                  os.environ.get("BIPED_JAX_CACHE", str(Path.home() / ".cache" / "biped_jax" / "jax")))
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)


def short_settings():
    """The tests' reference space and grid: 4 cubic knot spans, 4 Runge-Kutta steps each."""
    from biped_jax.gait import problem as gait
    return gait.GaitSettings(spans=4, substeps=4)


@pytest.fixture(scope="session")
def biped12():
    from biped_jax.dynamics import hybrid_step
    return hybrid_step.load_planar_biped("12kg")


@pytest.fixture(scope="session")
def biped18():
    from biped_jax.dynamics import hybrid_step
    return hybrid_step.load_planar_biped("18kg")


@pytest.fixture(scope="session")
def rollout():
    """One jitted single-support rollout shared by every test (compiled once per horizon)."""
    from biped_jax.dynamics import hybrid_step
    return jax.jit(hybrid_step.stance_rollout)


@pytest.fixture(scope="session")
def short_solver():
    """The gait solver at the tests' short horizon (:data:`TEST_SETTINGS`): the same code as the study;
    every test that solves gaits shares its compiled programs."""
    from biped_jax.gait import solver as gait_solver
    # the check is recorded but not enforced at this deliberately coarse grid (see GaitSolver)
    return gait_solver.GaitSolver(short_settings(), require_refinement=False)


@pytest.fixture(scope="session")
def paper_solutions(short_solver):
    """M1-M4 in one batch from the default start family (the program `biped-jax reproduce --spans 4
    --substeps 4` compiles for its refined-space stage)."""
    from biped_jax.studies import paper as study
    return short_solver.solve([r.name for r in study.PAPER_MODELS], study.paper_gait_models(study.PAPER_MODELS))
