"""The tracker of the optimal step on the free-base humanoid: its path stands on a still, flat foot, its
table is read as interpolation would, on the path its law commands the inverse dynamics' torques plus PD,
it lands at the gait's step time, answers a sideways push with a wider step, and one compiled walk serves
every gait of a mass class."""

import dataclasses

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from biped_jax.humanoid import tracker, walk3d, walker
from biped_jax.studies import humanoid as humanoid_study
from biped_jax.studies import paper as study

pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("tracker")]

SECONDS = 0.45  # one compiled chunk of physics steps: the first step and its touchdown
SIDEWAYS = 1.0  # N s, the lateral push: 0.08 m/s on the 12 kg robot


@pytest.fixture(scope="module")
def walkings(paper_solutions, short_solver):
    """M2's and M1's optimal steps at the tests' short horizon, each on the tracker (one mass class)."""
    models = study.paper_gait_models(study.PAPER_MODELS)
    found = {}
    for k, name in ((1, "M2"), (0, "M1")):
        batch = jax.tree.map(lambda a: jnp.asarray(a, dtype=jnp.result_type(float))[None], models[k])
        trajectory = jax.tree.map(lambda a: np.asarray(a[0]), short_solver.simulate(paper_solutions[k].x[None], batch))
        found[name] = humanoid_study.tracker_walking(name, paper_solutions[k].x, short_solver.settings, trajectory)
    return found


def test_the_path_stands_on_a_still_flat_foot_and_lifts_the_other(walkings):
    """At every sample of the path the stance foot's four sole corners are on the ground and the foot does not
    move (MuJoCo C's body velocity); the swing foot's sole is nowhere below the ground."""
    walking = walkings["M2"]
    prog = walk3d.program(walking.mass_class, walking.parallel)
    mj_model, path = prog.mj_model, walking.args.path
    data = mujoco.MjData(mj_model)
    hx, hy, hz = prog.legs.half_foot
    corners = np.array([[sx * hx, sy * hy, -hz] for sx in (-1, 1) for sy in (-1, 1)])
    geom, foot = prog.legs.foot_geoms[0], prog.layout.feet[0]
    for qpos, qvel in zip(np.asarray(path.qpos), np.asarray(path.qvel)):
        data.qpos[:], data.qvel[:] = qpos, qvel
        mujoco.mj_forward(mj_model, data)
        heights = (data.geom_xpos[geom] + corners @ data.geom_xmat[geom].reshape(3, 3).T)[:, 2]
        np.testing.assert_allclose(heights, 0.0, atol=1e-9)
        velocity = np.zeros(6)
        mujoco.mj_objectVelocity(mj_model, data, mujoco.mjtObj.mjOBJ_BODY, foot, velocity, 0)
        np.testing.assert_allclose(velocity, 0.0, atol=1e-9)
        assert float(walker.sole_heights(prog.legs, data)[1]) >= -1e-9


