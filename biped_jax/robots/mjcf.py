"""MJCF text of every robot variant, generated from one parameter set per robot.

The files under ``models/`` are written by :func:`write_models` and checked against these generators by
the tests, so the pinned-stance and floating-base biped (and every mass variant) can never disagree.
Inertial properties are always explicit (``inertiafromgeom="false"``); geoms are visual unless they
are feet or ground.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from biped_jax.robots.mjcf_text import (
    HEADER,
    NO_CONTACT_FLAGS,
    Part,
    actuators,
    box_geom,
    composite_inertia,
    fmt,
    inertial,
    link_inertial,
)
from biped_jax.robots.specs import (
    KELLY_BIPED,
    PLANAR_12KG,
    PLANAR_18KG,
    DonaldSpec,
    HumanoidSpec,
    PlanarBipedSpec,
    box_inertia,
)


# ----------------------------------------------------------------------------- planar five-link biped


def _planar_inertial(s: PlanarBipedSpec, link: str, z: float) -> str:
    """Inertial of a five-link biped link whose centre of mass lies at height z on the body's axis."""
    return inertial((0, 0, z), getattr(s, f"{link}_mass"), s.link_inertia(link))


def planar_pinned_xml(spec: PlanarBipedSpec, name: str, timestep: float = 0.005) -> str:
    """The single-support chain: stance foot pinned at the world origin by the ``stance`` hinge.

    Coordinates (qpos order): stance (absolute pitch of the stance shank, 0 = upright, positive leaning
    forward), knee1, hip1, hip2, knee2. The stance knee and hip joints have axis -y so that every
    coordinate is the relative angle of docs/gait-problem.md (hip i: thigh relative to torso; knee i: shank
    relative to thigh, flexion positive) even though the chain runs from the foot up.
    """
    s = spec
    half_shank, half_thigh = s.shank_length / 2, s.thigh_length / 2
    return HEADER.format(name=name, timestep=timestep, gz=-s.gravity, option_extra="",
                          flags=NO_CONTACT_FLAGS, floor_contact="") + f"""\
    <body name="shank1">
      <joint name="stance"/>
      {_planar_inertial(s, "shank", s.shank_length - s.link_com("shank"))}
      {box_geom(s.shank_box, (0, 0, half_shank), "0.3 0.5 0.8 1")}
      <site name="foot1"/>
      <body name="thigh1" pos="0 0 {s.shank_length:.10g}">
        <joint name="knee1" axis="0 -1 0"/>
        {_planar_inertial(s, "thigh", s.thigh_length - s.link_com("thigh"))}
        {box_geom(s.thigh_box, (0, 0, half_thigh), "0.3 0.5 0.8 1")}
        <site name="knee1"/>
        <body name="torso" pos="0 0 {s.thigh_length:.10g}">
          <joint name="hip1" axis="0 -1 0"/>
          {_planar_inertial(s, "torso", s.link_com("torso"))}
          {box_geom(s.torso_box, (0, 0, s.torso_length / 2))}
          <site name="hip"/>
          <body name="thigh2">
            <joint name="hip2"/>
            {_planar_inertial(s, "thigh", -s.link_com("thigh"))}
            {box_geom(s.thigh_box, (0, 0, -half_thigh), "0.8 0.5 0.3 1")}
            <body name="shank2" pos="0 0 {-s.thigh_length:.10g}">
              <joint name="knee2"/>
              {_planar_inertial(s, "shank", -s.link_com("shank"))}
              {box_geom(s.shank_box, (0, 0, -half_shank), "0.8 0.5 0.3 1")}
              <site name="knee2"/>
              <site name="foot2" pos="0 0 {-s.shank_length:.10g}"/>
            </body>
          </body>
        </body>
      </body>
    </body>
  </worldbody>
{_PLANAR_ACTUATORS}</mujoco>
"""


_PLANAR_ACTUATORS = actuators([("H1", "hip1"), ("K1", "knee1"), ("H2", "hip2"), ("K2", "knee2")])


