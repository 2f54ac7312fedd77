"""The optimal sagittal gait replayed on the 16-DoF humanoid under contact in MJX.

The gait optimiser's step (``biped_jax.gait.problem``: pinned stance foot, rigid impact map) is replayed on the
humanoid with point feet on a ground plane (MuJoCo's soft contacts, friction 0.8). Lateral motion is
held by a planarising constraint: the free base is replaced by a planar one (slide x, slide z, hinge
about y), and the lateral joints, ankles and arms are held at zero by PD loops. The hips and knees run
feed-forward torques from the optimiser plus PD on the optimal joint paths.

The reference is phased by the stance leg's absolute angle theta (the optimiser's unactuated
coordinate), not by time: the joints track b(s(theta)), the hybrid-zero-dynamics form of the gait
(Westervelt et al. 2003), so a late or early step does not drag the swing leg off its path. The
support switches when the swing foot's ground force rises in the second half of the step.

Modules: ``model`` (the planarised humanoid, joint layout), ``reference`` (the gait sampled by phase),
``controller``, ``walk`` (the compiled replay), ``touchdown`` (touchdowns against the
impact map, MuJoCo C), ``report``; their public names are re-exported here. The walk in 3D, each in its
own namespace: ``free_base`` (the free-base flat-foot humanoid with its drives in the loop), ``tracker``
(the law that tracks the optimal step: its own inverse dynamics as feed-forward, phased by the stance
angle), ``walker`` (a foot-placement law from rest), ``walk3d`` (the compiled walk of either law, pushes,
the batched push trial, the walk's measures).
"""

from biped_jax.humanoid.controller import (
    DEFAULT_GAINS,
    OFFSET_FADE,
    Gains,
    Support,
    after_touchdown,
    control,
    phase_of,
    sagittal_state,
    with_gains,
)
from biped_jax.humanoid.model import (
    ANKLE_ARMATURE,
    FOOT_SOLIMP,
    FOOT_SOLREF,
    IMPRATIO,
    SIDES,
    TIMESTEP,
    Layout,
    planarised_humanoid,
    sagittal_columns,
)
from biped_jax.humanoid.reference import (
    CLEARANCE_DAMPING,
    CLEARANCE_RAMP,
    PHASE_REVERSAL,
    PHASE_SAMPLES,
    SWING_CLEARANCE,
    GaitReference,
    clearance_offset,
    gait_reference,
)
from biped_jax.humanoid.walk import (
    CHUNK,
    FALL_HEIGHT,
    TOUCHDOWN_FORCE,
    Replay,
    contact_model,
    fallen,
    initial_state,
    replay,
)
from biped_jax.humanoid.report import applied_torque, walk_report
from biped_jax.humanoid.touchdown import (
    IMPACT_SETTLE,
    STOPPED_FRACTION,
    c_model_with_gains,
    compare_touchdowns,
    isolated_touchdown,
    rigid_impact,
    touchdown_indices,
)

__all__ = [
    "ANKLE_ARMATURE",
    "CHUNK",
    "CLEARANCE_DAMPING",
    "CLEARANCE_RAMP",
    "DEFAULT_GAINS",
    "FALL_HEIGHT",
    "FOOT_SOLIMP",
    "FOOT_SOLREF",
    "Gains",
    "GaitReference",
    "IMPACT_SETTLE",
    "IMPRATIO",
    "Layout",
    "OFFSET_FADE",
    "PHASE_REVERSAL",
    "PHASE_SAMPLES",
    "Replay",
    "SIDES",
    "STOPPED_FRACTION",
    "SWING_CLEARANCE",
    "Support",
    "TIMESTEP",
    "TOUCHDOWN_FORCE",
    "after_touchdown",
    "applied_torque",
    "c_model_with_gains",
    "clearance_offset",
    "compare_touchdowns",
    "contact_model",
    "control",
    "fallen",
    "gait_reference",
    "initial_state",
    "isolated_touchdown",
    "phase_of",
    "planarised_humanoid",
    "replay",
    "rigid_impact",
    "sagittal_columns",
    "sagittal_state",
    "touchdown_indices",
    "walk_report",
    "with_gains",
]
