"""Geometry and mass data of the three robots, with their provenance.

Every number that reaches an MJCF file starts here. Values marked ``paper`` come from the seed paper
(Tables 1, 2 and 7); values marked ``ours`` are choices the paper leaves open (see README, "Models").
All lengths in m, masses in kg, inertias in kg m^2.
"""

from __future__ import annotations

import dataclasses
import math

GRAVITY = 9.81  # m/s^2, docs/gait-problem.md
#: Section width of thigh and shank boxes, and the torso's depth; docs/gait-problem.md (paper Table 1).
LINK_SECTION = 0.1


def _require_positive(**values: float) -> None:
    """Raises ValueError naming the first value that is not a finite positive number."""
    for name, value in values.items():
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be a positive finite number, got {value!r}")


def box_inertia(mass: float, size: tuple[float, float, float]) -> tuple[float, float, float]:
    """Principal inertia of a uniform solid box about its centre.

    Args:
      mass: kg.
      size: full edge lengths (x, y, z), m.

    Returns:
      (I_xx, I_yy, I_zz), kg m^2.
    """
    x, y, z = size
    return (mass * (y**2 + z**2) / 12, mass * (x**2 + z**2) / 12, mass * (x**2 + y**2) / 12)


@dataclasses.dataclass(frozen=True)
class PlanarBipedSpec:
    """The sagittal five-link biped of docs/gait-problem.md (uniform solid boxes).

    Attributes:
      torso_mass, thigh_mass, shank_mass: kg per link (paper Table 2).
      torso_length: m, hip to top of torso (paper Table 1, d_z).
      thigh_length, shank_length: m, along the link (paper Table 1, d_x).
      torso_width: m, lateral size of the torso box (paper Table 1, d_y); no effect in the plane.
      gravity: m/s^2.
      shank_com, thigh_com, torso_com: distance of the link's centre of mass from the knee (shank),
        the hip (thigh) and the hip (torso), m; None puts it in the middle of the box.
      shank_inertia, thigh_inertia, torso_inertia: pitch inertia about the centre of mass, kg m^2
        (used for all three principal axes); None takes the uniform box's.
    """

    torso_mass: float = 7.355
    thigh_mass: float = 1.161
    shank_mass: float = 1.161
    torso_length: float = 0.385
    thigh_length: float = 0.14
    shank_length: float = 0.15
    torso_width: float = 0.25
    gravity: float = GRAVITY
    shank_com: float | None = None
    thigh_com: float | None = None
    torso_com: float | None = None
    shank_inertia: float | None = None
    thigh_inertia: float | None = None
    torso_inertia: float | None = None

    def __post_init__(self):
        _require_positive(**{k: v for k, v in dataclasses.asdict(self).items() if v is not None})
        for link in ("shank", "thigh", "torso"):
            com, length = getattr(self, f"{link}_com"), getattr(self, f"{link}_length")
            if com is not None and com >= length:
                raise ValueError(f"{link}_com {com} m lies beyond the link's length {length} m")

    @property
    def leg_length(self) -> float:
        """Hip to foot with the knee straight, m."""
        return self.thigh_length + self.shank_length

    def link_com(self, link: str) -> float:
        """Centre of mass of ``link`` (shank, thigh, torso) from its upper (shank: knee; thigh, torso:
        hip) joint, m."""
        com = getattr(self, f"{link}_com")
        return getattr(self, f"{link}_length") / 2 if com is None else com

    def link_inertia(self, link: str) -> tuple[float, float, float]:
        """Principal inertia of ``link`` about its centre of mass, kg m^2."""
        pitch = getattr(self, f"{link}_inertia")
        mass = getattr(self, f"{link}_mass")
        return box_inertia(mass, getattr(self, f"{link}_box")) if pitch is None else (pitch,) * 3

    @property
    def total_mass(self) -> float:
        return self.torso_mass + 2 * self.thigh_mass + 2 * self.shank_mass

    @property
    def torso_box(self) -> tuple[float, float, float]:
        return (LINK_SECTION, self.torso_width, self.torso_length)

    @property
    def thigh_box(self) -> tuple[float, float, float]:
        return (LINK_SECTION, LINK_SECTION, self.thigh_length)

    @property
    def shank_box(self) -> tuple[float, float, float]:
        return (LINK_SECTION, LINK_SECTION, self.shank_length)


#: Paper Table 2.
PLANAR_12KG = PlanarBipedSpec()
PLANAR_18KG = PlanarBipedSpec(torso_mass=11.03, thigh_mass=1.742, shank_mass=1.742)
#: Kelly's five-link biped (M. Kelly, SIAM Review 59(4), 2017, Section 7 and its OptimTraj code):
#: a public trajectory-optimisation benchmark, used to validate the gait optimiser.
KELLY_BIPED = PlanarBipedSpec(
    torso_mass=20.0, thigh_mass=6.8, shank_mass=3.2, torso_length=0.625, thigh_length=0.4,
    shank_length=0.4, shank_com=0.128, thigh_com=0.163, torso_com=0.425, shank_inertia=0.93,
    thigh_inertia=1.08, torso_inertia=2.22)