def _planar_leg(s: PlanarBipedSpec, leg: int, rgba: str) -> str:
    half_shank, half_thigh = s.shank_length / 2, s.thigh_length / 2
    return f"""\
      <body name="thigh{leg}">
        <joint name="hip{leg}"/>
        {_planar_inertial(s, "thigh", -s.link_com("thigh"))}
        {box_geom(s.thigh_box, (0, 0, -half_thigh), rgba)}
        <body name="shank{leg}" pos="0 0 {-s.thigh_length:.10g}">
          <joint name="knee{leg}"/>
          {_planar_inertial(s, "shank", -s.link_com("shank"))}
          {box_geom(s.shank_box, (0, 0, -half_shank), rgba)}
          <site name="knee{leg}"/>
          <site name="foot{leg}" pos="0 0 {-s.shank_length:.10g}"/>
        </body>
      </body>
"""


def planar_floating_xml(spec: PlanarBipedSpec, name: str, timestep: float = 0.005) -> str:
    """The floating-base planar biped for the impact map and the ground reaction.

    Coordinates (qpos order): rootx, rootz (hip position, m), pitch (torso, rad), hip1, knee1, hip2,
    knee2 (relative angles as in :func:`planar_pinned_xml`).
    """
    s = spec
    stand = s.thigh_length + s.shank_length
    return HEADER.format(name=name, timestep=timestep, gz=-s.gravity, option_extra="",
                          flags=NO_CONTACT_FLAGS, floor_contact="") + f"""\
    <body name="torso">
      <joint name="rootx" type="slide" axis="1 0 0"/>
      <joint name="rootz" type="slide" axis="0 0 1"/>
      <joint name="pitch"/>
      {_planar_inertial(s, "torso", s.link_com("torso"))}
      {box_geom(s.torso_box, (0, 0, s.torso_length / 2))}
      <site name="hip"/>
{_planar_leg(s, 1, "0.3 0.5 0.8 1")}{_planar_leg(s, 2, "0.8 0.5 0.3 1")}    </body>
  </worldbody>
{_PLANAR_ACTUATORS}  <keyframe>
    <key name="stand" qpos="0 {stand:.10g} 0 0 0 0 0"/>
  </keyframe>
</mujoco>
"""


# ----------------------------------------------------------------------------- 16-DoF humanoid

def _humanoid_leg(h: HumanoidSpec, side: str, y: float) -> str:
    s = h.planar
    half_shank, half_thigh = s.shank_length / 2, s.thigh_length / 2
    if h.foot == "point":
        r = h.point_foot_radius
        # The sphere's lowest point is the shank's end, where the planar model has its point foot.
        foot_inertial = inertial((0, 0, 0), h.point_foot_mass, [0.4 * h.point_foot_mass * r * r] * 3)
        foot_geom = (f'<geom name="foot_{side}" type="sphere" size="{r:.10g}" pos="0 0 {r:.10g}" '
                     f'contype="1" conaffinity="1" condim="3" friction="0.8" rgba="0.2 0.2 0.2 1"/>')
    else:
        size = np.asarray(h.flat_foot_size)
        centre = (0.25 * size[0] - 0.02, 0, -size[2] / 2)
        foot_inertial = link_inertial(h.flat_foot_mass, size, centre)
        foot_geom = (f'<geom name="foot_{side}" type="box" size="{fmt(size / 2)}" pos="{fmt(centre)}" '
                     f'contype="1" conaffinity="1" condim="3" friction="0.8" rgba="0.2 0.2 0.2 1"/>')
    return f"""\
      <body name="thigh_{side}" pos="0 {y:.10g} 0">
        <joint name="hip_yaw_{side}" axis="0 0 1"/>
        <joint name="hip_roll_{side}" axis="1 0 0"/>
        <joint name="hip_pitch_{side}" axis="0 1 0"/>
        {link_inertial(s.thigh_mass, s.thigh_box, (0, 0, -half_thigh))}
        {box_geom(s.thigh_box, (0, 0, -half_thigh))}
        <body name="shank_{side}" pos="0 0 {-s.thigh_length:.10g}">
          <joint name="knee_{side}" axis="0 1 0"/>
          {link_inertial(s.shank_mass, s.shank_box, (0, 0, -half_shank))}
          {box_geom(s.shank_box, (0, 0, -half_shank))}
          <body name="foot_{side}" pos="0 0 {-s.shank_length:.10g}">
            <joint name="ankle_pitch_{side}" axis="0 1 0"/>
            <joint name="ankle_roll_{side}" axis="1 0 0"/>
            {foot_inertial}
            {foot_geom}
            <site name="foot_{side}"/>
          </body>
        </body>
      </body>
"""


