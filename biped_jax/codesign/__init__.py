"""Co-design of gear ratios, windings, link masses and drive placement with the gait, motor in the loop:
the hardware (:mod:`biped_jax.codesign.drive_design`), batched solves, envelope gradients and the
co-optimisation (:mod:`biped_jax.codesign.optimise`, whose names are this package's), and plots
(:mod:`biped_jax.codesign.plots`)."""

from biped_jax.codesign.optimise import *  # noqa: F403  (the co-design's names: optimise.__all__)
from biped_jax.codesign.optimise import __all__  # noqa: F401