def test_the_pelvis_sways_over_the_stance_foot_as_a_linear_inverted_pendulum(walkings):
    """The path's pelvis is at y(t) = c (1 - cosh(w (t - T/2)) / cosh(w T/2)) from the stance foot's line
    (c the hip's offset, w = sqrt(g / z), z the centre of mass's height mid-step, read here from MuJoCo C),
    toward the stance foot, on the centre line at both ends of the step."""
    walking = walkings["M2"]
    prog = walk3d.program(walking.mass_class, walking.parallel)
    path = walking.args.path
    qpos, t = np.asarray(path.qpos), np.asarray(path.phase) * walking.step_time
    data = mujoco.MjData(prog.mj_model)
    data.qpos[:] = qpos[len(t) // 2]
    mujoco.mj_kinematics(prog.mj_model, data)
    mujoco.mj_comPos(prog.mj_model, data)
    w, c, half = np.sqrt(9.81 / data.subtree_com[0][2]), prog.legs.hip_y, walking.step_time / 2
    expected = c * (1 - np.cosh(w * (t - half)) / np.cosh(w * half))
    assert expected.max() > 0.01  # a sway worth testing: 2 cm mid-step
    np.testing.assert_allclose(qpos[:, 1], expected, rtol=0.01, atol=2e-4)


def test_the_path_roll_and_yaw_torques_are_mirrored_when_leg_r_stands(walkings):
    """Adding torques to the path's hip-yaw, hip-roll and ankle-roll columns adds them to the command (the
    yaw's times ``yaw_ff``) as they are while leg l stands, and with their sign flipped on the other leg's
    joints while leg r stands (the gait mirrored about the sagittal plane); the other joints' commands do
    not change."""
    walking = walkings["M2"]
    prog = walk3d.program(walking.mass_class, walking.parallel)
    layout, args = prog.layout, walking.args
    lateral = (tracker.HIP_YAW, *tracker.ROLLS)
    joints = [layout.legs[side][joint] for side in (0, 1) for joint in lateral]
    extra = np.zeros(args.path.torque.shape[1])
    extra[joints] = [0.5, 0.7, -0.3, -0.9, 1.1, 0.4]
    share = np.ones_like(extra)
    share[[layout.legs[side][tracker.HIP_YAW] for side in (0, 1)]] = float(args.gains.yaw_ff)
    assert float(args.gains.yaw_ff) > 0.0
    more = dataclasses.replace(args, path=dataclasses.replace(args.path, torque=args.path.torque + extra))
    data, state = walking.start(*walking.start_state)
    swapped = dataclasses.replace(state, memory=dataclasses.replace(state.memory, stance=jnp.asarray(1)))
    for standing, mirrored in ((state, share * extra), (swapped, np.zeros_like(extra))):
        if standing is swapped:
            for side in (0, 1):
                for joint in lateral:
                    k = layout.legs[side][joint]
                    mirrored[layout.legs[1 - side][joint]] = -share[k] * extra[k]
        change = np.asarray(tracker.control(more, prog, data, standing)[0]
                            - tracker.control(args, prog, data, standing)[0])
        np.testing.assert_allclose(change, mirrored, atol=1e-9)


def test_the_table_is_read_as_interpolation_would(walkings):
    """:func:`tracker.at_phase` (one search for every column) equals numpy's interpolation column by column,
    held at the ends."""
    path = walkings["M2"].args.path
    phase = np.asarray(path.phase)
    for s in (-0.1, 0.0, 0.013, 0.3, 0.5, 0.77, 1.0, 1.2):
        row = tracker.at_phase(path, jnp.asarray(s))
        for name in ("qpos", "qvel", "torque"):
            table = np.asarray(getattr(path, name))
            expected = [np.interp(s, phase, table[:, k]) for k in range(table.shape[1])]
            np.testing.assert_allclose(np.asarray(getattr(row, name)), expected, rtol=1e-12, atol=1e-12)


def test_on_the_path_the_law_commands_the_inverse_dynamics_plus_pd(walkings):
    """At the start (on the path, s = 0) every sagittal joint's command is the path's inverse-dynamics
    torque; moving the swing knee by 0.01 rad adds the swing leg's stiffness times -0.01 to its command and
    the ankle's stiffness times -0.01 to the swing ankle's (which keeps the foot level), nothing to the
    other sagittal joints."""
    walking = walkings["M2"]
    prog = walk3d.program(walking.mass_class, walking.parallel)
    layout, args = prog.layout, walking.args
    data, state = walking.start(*walking.start_state)
    command, s = tracker.control(args, prog, data, state)
    assert float(s) == 0.0
    joints = [layout.legs[side][joint] for side in (0, 1) for joint in tracker.SAGITTAL]
    np.testing.assert_allclose(np.asarray(command)[joints], np.asarray(args.path.torque[0])[joints], atol=1e-9)
    knee = layout.legs[1][3]
    bent = data.replace(qpos=data.qpos.at[layout.qpos[knee]].add(0.01))
    moved, _ = tracker.control(args, prog, bent, state)
    change = np.asarray(moved - command)[joints]
    expected = np.zeros(len(joints))
    expected[joints.index(knee)] = -float(args.gains.kp_sw) * 0.01
    expected[joints.index(layout.legs[1][4])] = -float(args.gains.kp_a) * 0.01
    np.testing.assert_allclose(change, expected, atol=1e-9)


def test_the_damping_ramps_in_over_the_impact_time_after_a_touchdown(walkings):
    """A swing knee 0.1 rad/s faster than the path changes the swing knee's command by -kd_sw 0.1 and the swing
    ankle's (which keeps its foot level) by -kd_a 0.1, times t / impact in the first ``impact`` s after the
    touchdown: nothing at the touchdown, half halfway, all after it. With ``impact_kp`` 1 the stance knee's
    stiffness ramps in so too, and with ``impact_kp_t`` 1 the torso's."""
    walking = walkings["M2"]
    prog = walk3d.program(walking.mass_class, walking.parallel)
    layout, args = prog.layout, walking.args
    impact = float(args.gains.impact)
    assert impact > 0.0
    data, state = walking.start(*walking.start_state)
    knee, ankle = layout.legs[1][3], layout.legs[1][4]
    faster = data.replace(qvel=data.qvel.at[layout.qvel[knee]].add(0.1))
    for share in (0.0, 0.5, 1.0, 3.0):
        later = dataclasses.replace(state, memory=dataclasses.replace(state.memory, time=jnp.asarray(share * impact)))
        change = np.asarray(tracker.control(args, prog, faster, later)[0] - tracker.control(args, prog, data, later)[0])
        expected = np.zeros_like(change)
        expected[[knee, ankle]] = -min(share, 1.0) * 0.1 * np.array([float(args.gains.kd_sw), float(args.gains.kd_a)])
        np.testing.assert_allclose(change, expected, atol=1e-9)

    def ramped(field, moved, joint):
        """The command's change from ``field`` 0 to 1 at ``moved`` over the impact (at t = 0, impact / 2,
        impact): only at ``joint``, there the full term, half of it, none."""
        changes = []
        for share in (0.0, 0.5, 1.0):
            later = dataclasses.replace(state, memory=dataclasses.replace(state.memory,
                                                                          time=jnp.asarray(share * impact)))
            yielding, stiff = (dataclasses.replace(args, gains=dataclasses.replace(args.gains, **{field: value}))
                               for value in (1.0, 0.0))
            change = np.asarray(tracker.control(yielding, prog, moved, later)[0]
                                - tracker.control(stiff, prog, moved, later)[0])
            assert np.all(np.delete(change, joint) == 0.0)
            changes.append(change[joint])
        np.testing.assert_allclose(changes[1:], [0.5 * changes[0], 0.0], atol=1e-9)
        return changes[0]

    # the stance knee's stiffness: impact_kp of its kp ramps in the same way (a knee bent off its target)
    stance = layout.legs[int(state.stance)]
    bent = data.replace(qpos=data.qpos.at[layout.qpos[stance[3]]].add(0.02))
    assert abs(ramped("impact_kp", bent, stance[3])) > 0.5  # N m: kp times the bend, none at the touchdown
    # the torso's: impact_kp_t of kp_t, through the stance hip (the torso pitched 0.02 rad off the path)
    turn = np.array([[np.cos(0.02), 0.0, np.sin(0.02)], [0.0, 1.0, 0.0], [-np.sin(0.02), 0.0, np.cos(0.02)]])
    pitched = data.replace(xmat=data.xmat.at[layout.torso].set(data.xmat[layout.torso] @ turn))
    assert abs(ramped("impact_kp_t", pitched, stance[2])) > 0.5 * float(args.gains.kp_t) * 0.02


def test_one_compiled_walk_lands_every_gait_at_its_step_time(walkings):
    """M2's and M1's first steps (0.36 s and 0.48 s; M1 on the untuned :data:`tracker.START` gains) land
    within 10 % of their step time, upright, from one compiled program; a sideways push (+y) while foot r
    swings puts it down further toward +y."""
    landed = {}
    for name, walking in walkings.items():
        record = walk3d.run(walking.law, walking.args, walking.start(*walking.start_state), walking.mass_class,
                            walking.parallel, limit=SECONDS * walking.step_time / 0.36)
        landings = walk3d.touchdowns(record)
        assert len(landings) >= 1 and not walk3d.fallen(record.qpos[:landings[0] + 50]).any()  # up 50 ms after
        assert float(record.t[landings[0]]) == pytest.approx(walking.step_time, rel=0.1)
        landed[name] = record
    walking = walkings["M2"]
    push = walk3d.pushes(0.0, SIDEWAYS, 0.0, 0.05, duration=0.1)
    pushed = walk3d.run(walking.law, walking.args, walking.start(*walking.start_state), walking.mass_class,
                        walking.parallel, push=push, limit=SECONDS)
    first = [run.feet[walk3d.touchdowns(run)[0], 1, 1] for run in (landed["M2"], pushed)]  # foot r's y
    assert first[1] > first[0] + 0.01
    assert walk3d._recorder(walking.mass_class, walking.parallel, tracker.LAW)._cache_size() == 1


def test_bad_gains_are_named():
    with pytest.raises(ValueError, match="fade"):
        dataclasses.replace(tracker.START, fade=0.0)
    with pytest.raises(ValueError, match="kp"):
        dataclasses.replace(tracker.START, kp=float("nan"))
    with pytest.raises(ValueError, match="impact"):
        dataclasses.replace(tracker.START, impact=-0.01)
    with pytest.raises(ValueError, match="impact_kp must be in"):
        dataclasses.replace(tracker.START, impact_kp=1.5)
    with pytest.raises(ValueError, match="impact_kp_t must be in"):
        dataclasses.replace(tracker.START, impact_kp_t=-0.5)


def test_unknown_lateral_numbers_are_named():
    with pytest.raises(ValueError, match="lateral_gian"):
        humanoid_study.tracker_walking("M2", np.zeros(3), None, None, lateral={"lateral_gian": 0.05})


def test_the_walked_step_is_the_models_cleared_step_or_its_optimum(walkings, paper_solutions, short_solver,
                                                                   monkeypatch):
    """``walked_step``: a model without a WALK_GAITS entry (M4), or any model asked for no clearance, walks its
    optimum as given (no lift recorded, no gait record); M2 by default walks its WALK_GAITS step, solved again
    with that clearance and landing bound (here a stand-in solve), tracked with no lift and recorded; asked
    for drive limits the solve gets the walk's drives (two at each hip pitch: twice a knee's gear limit)."""
    optimum, settings = paper_solutions[1].x, short_solver.settings
    trajectory = walkings["M2"].args  # any object: the optimum's trajectory is passed through untouched
    for name, clearance in (("M4", None), ("M2", 0.0)):
        step = humanoid_study.walked_step(name, optimum, settings, trajectory, clearance=clearance)
        assert step.x is optimum and step.trajectory is trajectory and step.settings == settings
        assert step.lift is None and step.gait is None
    asked = {}

    def stand_in(name, x, settings_, clearance, ramp=None, touchdown_speed=None, progress=None, *, drives=None):
        asked.update(name=name, clearance=clearance, touchdown_speed=touchdown_speed, drives=drives)
        return x + 1.0, dataclasses.replace(settings_, swing_clearance=clearance,
                                            touchdown_forward_speed=touchdown_speed), "converged"
    batch = jax.tree.map(lambda a: jnp.asarray(a)[None], study.paper_gait_models(study.PAPER_MODELS)[1])
    simulated = jax.tree.map(lambda a: np.asarray(a[0]), short_solver.simulate(optimum[None], batch))
    monkeypatch.setattr(humanoid_study, "cleared_gait", stand_in)
    monkeypatch.setattr(humanoid_study, "simulated_step", lambda name, x, settings_: simulated)
    step = humanoid_study.walked_step("M2", optimum, settings, trajectory)
    clearance, landing, drive_limits = humanoid_study.WALK_GAITS["M2"]
    assert not drive_limits
    assert asked == {"name": "M2", "clearance": clearance, "touchdown_speed": landing, "drives": None}
    np.testing.assert_array_equal(step.x, optimum + 1.0)
    assert step.settings.swing_clearance == clearance and step.trajectory is simulated and step.lift == 0.0
    assert step.gait["swing_clearance_m"] == clearance and step.gait["touchdown_forward_speed_mps"] == landing
    assert step.gait["status"] == "converged" and step.gait["cost"] == pytest.approx(paper_solutions[1].cost, rel=1e-6)
    # a bound asked for overrides the entry's
    humanoid_study.walked_step("M2", optimum, settings, trajectory, touchdown_speed=0.5)
    assert asked["touchdown_speed"] == 0.5
    step = humanoid_study.walked_step("M2", optimum, settings, trajectory, drive_limits=True,
                                      parallel=("hip_roll", "hip_pitch"))
    assert step.gait["drive_limits"] and asked["clearance"] == clearance
    limit = np.asarray(asked["drives"].gear_torque_limit)  # hip, knee of one leg, then the other
    np.testing.assert_allclose(limit[[0, 2]], 2.0 * limit[[1, 3]])
    one = humanoid_study.planar_walk_drives("M2")  # one drive at M2's hip pitch and knee
    np.testing.assert_allclose(np.asarray(one.gear_torque_limit), limit[1])
    assert np.shape(one.supply_voltage) == ()
