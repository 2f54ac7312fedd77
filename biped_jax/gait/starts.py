"""Starting points: the heuristic start families and the projection of a gait between spaces."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
from scipy.interpolate import CubicHermiteSpline

from biped_jax.gait.settings import GaitModel, GaitSettings, GaitTrajectory
from biped_jax.gait.splines import basis, greville, pack, reference, segment_starts
from biped_jax.robots.planar_biped import SWAP

# ----------------------------------------------------------------------------- starting points

@dataclasses.dataclass(frozen=True)
class StartFamily:
    """A family of heuristic gaits: the shape of a start, in the joint space (no solution involved).

    Attributes:
      name: label. swing_lift: how far the swing knee flexes mid-step (rad, roughly). stance_knee:
        flexion of the stance knee mid-stance, rad. torso_pitch: torso lean forward, rad (hips flex by
        it). rate_factor: the stance angle's start rate as a multiple of v / leg length.
        impact_knee: flexion of the stance knee at touchdown, rad (by the mirror, the swing knee's at
        the start), blended linearly in between.
    """

    name: str
    swing_lift: float = 0.5
    stance_knee: float = 0.0
    torso_pitch: float = 0.0
    rate_factor: float = 1.3
    impact_knee: float = 0.0


#: The multistart's families (:func:`initial_guess`), spanning the gait families seen in this problem:
#: stance knee straight or flexed, low or high swing, torso upright or leaning, slow or fast vault.
START_FAMILIES = (
    StartFamily("straight stance"),
    StartFamily("flexed stance", stance_knee=0.25),
    StartFamily("high swing", swing_lift=0.9),
    StartFamily("low swing, fast vault", swing_lift=0.3, rate_factor=1.7),
    StartFamily("leaning torso", torso_pitch=0.15, stance_knee=0.1),
    StartFamily("slow vault, flexed", stance_knee=0.15, swing_lift=0.7, rate_factor=1.0),
)

#: Families that land on a flexed stance knee (``impact_knee``), the axis along which the cheapest gaits
#: of this problem lie: measured on M2 without a power limit (multiple shooting, 16 spans), these three
#: reached J = 2.49-2.73 where every family of :data:`START_FAMILIES` stopped at 4.3-5.2 (README,
#: "Transcription and starts"). The study starts from these and the first of START_FAMILIES.
IMPACT_FAMILIES = (
    StartFamily("flexed stance, flexed impact", stance_knee=0.25, impact_knee=0.45),
    StartFamily("straight stance, flexed impact", impact_knee=0.45),
    StartFamily("high swing, flexed impact", swing_lift=0.9, impact_knee=0.3),
)


def initial_guess(model: GaitModel, settings: GaitSettings, leg_length: float = 0.29,
                  swing_lift: float | None = None, family: StartFamily = START_FAMILIES[0]) -> jax.Array:
    """A heuristic start of ``family``: legs mirrored about the vertical at the ends, the swing knee and
    hip flexed mid-step, the stance knee flexed mid-stance, the stance leg vaulting forward from
    ``-asin(L / 2 l)`` to its mirror along a parabola whose start rate is the family's. The curve is
    sampled at the Greville abscissae, the vault at the shooting nodes (:func:`segment_starts`).
    Shape (settings.size,)."""
    lift = family.swing_lift if swing_lift is None else swing_lift
    stance = -jnp.arcsin(0.5 * model.step_length / leg_length)
    # (H1, K1, H2, K2): a hip angle is the thigh against the torso, so leaning the torso forward by
    # ``torso_pitch`` flexes both hips by it.
    start = jnp.stack([stance, 0.0, -stance, family.impact_knee]) \
        + family.torso_pitch * jnp.array([-1.0, 0.0, -1.0, 0.0])
    end = start[SWAP]
    s = jnp.asarray(greville(settings))[1:, None]
    bump = 4 * s * (1 - s) * (lift * jnp.array([0.0, 0.0, -0.6, 1.0])
                              + family.stance_knee * jnp.array([0.5, 1.0, 0.0, 0.0]))
    coefficients = start + s * (end - start) + bump
    step_time = model.step_length / model.speed
    rate = family.rate_factor * model.speed / leg_length
    # theta(s) = stance (1 - 2 s) + curvature s (1 - s), with theta'(0) = rate t_f
    curvature = rate * step_time + 2 * stance
    knots = jnp.asarray(segment_starts(settings))
    theta = stance * (1 - 2 * knots) + curvature * knots * (1 - knots)
    theta_rate = (-2 * stance + curvature * (1 - 2 * knots)) / step_time
    return pack(jnp.stack([theta, theta_rate], axis=-1), coefficients)


def project(x: np.ndarray, source: GaitSettings, target: GaitSettings, trajectory: GaitTrajectory,
            samples: int = 400) -> np.ndarray:
    """The decision vector of ``source``'s space carried into ``target``'s (continuation from a coarse
    to a fine reference space): the control points by least squares on ``samples`` points (exact when
    the target's breakpoints contain the source's: the same grading, spans a multiple, since the fine
    space then contains the coarse curve), the shooting nodes from ``trajectory`` (x simulated in
    ``source``) by cubic Hermite interpolation of its stance angle and rate at the target's segment
    starts. Shape (target.size,)."""
    x = np.asarray(x, dtype=float)
    s = np.linspace(0.0, 1.0, samples)
    curve = np.asarray(reference(jnp.asarray(x), source, s)[0])
    points = np.linalg.lstsq(basis(target, s)[0], curve, rcond=None)[0]
    points[-1] = 0.5 * (points[-1] + points[0][SWAP])  # keep the mirror exact
    t = np.asarray(trajectory.t)
    # at a segment boundary the grid point carries the next node (the previous segment's end differs
    # from it by the defect); the grid's times are strictly increasing, as the interpolant needs
    angle = CubicHermiteSpline(t, np.asarray(trajectory.q)[:, 0], np.asarray(trajectory.qd)[:, 0])
    rate = CubicHermiteSpline(t, np.asarray(trajectory.qd)[:, 0], np.asarray(trajectory.qdd)[:, 0])
    starts = segment_starts(target) * t[-1]
    nodes = np.stack([angle(starts), rate(starts)], axis=-1)
    nodes[0] = x[:2]
    return np.asarray(pack(nodes, points[1:]))
