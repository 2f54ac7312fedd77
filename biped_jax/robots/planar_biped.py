"""The sagittal five-link biped's names and index maps, in one place: its coordinates in the pinned
(single-support) and floating (impact) models, the actuated joints' order, the relabelling at
touchdown, its design links and sites. Every module that indexes the biped's arrays takes them from
here."""

import numpy as np

#: Pinned (single-support) coordinates, in qpos order: the stance shank's absolute pitch, then the
#: joints from the stance foot up and down the swing leg.
PINNED_COORDINATES = ("stance", "knee1", "hip1", "hip2", "knee2")
#: Floating-base coordinates: the hip's x, z, the torso's pitch, then the joints leg by leg.
FLOATING_COORDINATES = ("x", "z", "pitch", "hip1", "knee1", "hip2", "knee2")
#: The actuated joints in the order of the torques u.
ACTUATED = ("H1", "K1", "H2", "K2")
N_PINNED, N_FLOATING, N_ACTUATED = 5, 7, 4

#: Pinned coordinates of the actuated joints in (H1, K1, H2, K2) order.
ACTUATED_INDEX = np.array([2, 1, 3, 4])
#: For pinned coordinates 1-4 (knee1, hip1, hip2, knee2): the column of each in (H1, K1, H2, K2) order.
_ACTUATED_OF_PINNED = [list(ACTUATED_INDEX).index(p) for p in range(1, N_PINNED)]


def pinned_coordinates(stance, actuated, xp=np):
    """Pinned coordinates (..., 5) from the stance angle (...) and the actuated joints in (H1, K1, H2, K2)
    order (..., 4): positions, rates or accelerations alike. ``xp``: ``numpy`` or ``jax.numpy``."""
    actuated = xp.asarray(actuated)
    stance = xp.broadcast_to(xp.asarray(stance, dtype=actuated.dtype), actuated.shape[:-1])
    return xp.stack([stance] + [actuated[..., j] for j in _ACTUATED_OF_PINNED], axis=-1)


#: Relabelling in (H1, K1, H2, K2) order: the next step's (H1, K1, H2, K2) is this step's (H2, K2, H1, K1).
SWAP = np.array([2, 3, 0, 1])

#: Floating -> pinned coordinates: stance = pitch + hip1 + knee1; the joint angles copied.
FLOATING_TO_PINNED = np.array([
    [0, 0, 1, 1, 1, 0, 0],
    [0, 0, 0, 0, 1, 0, 0],
    [0, 0, 0, 1, 0, 0, 0],
    [0, 0, 0, 0, 0, 1, 0],
    [0, 0, 0, 0, 0, 0, 1],
], dtype=float)
#: Relabelling swaps (hip1, knee1) with (hip2, knee2) in floating coordinates.
RELABEL = np.array([0, 1, 2, 5, 6, 3, 4])

#: The stance shank's body index in the pinned model (shank1, the chain's first body; checked in the tests).
STANCE_BODY = 1

#: Design links, in the order of ``Design.link_mass``.
PLANAR_LINKS = ("torso", "thigh1", "shank1", "thigh2", "shank2")
#: Actuated joints' names in the MJCF, in the order of u = (H1, K1, H2, K2).
PLANAR_ACTUATED = ("hip1", "knee1", "hip2", "knee2")
#: The link that carries each joint's drive (motor + gear), at the joint: both hip drives sit in the
#: torso, each knee drive at the knee end of its thigh.
PLANAR_DRIVE_MOUNTS = ("torso", "thigh1", "torso", "thigh2")
#: The joint each drive may move toward along the link carrying it (``Design.drive_offset``; a
#: transmission then carries the torque back to its joint): the knee drives up their thighs to the
#: hips; the hip drives, at the hips already, stay.
PLANAR_DRIVE_SHIFTS = ("hip1", "hip1", "hip2", "hip2")

#: Sites the gait's constraints read, in the order of its heights: the swing foot, the hip, the knees.
GAIT_SITES = ("foot2", "hip", "knee1", "knee2")
