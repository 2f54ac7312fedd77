"""The 3D walk of the free-base humanoid: momentum under contact and pushes, the drives' clipping, the
controller's answer to a push, one program for every walk, and the walk's measures on known records."""

import dataclasses

import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from biped_jax.drives import model as drive_model
from biped_jax.humanoid import tracker, walk3d, walker

pytestmark = pytest.mark.xdist_group("walk3d")

SECONDS = 0.5  # one compiled chunk of physics steps
SIDEWAYS = 1.0  # N s, the test's lateral push: 0.08 m/s on the 12 kg robot


@pytest.fixture(scope="module")
def walks():
    """Half a second from the start, unpushed and pushed sideways (+y) while the first swing leg (r) is in
    the air; both from the same compiled program."""
    params = walker.WalkerParams()
    push = walk3d.pushes(0.0, SIDEWAYS, 0.0, 0.05, duration=0.1)
    quiet = walk3d.walk(params, "12kg", steps=1, seconds=SECONDS)
    pushed = walk3d.walk(params, "12kg", steps=1, seconds=SECONDS, push=push)
    return params, push, quiet, pushed


def _linear_momentum(mj_model, qpos, qvel):
    data = mujoco.MjData(mj_model)
    data.qpos[:], data.qvel[:] = qpos, qvel
    mujoco.mj_forward(mj_model, data)
    mujoco.mj_subtreeVel(mj_model, data)
    return mj_model.body_subtreemass[0] * data.subtree_linvel[0]


def test_momentum_changes_by_gravity_the_ground_and_the_push(walks):
    """Over the physics steps of the pushed walk the linear momentum changes by dt (m g + the ground's
    force on both feet, as the walk reports them + the push), to 1 % of the weight or of the ground's force
    where larger (0.3 % measured: the Euler step's first-order error)."""
    _, push, _, pushed = walks
    prog = walk3d.program("12kg")
    mj_model, dt = prog.mj_model, float(prog.mj_model.opt.timestep)
    mass = float(mj_model.body_subtreemass[0])
    worst = 0.0
    for k in range(1, len(pushed.t), 7):
        before = _linear_momentum(mj_model, pushed.qpos[k - 1], pushed.qvel[k - 1])
        after = _linear_momentum(mj_model, pushed.qpos[k], pushed.qvel[k])
        force = np.array([0.0, 0.0, -9.81 * mass]) + pushed.foot_force[k].sum(axis=0) + np.asarray(
            push.at(jnp.asarray(pushed.t[k - 1])))
        scale = max(mass * 9.81, float(np.abs(pushed.foot_force[k].sum(axis=0)).max()))
        worst = max(worst, float(np.abs(after - before - dt * force).max()) / (scale * dt))
    assert worst < 0.01
    # the ground carried the robot, and the push acted
    assert pushed.foot_force[..., 2].sum(axis=1).mean() == pytest.approx(mass * 9.81, rel=0.2)


def test_every_torque_is_the_command_clipped_to_the_drive_line(walks):
    """applied = clip(command, the line at the joint's speed before the step), and the line was reached."""
    _, _, quiet, _ = walks
    prog = walk3d.program("12kg")
    speed = quiet.qvel[:-1, list(prog.layout.qvel)]
    low, high = (np.asarray(a) for a in drive_model.torque_limits(prog.drives, jnp.asarray(speed)))
    np.testing.assert_allclose(quiet.applied[1:], np.clip(quiet.command[1:], low, high), atol=1e-12)
    assert np.any(np.abs(quiet.command) > 6.5)  # the controller asked for more than the gear gives
    assert np.abs(quiet.applied).max() <= 6.5 + 1e-12


def test_a_sideways_push_is_answered_by_a_wider_step_to_that_side(walks):
    """Pushed toward +y while the right leg swings, the robot puts that foot down further toward +y than
    unpushed (the foot placement's lateral term), and its pelvis drifts that way."""
    _, _, quiet, pushed = walks
    landings = [walk3d.touchdowns(run) for run in (quiet, pushed)]
    assert all(len(found) >= 1 for found in landings)
    first = [run.feet[found[0], 1, 1] for run, found in zip((quiet, pushed), landings)]  # foot r's y at landing
    assert first[1] > first[0] + 0.01
    assert pushed.qvel[150, 1] > quiet.qvel[150, 1] + 0.05


