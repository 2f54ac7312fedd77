"""The robot registry: model names, their MJCF files, and loading into MuJoCo and MJX."""

from __future__ import annotations

import contextlib
import io
from pathlib import Path

import mujoco

#: Model name -> (file, one-line description). Names are what the CLI and `load_*` accept.
ROBOTS: dict[str, tuple[str, str]] = {
    "biped5_pinned_12kg": ("biped5_pinned_12kg.xml", "five-link biped, stance foot pinned, 12 kg"),
    "biped5_pinned_18kg": ("biped5_pinned_18kg.xml", "five-link biped, stance foot pinned, 18 kg"),
    "biped5_floating_12kg": ("biped5_floating_12kg.xml", "five-link biped, floating planar base, 12 kg"),
    "biped5_floating_18kg": ("biped5_floating_18kg.xml", "five-link biped, floating planar base, 18 kg"),
    "biped5_pinned_kelly": ("biped5_pinned_kelly.xml",
                            "Kelly's five-link biped (SIAM Review 2017), stance foot pinned"),
    "biped5_floating_kelly": ("biped5_floating_kelly.xml",
                              "Kelly's five-link biped (SIAM Review 2017), floating planar base"),
    "humanoid16_12kg": ("humanoid16_12kg.xml", "16-DoF humanoid, point feet, 12 kg"),
    "humanoid16_18kg": ("humanoid16_18kg.xml", "16-DoF humanoid, point feet, 18 kg"),
    "humanoid16_flatfoot_12kg": ("humanoid16_flatfoot_12kg.xml", "16-DoF humanoid, flat feet, 12 kg"),
    "humanoid16_flatfoot_18kg": ("humanoid16_flatfoot_18kg.xml", "16-DoF humanoid, flat feet, 18 kg"),
    "donald": ("donald.xml", "DONALD, the 4-DoF prototype with a sideways pendulum"),
}

#: Parameter sets of the sagittal biped: the paper's two mass classes (Table 2) and Kelly's benchmark.
PLANAR_MASS_CLASSES = ("12kg", "18kg", "kelly")


def models_dir() -> Path:
    """Folder holding the MJCF files: inside the installed package, else the source tree's models/."""
    package = Path(__file__).resolve().parent.parent  # biped_jax/
    for candidate in (package / "models", package.parent / "models"):
        if (candidate / "donald.xml").is_file():
            return candidate
    raise FileNotFoundError(f"no MJCF folder found next to {package}; reinstall biped-jax")


def model_path(name: str) -> Path:
    """Path of the MJCF file of robot ``name`` (a key of :data:`ROBOTS`)."""
    if name not in ROBOTS:
        raise ValueError(f"unknown model name {name!r}; known models: {', '.join(ROBOTS)}")
    return models_dir() / ROBOTS[name][0]


def load_mj_model_from_path(path: str | Path) -> mujoco.MjModel:
    """Compiles an MJCF file, turning MuJoCo's parse errors into one naming the file."""
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"MJCF file {str(path)!r} is a folder, not a file")
    if not path.is_file():
        raise FileNotFoundError(f"MJCF file {str(path)!r} does not exist")
    try:
        return mujoco.MjModel.from_xml_path(str(path))
    except ValueError as error:
        raise ValueError(f"malformed MJCF file {str(path)!r}: {error}") from error


def load_mj_model(name: str) -> mujoco.MjModel:
    """MuJoCo (C) model of robot ``name``."""
    return load_mj_model_from_path(model_path(name))


def put_mjx_model(mj_model: mujoco.MjModel):
    """The MJX model (JAX implementation, the one with autodiff) of a MuJoCo model.

    Its arrays are left uncommitted to a device, like every array made by ``jnp.array``: ``mjx.put_model``
    commits them, and jit compiles a second program (another persistent-cache entry) for the same
    computation when committed and uncommitted arguments meet in other combinations (a rollout of
    ``with_timestep(model, dt)``, a touchdown from a rollout's end state)."""
    import jax
    import jax.numpy as jnp
    import numpy as np
    mjx = import_mjx()
    model = mjx.put_model(mj_model, impl="jax")
    return jax.tree.map(lambda x: jnp.asarray(np.asarray(x)) if isinstance(x, jax.Array) else x, model)


def load_mjx_model(name: str):
    """MJX model of robot ``name``; dtype follows JAX's x64 setting at call time."""
    return put_mjx_model(load_mj_model(name))


def import_mjx():
    """Imports ``mujoco.mjx`` without the 'Failed to import warp' lines it prints when the optional
    Warp backend is absent (we use the JAX implementation only)."""
    with contextlib.redirect_stdout(io.StringIO()):
        from mujoco import mjx
    return mjx


def jax_fields(data):
    """The fields MJX's JAX implementation keeps beside the public ``mjx.Data`` (the constraint rows'
    Jacobian and forces, subtree momenta, body forces): private in mujoco-mjx 3.x (``Data._impl``), so read
    here only; a named error where a MuJoCo version keeps them elsewhere."""
    try:
        return data._impl
    except AttributeError:
        raise RuntimeError(f"this mujoco-mjx ({mujoco.__version__}) keeps no implementation fields at "
                           "Data._impl, which biped_jax reads for contact forces and momenta; use mujoco-mjx "
                           "3.x") from None