def _humanoid_arm(h: HumanoidSpec, side: str, y: float) -> str:
    s = h.planar
    length, r = h.arm_length, h.arm_radius
    inertia = (h.arm_mass * length**2 / 12, h.arm_mass * length**2 / 12, 0.5 * h.arm_mass * r * r)
    return f"""\
      <body name="arm_{side}" pos="0 {y:.10g} {s.torso_length - h.shoulder_inset:.10g}">
        <joint name="shoulder_pitch_{side}" axis="0 1 0"/>
        <joint name="shoulder_roll_{side}" axis="1 0 0"/>
        {inertial((0, 0, -length / 2), h.arm_mass, inertia)}
        <geom type="capsule" size="{r:.10g}" fromto="0 0 0 0 0 {-length:.10g}"/>
      </body>
"""


HUMANOID_ACTUATED_JOINTS = tuple(
    f"{joint}_{side}" for side in ("l", "r")
    for joint in ("hip_yaw", "hip_roll", "hip_pitch", "knee", "ankle_pitch", "ankle_roll")
) + tuple(f"{joint}_{side}" for side in ("l", "r") for joint in ("shoulder_pitch", "shoulder_roll"))


def humanoid_xml(spec: HumanoidSpec, name: str, timestep: float = 0.002) -> str:
    """The 16-DoF humanoid with a free-floating torso; leg "l" (y > 0) is the planar model's leg 1.

    The torso frame sits at the hip centre (bottom centre of the torso box), as in the planar model.
    """
    s = spec.planar
    torso_core = link_inertial(spec.torso_core_mass, s.torso_box, (0, 0, s.torso_length / 2))
    shoulder_y = s.torso_width / 2 + spec.arm_radius
    foot_drop = 0.0 if spec.foot == "point" else spec.flat_foot_size[2]
    stand = s.thigh_length + s.shank_length + foot_drop
    return HEADER.format(name=name, timestep=timestep, gz=-s.gravity, option_extra="",
                          flags="", floor_contact=' contype="1" conaffinity="1"') + f"""\
    <body name="torso" pos="0 0 {stand:.10g}">
      <freejoint name="root"/>
      {torso_core}
      {box_geom(s.torso_box, (0, 0, s.torso_length / 2))}
      <geom name="head" type="sphere" size="0.06" pos="0 0 {s.torso_length + 0.06:.10g}"/>
      <site name="hip"/>
{_humanoid_leg(spec, "l", spec.hip_half_width)}{_humanoid_leg(spec, "r", -spec.hip_half_width)}\
{_humanoid_arm(spec, "l", shoulder_y)}{_humanoid_arm(spec, "r", -shoulder_y)}    </body>
  </worldbody>
{actuators((j, j) for j in HUMANOID_ACTUATED_JOINTS)}</mujoco>
"""


# ----------------------------------------------------------------------------- DONALD

DONALD_ACTUATED_JOINTS = ("ankle1", "hip1", "hip2", "ankle2", "pendulum")