#: Parameter sets of the sagittal biped by name: the paper's two mass classes and Kelly's benchmark.
PLANAR_SPECS = {"12kg": PLANAR_12KG, "18kg": PLANAR_18KG, "kelly": KELLY_BIPED}


@dataclasses.dataclass(frozen=True)
class HumanoidSpec:
    """The 16-DoF humanoid of docs/models.md (paper Fig. 1, Tables 1-2).

    The torso of Table 2 lumps arms and head; ``arm_mass`` per arm is taken out of it so the total stays.

    Attributes:
      planar: link masses and lengths shared with the sagittal model.
      hip_half_width: m, lateral offset of each hip from the mid-plane (docs/models.md).
      arm_mass, arm_length: kg and m per arm (docs/models.md).
      arm_radius: m, capsule radius of an arm (ours).
      shoulder_inset: m, shoulder joint below the torso's top (ours).
      foot: "point" (sphere at the shank end, as the paper) or "flat" (box foot, the paper's next step).
      point_foot_radius, point_foot_mass: m and kg; the point foot is nearly massless (ours).
      flat_foot_size, flat_foot_mass: m (x, y, z) and kg of the optional foot box (ours).
    """

    planar: PlanarBipedSpec = PLANAR_12KG
    hip_half_width: float = 0.065
    arm_mass: float = 0.3
    arm_length: float = 0.25
    arm_radius: float = 0.02
    shoulder_inset: float = 0.03
    foot: str = "point"
    point_foot_radius: float = 0.01
    point_foot_mass: float = 1e-4
    flat_foot_size: tuple[float, float, float] = (0.16, 0.09, 0.02)
    flat_foot_mass: float = 0.2

    def __post_init__(self):
        _require_positive(hip_half_width=self.hip_half_width, arm_mass=self.arm_mass,
                          arm_length=self.arm_length, arm_radius=self.arm_radius,
                          point_foot_radius=self.point_foot_radius,
                          point_foot_mass=self.point_foot_mass, flat_foot_mass=self.flat_foot_mass)
        if self.foot not in ("point", "flat"):
            raise ValueError(f"foot must be 'point' or 'flat', got {self.foot!r}")
        if 2 * self.arm_mass >= self.planar.torso_mass:
            raise ValueError(f"arm_mass {self.arm_mass} leaves no torso mass out of "
                             f"{self.planar.torso_mass}")

    @property
    def torso_core_mass(self) -> float:
        """Torso without arms, kg (head stays lumped into the torso, as in Table 2)."""
        return self.planar.torso_mass - 2 * self.arm_mass


@dataclasses.dataclass(frozen=True)
class DonaldSpec:
    """DONALD, the 4-DoF prototype (paper Section 3, Table 7; docs/models.md).

    Attributes:
      link_length, link_mass: leg lever arm, m and kg (Table 7).
      foot_size: foot plate (x, y, z), m; 100 x 160 mm in Table 7, the 160 mm taken along x (ours),
        thickness ours.
      foot_mass: kg (Table 7).
      module_mass: motor + gear + encoder per joint, kg (Table 7).
      base_plate_mass: per joint, kg (Table 7).
      gear_ratio: GP 32 A four-stage ratio (Table 7; catalogue 245.96).
      hip_half_width: m, lateral offset of each hip joint from the mid-plane (ours).
      pendulum_mass, pendulum_length: kg and m of the sideways inverted pendulum (docs/models.md).
      friction: sliding friction coefficient of foot on ground (ours).
    """

    link_length: float = 0.28
    link_mass: float = 0.103
    foot_size: tuple[float, float, float] = (0.16, 0.10, 0.01)
    foot_mass: float = 0.57
    module_mass: float = 0.376
    base_plate_mass: float = 0.137
    gear_ratio: float = 245.96
    hip_half_width: float = 0.055
    pendulum_mass: float = 0.4
    pendulum_length: float = 0.2
    friction: float = 0.8

    def __post_init__(self):
        _require_positive(link_length=self.link_length, link_mass=self.link_mass,
                          foot_mass=self.foot_mass, module_mass=self.module_mass,
                          base_plate_mass=self.base_plate_mass, gear_ratio=self.gear_ratio,
                          hip_half_width=self.hip_half_width, pendulum_mass=self.pendulum_mass,
                          pendulum_length=self.pendulum_length, friction=self.friction)
        for k, size in enumerate(self.foot_size):
            _require_positive(**{f"foot_size[{k}]": size})

    @property
    def joint_module_mass(self) -> float:
        """One joint module: motor, gear, encoder and base plate, kg."""
        return self.module_mass + self.base_plate_mass
