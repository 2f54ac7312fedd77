"""biped_jax: design fast-walking legged robots by differentiable simulation (JAX + MuJoCo MJX).

Modules: ``robots`` (model registry and loading), ``robot_specs`` and ``mjcf`` (robot data and the
MJCF files), ``design`` (design parameters as arrays), ``hybrid_step`` (the sagittal walking step in
MJX), ``heuristic_step`` (a PD-controlled step), ``cli`` (the ``biped-jax`` command).
"""

from biped_jax.design import Design, apply_design, check_design, design_layout
from biped_jax.hybrid_step import (
    PlanarBiped,
    StanceTrajectory,
    Touchdown,
    load_planar_biped,
    stance_rollout,
    touchdown,
    with_design,
)
from biped_jax.robots import ROBOTS, load_mj_model, load_mjx_model, model_path

__all__ = [
    "ROBOTS", "Design", "PlanarBiped", "StanceTrajectory", "Touchdown", "apply_design", "check_design",
    "design_layout", "load_mj_model", "load_mjx_model", "load_planar_biped", "model_path",
    "stance_rollout", "touchdown", "with_design",
]
__version__ = "0.1.0"