def test_walks_of_other_gaits_and_batch_members_share_one_program(walks):
    """The recorder served both walks above and a walk at another gait's speed and step time without a
    second compilation; a batch of pushed, disturbed walks is one vmapped program for any pushes."""
    params = walks[0]
    other = dataclasses.replace(params, speed=0.417, step_time=0.48)  # M1's gait
    walk3d.walk(other, "12kg", steps=1, seconds=SECONDS)
    assert walk3d._recorder("12kg", (), walk3d.WALKER)._cache_size() == 1
    prog = walk3d.program("12kg")
    qpos, qvel = walk3d.disturbed_starts(prog, params, 2, seed=3)
    for impulse in (0.0, 40.0):
        batch = [walk3d.pushes(impulse, -impulse, 0.05, 0.15), walk3d.pushes(0.0, 0.0, 0.05, 0.15)]
        stacked = walk3d.Push(*(jnp.stack([getattr(b, field.name) for b in batch])
                                for field in dataclasses.fields(walk3d.Push)))
        up, steps = walk3d.survive(params, stacked, qpos, qvel, 0.4)
        if impulse:  # 40 N s (3 m/s) knocks the first run over; the second walks on
            assert not up[0] and up[1]
        else:
            assert up.all()
    assert walk3d._survivor("12kg", (), walk3d.WALKER, 400)._cache_size() == 1


def _record(stance, feet, force, qpos=None, soles=None):
    n = len(stance)
    qpos = np.tile(np.array([0.0, 0.0, 0.3, 1.0, 0.0, 0.0, 0.0] + [0.0] * 16), (n, 1)) if qpos is None else qpos
    soles = np.zeros((n, 2)) if soles is None else soles
    return walk3d.Walk(t=(np.arange(n) + 1) * 1e-3, qpos=qpos, qvel=np.zeros((n, 22)), command=np.zeros((n, 16)),
                       applied=np.zeros((n, 16)), stance=np.asarray(stance), feet=np.asarray(feet),
                       foot_force=np.asarray(force), soles=np.asarray(soles))