def donald_xml(spec: DonaldSpec, name: str = "donald", timestep: float = 0.002) -> str:
    """DONALD: pelvis (two hip modules, free base), two kneeless legs with roll ankles and flat feet,
    and a sideways inverted pendulum at the hips. Leg 1 is on the left (y > 0).
    """
    d = spec
    module = d.joint_module_mass
    module_inertia = box_inertia(module, (0.05, 0.05, 0.05))  # a 5 cm module (ours)
    pelvis_mass, pelvis_com, pelvis_inertia = composite_inertia([
        Part(module, (0, y, 0), module_inertia) for y in (d.hip_half_width, -d.hip_half_width)])
    ankle_height = 0.04  # ankle axis above the foot plate's top (ours)
    plate_centre = (0.0, 0.0, -ankle_height - d.foot_size[2] / 2)
    foot_mass, foot_com, foot_inertia = composite_inertia([
        Part(module, (0, 0, 0), module_inertia),
        Part(d.foot_mass, plate_centre, box_inertia(d.foot_mass, d.foot_size))])
    link_inertia = (d.link_mass * d.link_length**2 / 12, d.link_mass * d.link_length**2 / 12, 1e-6)
    r_bob = 0.03
    bob_inertia = [0.4 * d.pendulum_mass * r_bob**2] * 3
    hip_height = d.link_length + ankle_height + d.foot_size[2]

    def leg(k: int, y: float) -> str:
        return f"""\
      <body name="leg{k}" pos="0 {y:.10g} 0">
        <joint name="hip{k}" axis="0 1 0"/>
        {inertial((0, 0, -d.link_length / 2), d.link_mass, link_inertia)}
        <geom type="capsule" size="0.012" fromto="0 0 0 0 0 {-d.link_length:.10g}"/>
        <body name="foot{k}" pos="0 0 {-d.link_length:.10g}">
          <joint name="ankle{k}" axis="1 0 0"/>
          {inertial(foot_com, foot_mass, foot_inertia)}
          <geom type="box" size="0.025 0.025 0.025" rgba="0.3 0.3 0.3 1"/>
          <geom name="foot{k}" type="box" size="{fmt(np.asarray(d.foot_size) / 2)}" \
pos="{fmt(plate_centre)}" contype="1" conaffinity="1" condim="3" friction="{d.friction:.10g}" \
rgba="0.2 0.2 0.2 1"/>
          <site name="foot{k}" pos="0 0 {-ankle_height - d.foot_size[2]:.10g}"/>
        </body>
      </body>
"""

    return HEADER.format(name=name, timestep=timestep, gz=-9.81, option_extra="",
                          flags="", floor_contact=' contype="1" conaffinity="1"') + f"""\
    <body name="pelvis" pos="0 0 {hip_height:.10g}">
      <freejoint name="root"/>
      {inertial(pelvis_com, pelvis_mass, pelvis_inertia)}
      <geom type="box" size="0.025 {d.hip_half_width + 0.025:.10g} 0.025" rgba="0.3 0.3 0.3 1"/>
      <body name="pendulum">
        <joint name="pendulum" axis="1 0 0"/>
        {inertial((0, 0, d.pendulum_length), d.pendulum_mass, bob_inertia)}
        <geom type="capsule" size="0.006" fromto="0 0 0 0 0 {d.pendulum_length:.10g}"/>
        <geom type="sphere" size="{r_bob}" pos="0 0 {d.pendulum_length:.10g}" rgba="0.8 0.3 0.2 1"/>
      </body>
{leg(1, d.hip_half_width)}{leg(2, -d.hip_half_width)}    </body>
  </worldbody>
{actuators((j, j) for j in DONALD_ACTUATED_JOINTS)}</mujoco>
"""


# ----------------------------------------------------------------------------- the files

def model_sources() -> dict[str, str]:
    """MJCF text of every file under ``models/``, keyed by file name."""
    sources = {}
    for mass, spec in (("12kg", PLANAR_12KG), ("18kg", PLANAR_18KG)):
        sources[f"biped5_pinned_{mass}.xml"] = planar_pinned_xml(spec, f"biped5_pinned_{mass}")
        sources[f"biped5_floating_{mass}.xml"] = planar_floating_xml(spec, f"biped5_floating_{mass}")
        sources[f"humanoid16_{mass}.xml"] = humanoid_xml(HumanoidSpec(planar=spec), f"humanoid16_{mass}")
        sources[f"humanoid16_flatfoot_{mass}.xml"] = humanoid_xml(
            HumanoidSpec(planar=spec, foot="flat"), f"humanoid16_flatfoot_{mass}")
    sources["biped5_pinned_kelly.xml"] = planar_pinned_xml(KELLY_BIPED, "biped5_pinned_kelly")
    sources["biped5_floating_kelly.xml"] = planar_floating_xml(KELLY_BIPED, "biped5_floating_kelly")
    sources["donald.xml"] = donald_xml(DonaldSpec())
    return sources


def write_models(directory: Path) -> list[Path]:
    """Writes every MJCF file of :func:`model_sources` into ``directory``; returns the paths."""
    directory.mkdir(parents=True, exist_ok=True)
    paths = []
    for file_name, text in model_sources().items():
        path = directory / file_name
        path.write_text(text)
        paths.append(path)
    return paths


if __name__ == "__main__":
    for written in write_models(Path(__file__).resolve().parents[2] / "models"):  # the source tree's models/
        print(written)
