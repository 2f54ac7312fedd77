"""Headless animations of a replay (times and qpos) rendered with MuJoCo's own renderer, written as GIF.

No display is needed: the OpenGL context is EGL (Mesa's software device where there is no GPU) or,
failing that, OSMesa; ``MUJOCO_GL`` chooses one of them (or ``glfw``, which needs a display) where set.
The camera follows the model's first body from its left and a little behind (:data:`CAMERA`), so a walk
stays in the picture and both legs show.
"""

from __future__ import annotations

import io
import os
from pathlib import Path

import mujoco
import numpy as np

from biped_jax import checks
from biped_jax.report import outputs

#: Picture size (pixels) and frame rate (frames per second of simulated time) of :func:`write_gif`.
WIDTH, HEIGHT, FPS = 480, 360, 30
#: The camera: distance (m), elevation and azimuth (degrees; 90 looks across the walk from its left,
#: at the sagittal plane; 130 from behind that, so that both legs show).
CAMERA = (1.4, -15.0, 130.0)
_BACKENDS = ("egl", "osmesa", "glfw")


def _gl_context(width: int, height: int):
    """A current OpenGL context of the first backend that starts (``MUJOCO_GL``'s alone where set);
    RuntimeError naming each backend's failure where none does."""
    chosen = os.environ.get("MUJOCO_GL", "").lower().strip()
    failures = []
    for backend in (chosen,) if chosen in _BACKENDS else _BACKENDS[:2]:
        try:
            if backend == "egl":
                from mujoco.egl import GLContext
            elif backend == "osmesa":
                from mujoco.osmesa import GLContext
            else:
                from mujoco.glfw import GLContext
            context = GLContext(width, height)
            context.make_current()
            return context
        except Exception as error:  # noqa: BLE001 - any backend's failure: try the next, report them all
            failures.append(f"{backend}: {type(error).__name__}: {error}")
    raise RuntimeError("no OpenGL context for headless rendering (" + "; ".join(failures) + "); install Mesa's "
                       "EGL (libegl1 with libgl1-mesa-dri) or OSMesa (libosmesa6), or set MUJOCO_GL")


def frame_indices(t: np.ndarray, fps: float) -> np.ndarray:
    """The samples of the replay's times ``t`` (N,), s, nearest to a frame every 1/``fps`` s, (F,)."""
    t = np.asarray(t, dtype=float)
    frames = t[0] + np.arange(int(np.floor((t[-1] - t[0]) * fps + 1e-9)) + 1) / fps
    return np.rint(np.interp(frames, t, np.arange(len(t)))).astype(int)


def render_frames(mj_model: mujoco.MjModel, qpos: np.ndarray, width: int = WIDTH, height: int = HEIGHT,
                  camera=CAMERA) -> np.ndarray:
    """RGB pictures (F, height, width, 3) uint8 of ``mj_model`` at each row of ``qpos`` (F, nq), seen by a
    camera that follows body 1 (``camera`` = distance m, elevation and azimuth deg: :data:`CAMERA`)."""
    qpos = np.asarray(qpos, dtype=float)
    if qpos.ndim != 2 or qpos.shape[1] != mj_model.nq:
        raise ValueError(f"qpos must have shape (frames, {mj_model.nq}), got {qpos.shape}")
    checks.integer_in("width", width, 16, 4096)
    checks.integer_in("height", height, 16, 4096)
    model = mj_model
    model.vis.global_.offwidth, model.vis.global_.offheight = max(width, model.vis.global_.offwidth), max(
        height, model.vis.global_.offheight)
    context = _gl_context(width, height)
    try:
        gpu = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_100)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, gpu)
        scene, option, view = mujoco.MjvScene(model, maxgeom=2000), mujoco.MjvOption(), mujoco.MjvCamera()
        view.type, view.trackbodyid = mujoco.mjtCamera.mjCAMERA_TRACKING, 1
        view.distance, view.elevation, view.azimuth = camera
        viewport = mujoco.MjrRect(0, 0, width, height)
        data = mujoco.MjData(model)
        pictures = np.empty((len(qpos), height, width, 3), np.uint8)
        for i, q in enumerate(qpos):
            data.qpos[:] = q
            mujoco.mj_forward(model, data)
            mujoco.mjv_updateScene(model, data, option, None, view, mujoco.mjtCatBit.mjCAT_ALL, scene)
            mujoco.mjr_render(viewport, scene, gpu)
            mujoco.mjr_readPixels(pictures[i], None, viewport, gpu)
        gpu.free()
    finally:
        context.free()
    return pictures[:, ::-1]  # OpenGL's rows run bottom-up


def write_gif(path: Path, mj_model: mujoco.MjModel, t: np.ndarray, qpos: np.ndarray, fps: float = FPS,
              width: int = WIDTH, height: int = HEIGHT) -> Path:
    """The replay (times ``t`` (N,) s, ``qpos`` (N, nq)) as an animated GIF at ``path``, in real time at
    ``fps`` frames per second (:func:`render_frames`; Pillow shows equal frames in a row as one), written
    atomically; returns ``path``."""
    from PIL import Image
    checks.number_in("fps", fps, 0.0, 100.0, "frames per second")
    t = np.asarray(t, dtype=float)
    if t.ndim != 1 or len(t) != len(qpos) or len(t) == 0 or np.any(np.diff(t) < 0):
        raise ValueError(f"t must be ascending times, one per row of qpos ({len(qpos)}), got shape {t.shape}")
    pictures = render_frames(mj_model, np.asarray(qpos)[frame_indices(t, fps)], width, height)
    images = [Image.fromarray(p) for p in pictures]
    gif = io.BytesIO()
    images[0].save(gif, format="GIF", save_all=True, append_images=images[1:], duration=round(1000.0 / fps),
                   loop=0)
    return outputs.write_bytes(Path(path), gif.getvalue())  # atomically, and listed in a run's manifest
