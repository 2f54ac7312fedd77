"""biped_jax: design fast-walking legged robots by differentiable simulation (JAX + MuJoCo MJX).

Modules (README "Module map"): ``robots``, ``robot_specs``, ``mjcf``, ``design`` (the robots and their
design arrays); ``hybrid_step`` and ``planar_chain`` (the walking step in MJX and in closed form);
``augmented_lagrangian`` and ``sqp`` (the optimisers); ``gait`` and ``gait_solver`` (the optimal
walking step); ``drives`` and ``drive_selection`` (motors and gearheads); ``codesign``; ``donald``,
``humanoid``; ``study`` and the other ``*_study`` modules (the command line's studies); ``cli`` (the
``biped-jax`` command).

The names below load on first use (PEP 562), so ``import biped_jax`` and the command line's argument
checks do not wait for JAX and MuJoCo to import.
"""

import importlib

_EXPORTS = {
    "Design": "design", "apply_design": "design", "check_design": "design", "design_layout": "design",
    "PlanarBiped": "hybrid_step", "StanceTrajectory": "hybrid_step", "Touchdown": "hybrid_step",
    "load_planar_biped": "hybrid_step", "stance_rollout": "hybrid_step", "touchdown": "hybrid_step",
    "with_design": "hybrid_step",
    "ROBOTS": "robots", "load_mj_model": "robots", "load_mjx_model": "robots", "model_path": "robots",
    "GaitSettings": "gait", "gait_model": "gait", "START_FAMILIES": "gait",
    "GaitSolver": "gait_solver", "GaitSolution": "gait_solver", "solve_multistart": "gait_solver",
}

__all__ = sorted(_EXPORTS)
__version__ = "0.1.0"


def __getattr__(name: str):
    if name in _EXPORTS:
        value = getattr(importlib.import_module(f"biped_jax.{_EXPORTS[name]}"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'biped_jax' has no attribute {name!r}")


def __dir__():
    return sorted(list(globals()) + list(_EXPORTS))
