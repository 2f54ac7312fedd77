"""Headless animations (biped_jax.report.animation): MuJoCo's renderer draws what qpos says, and the GIF
plays the replay in real time."""

import mujoco
import numpy as np
import pytest
from PIL import Image

from biped_jax import cli
from biped_jax.report import animation

#: A grey anchor (body 1, what the camera follows) at the origin and a red ball that slides along x.
SCENE = """
<mujoco>
  <visual><headlight ambient="0.6 0.6 0.6"/></visual>
  <worldbody>
    <body name="anchor"><geom type="box" size="0.02 0.02 0.02" rgba="0.5 0.5 0.5 1"/></body>
    <body name="ball"><joint name="x" type="slide" axis="1 0 0"/>
      <geom type="sphere" size="0.08" rgba="1 0 0 1"/></body>
  </worldbody>
</mujoco>
"""


@pytest.fixture(scope="module")
def rendering():
    """Skips where this machine has no OpenGL for headless rendering (the reason is the error)."""
    try:
        animation._gl_context(16, 16).free()
    except RuntimeError as error:
        pytest.skip(str(error))


def red_columns(picture: np.ndarray) -> np.ndarray:
    """The columns of the red ball's pixels in an RGB picture."""
    red = (picture[..., 0] > 150) & (picture[..., 1] < 80) & (picture[..., 2] < 80)
    return np.nonzero(red)[1]


def test_the_pictures_show_the_ball_where_qpos_puts_it(rendering):
    """Seen from the side, the ball at x = 0 sits on the picture's middle column (the anchor there is
    what the camera follows); at x = -0.3 and +0.3 m it sits on either side, equally far."""
    model = mujoco.MjModel.from_xml_string(SCENE)
    pictures = animation.render_frames(model, np.array([[-0.3], [0.0], [0.3]]), width=160, height=120,
                                       camera=(2.0, 0.0, 90.0))
    assert pictures.shape == (3, 120, 160, 3) and pictures.dtype == np.uint8
    left, centre, right = (red_columns(p) for p in pictures)
    assert min(len(left), len(centre), len(right)) > 50
    assert abs(centre.mean() - 79.5) < 2.0
    assert abs(left.mean() - centre.mean()) > 15.0
    assert np.sign(left.mean() - centre.mean()) == -np.sign(right.mean() - centre.mean())
    assert abs((left.mean() + right.mean()) / 2 - centre.mean()) < 2.0


def test_the_gif_plays_the_replay_in_real_time(rendering, tmp_path):
    """One frame every 1/fps s of the replay's time (the ball moving in every one: Pillow merges equal
    frames), each shown 1/fps s; a replay of the wrong width or
    an unordered time is named before any rendering."""
    model = mujoco.MjModel.from_xml_string(SCENE)
    t = np.linspace(0.0, 1.0, 1001)
    np.testing.assert_array_equal(animation.frame_indices(t, 10.0), np.arange(0, 1001, 100))
    path = animation.write_gif(tmp_path / "ball.gif", model, t, (0.6 * t - 0.3)[:, None], fps=10.0,
                               width=64, height=48)
    with Image.open(path) as gif:
        assert gif.n_frames == 11 and gif.size == (64, 48)
        assert gif.info["duration"] == 100
        gif.seek(0)
        first = np.asarray(gif.convert("RGB"))
        gif.seek(3)  # 0.3 s: the ball at -0.12 m, from -0.3 m at the start
        later = np.asarray(gif.convert("RGB"))
    assert np.abs(first.astype(int) - later).sum() > 0
    with pytest.raises(ValueError, match=r"qpos must have shape \(frames, 1\)"):
        animation.render_frames(model, np.zeros((3, 2)))
    with pytest.raises(ValueError, match="t must be ascending times"):
        animation.write_gif(tmp_path / "bad.gif", model, t[::-1], np.zeros((1001, 1)))


def test_view_renders_a_replay_into_a_gif(rendering, tmp_path, capsys):
    """``biped-jax view donald --replay R.npz --gif G.gif`` writes the animation without a display;
    --gif without --replay is named."""
    from biped_jax import robots
    donald = robots.load_mj_model("donald")
    t = np.linspace(0.0, 0.2, 201)
    qpos = np.tile(donald.qpos0, (len(t), 1))
    qpos[:, -1] += np.linspace(0.0, 0.5, len(t))  # a joint that moves: Pillow merges identical frames
    np.savez(tmp_path / "replay.npz", t=t, qpos=qpos)
    assert cli.main(["view", "donald", "--replay", str(tmp_path / "replay.npz"), "--gif",
                     str(tmp_path / "donald.gif"), "--fps", "20"]) == 0
    with Image.open(tmp_path / "donald.gif") as gif:
        assert gif.n_frames == 5
    assert "5 frames" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        cli.main(["view", "donald", "--gif", str(tmp_path / "x.gif")])
    assert "--gif needs --replay" in capsys.readouterr().err
