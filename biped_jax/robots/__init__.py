"""The robots: registry and MJCF files (re-exported here: ``robots.load_mj_model("donald")``),
specifications, MJCF writer, design arrays."""

from biped_jax.robots.registry import (
                                       PLANAR_MASS_CLASSES,
                                       ROBOTS,
                                       import_mjx,
                                       load_mj_model,
                                       load_mj_model_from_path,
                                       load_mjx_model,
                                       model_path,
                                       models_dir,
                                       put_mjx_model,
)

__all__ = ["PLANAR_MASS_CLASSES", "ROBOTS", "import_mjx", "load_mj_model", "load_mj_model_from_path",
           "load_mjx_model", "model_path", "models_dir", "put_mjx_model"]