def test_the_measures_find_steps_rebounds_and_slip():
    """A made-up record: four steps of 0.2 s at 0.5 m/s, steps of 0.1 m; at the second landing the foot
    leaves the ground for 5 ms, rising 2 mm (a rebound); at the third the ground's force vanishes for 1 ms
    with the sole still sunk 0.03 mm into it (a contact loss, no rebound); a stance foot slides 4 mm."""
    n, step = 1000, 200
    stance = (np.arange(n) // step) % 2
    feet = np.zeros((n, 2, 3))
    force = np.zeros((n, 2, 3))
    soles = np.full((n, 2), 0.02)  # the swing sole 2 cm up
    qpos = np.tile(np.array([0.0, 0.0, 0.3, 1.0, 0.0, 0.0, 0.0] + [0.0] * 16), (n, 1))
    qpos[:, 0] = 0.5 * (np.arange(n) + 1) * 1e-3
    for k in range(n // step):
        span = slice(k * step, (k + 1) * step)
        foot = k % 2
        feet[span, foot, 0] = 0.1 * k
        force[span, foot, 2] = 120.0
        soles[span, foot] = -5e-5  # the stance sole sunk 0.05 mm
    force[2 * step + 10:2 * step + 15, 0, 2] = 0.0  # the third landing (foot l) leaves the ground ...
    soles[2 * step + 10:2 * step + 15, 0] = np.linspace(5e-4, 2e-3, 5)  # ... rising 2 mm
    force[3 * step + 80, 1, 2] = 0.0  # the fourth landing's force gap: the sole stays in the ground
    soles[3 * step + 80, 1] = -3e-5
    feet[3 * step + 50:4 * step, 1, 0] += 0.004  # foot r slides 4 mm in its stance
    params = dataclasses.replace(walker.WalkerParams(), ramp=0.05, step_time=0.2)
    figures = walk3d.measures(_record(stance, feet, force, qpos, soles), "12kg", params, gait_speed=0.5,
                              gait_step_length=0.1, steady_after=0.0)
    assert figures["steps"] == 4 and not figures["fell"]
    assert figures["speed_ratio"] == pytest.approx(1.0, abs=1e-9)
    assert figures["step_length_ratio"] == pytest.approx(1.0, abs=1e-9)
    assert figures["step_time_s"] == pytest.approx(0.2, abs=1e-9)
    assert figures["rebounds"] == 1 and figures["contact_losses"] == 2
    assert [t["rebound"] for t in figures["touchdowns"]] == [False, True, False, False]
    assert [t["contact_lost"] for t in figures["touchdowns"]] == [False, True, True, False]
    assert figures["touchdowns"][1]["highest_sole_m"] == pytest.approx(2e-3)
    assert figures["touchdowns"][2]["highest_sole_m"] == pytest.approx(-3e-5)
    assert figures["highest_stance_sole_m"] == pytest.approx(2e-3)
    assert figures["touchdowns"][1]["contact_s"] == pytest.approx(0.010, abs=1e-9)
    assert figures["touchdowns"][1]["longest_loss_s"] == pytest.approx(0.005, abs=1e-9)
    assert figures["touchdowns"][2]["longest_loss_s"] == pytest.approx(0.001, abs=1e-9)
    assert figures["longest_contact_loss_s"] == pytest.approx(0.005, abs=1e-9)
    assert figures["slip_max_m"] == pytest.approx(0.004, abs=1e-9)


def test_the_paths_own_torques_are_measured_against_the_drive_line():
    """A made-up path: joint 0 standing still asks twice the drive's stall torque (ratio 2); joint 3 moving at
    10 rad/s asks exactly what the line gives at that speed (ratio 1), less than it gives standing still."""
    prog = walk3d.program("12kg", ())
    high_at = lambda speed: np.asarray(drive_model.torque_limits(prog.drives, jnp.asarray(speed)))[1]  # noqa: E731
    samples = 3
    moving = np.zeros(16)
    moving[3] = 10.0
    qvel = np.zeros((samples, prog.mj_model.nv))
    qvel[2, prog.layout.qvel[3]] = 10.0
    torque = np.zeros((samples, 16))
    torque[1, 0] = 2.0 * high_at(np.zeros(16))[0]
    torque[2, 3] = high_at(moving)[3]
    assert high_at(moving)[3] < high_at(np.zeros(16))[3]
    path = tracker.Path3D(phase=np.linspace(0, 1, samples), qpos=np.zeros((samples, prog.mj_model.nq)), qvel=qvel,
                          torque=torque, pitch=np.zeros(samples))
    ratio = tracker.path_drive_ratio(prog, path)
    assert ratio.shape == (samples, 16)
    assert ratio[1, 0] == pytest.approx(2.0) and ratio[2, 3] == pytest.approx(1.0) and ratio[0].max() == 0.0


def test_bad_input_is_named():
    with pytest.raises(ValueError, match="step_time"):
        walker.WalkerParams(step_time=0.0)
    with pytest.raises(ValueError, match="transfer"):
        walker.WalkerParams(step_time=0.3, transfer=0.3)
    with pytest.raises(ValueError, match="'9kg'"):
        walker.tuned("9kg")
    with pytest.raises(ValueError, match="'9kg'"):
        walk3d.walk_drives("9kg")
    with pytest.raises(ValueError, match="steps"):
        walk3d.walk(walker.WalkerParams(), steps=0)
    with pytest.raises(ValueError, match="duration"):
        walk3d.pushes(1.0, 1.0, 0.1, 0.2, duration=0.0)
    with pytest.raises(ValueError, match="lateral"):
        walk3d.pushes(1.0, float("nan"), 0.1, 0.2)


def test_the_half_fall_impulse_is_where_falls_cross_one_half():
    """A logistic fit on synthetic trials: falls from 1 N s on cross one half near 1 N s; all falling gives
    0 (half fall unpushed), none None (beyond the sweep), most falling from the start 0, not a negative
    impulse."""
    from biped_jax.studies.humanoid import half_fall_impulse
    impulse = np.linspace(0.0, 2.0, 64)
    assert half_fall_impulse(impulse, impulse < 1.0) == pytest.approx(1.0, abs=0.05)
    assert half_fall_impulse(impulse, np.zeros(64, bool)) == 0.0
    assert half_fall_impulse(impulse, np.ones(64, bool)) is None
    mostly_down = np.random.default_rng(0).uniform(size=64) < 0.2 * (1 - impulse / 2)  # 20 % up unpushed
    assert half_fall_impulse(impulse, mostly_down) == 0.0
