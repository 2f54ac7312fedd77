"""biped_jax: design fast-walking legged robots by differentiable simulation (JAX + MuJoCo MJX).

Subpackages in the order of the data flow (README "Module map"): ``robots`` (registry, specifications,
MJCF, design arrays), ``dynamics`` (the walking step behind one interface: MJX, the planar chain in
closed form, MuJoCo C),
``optim`` (the batched interior point and its exact derivatives), ``gait`` (the optimal walking step:
problem, solver, report, heuristic starts, MuJoCo C reference), ``drives`` (motors and gearheads,
drive-train selection), ``codesign``, ``donald``, ``humanoid``, ``studies`` (one module per
command-line study), ``report`` (output files, compile profiles); ``checks`` (input validation) and
``cli`` (the ``biped-jax`` command).

The names below load on first use (PEP 562), so ``import biped_jax`` and the command line's argument
checks do not wait for JAX and MuJoCo to import.
"""

import importlib
import importlib.metadata
import os

#: XLA's CPU runtime can deadlock in its multi-threaded Eigen pool on large vmapped programs (known:
#: openxla/xla and JAX users report the same stacks): the co-design's gait problem in a batch of 48 hung
#: twice in ``block_until_ready`` with every XLA thread idle (2-core CPU, jax 0.10.2, 2026-12-05), and
#: finished in 96 s with the pool off; a batch in 16 lanes took 76.9 s with it off, 75.9 s on. Set on
#: import, before JAX starts its backend (it reads XLA_FLAGS then); a value the user set is kept.
def default_xla_flag(flag: str) -> None:
    """Appends ``flag`` ("--name=value") to XLA_FLAGS unless XLA_FLAGS already names it (the user's choice
    stays); effective only before JAX starts its backend, which reads XLA_FLAGS then."""
    if flag.split("=")[0] not in os.environ.get("XLA_FLAGS", ""):
        os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " " + flag).strip()


default_xla_flag("--xla_cpu_multi_thread_eigen=false")
#: The same kind of hang with the pool off: the gait solver's iterations (8 problems, 48 knot spans, from
#: starts far off the optimum) stopped with every XLA thread idle in 5 runs of 5 with XLA's fusion emitters
#: (the default; fresh compilations and cached ones, sometimes after a few blocks of iterations) and ran to
#: the end in 2 of 2 with its elemental emitters (2-core CPU, jaxlib 0.10.2, 2026-12-06). Only on the jaxlib
#: releases it was measured on (XLA stops at a flag it does not know); a value the user set is kept.
try:
    _JAXLIB = importlib.metadata.version("jaxlib")
except importlib.metadata.PackageNotFoundError:
    _JAXLIB = ""
if _JAXLIB.startswith("0.10."):
    default_xla_flag("--xla_cpu_use_fusion_emitters=false")

_MODULES = {
    "robots.design": ("Design", "apply_design", "check_design", "design_layout"),
    "dynamics.mjx_biped": ("PlanarBiped", "load_planar_biped", "with_design"),
    "dynamics.interface": ("StanceTrajectory", "stance_dynamics", "stance_rollout", "stance_step", "touchdown"),
    "dynamics.impact": ("Touchdown",),
    "robots.registry": ("ROBOTS", "load_mj_model", "load_mjx_model", "model_path"),
    "gait.problem": ("GaitSettings", "gait_model", "START_FAMILIES"),
    "gait.solver": ("GaitSolver", "GaitSolution"),
    "gait.multistart": ("solve_multistart",),
}
_EXPORTS = {name: module for module, names in _MODULES.items() for name in names}

__all__ = sorted(_EXPORTS)
__version__ = "0.1.0"


def __getattr__(name: str):
    if name in _EXPORTS:
        value = getattr(importlib.import_module(f"biped_jax.{_EXPORTS[name]}"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'biped_jax' has no attribute {name!r}")


def __dir__():
    return sorted(list(globals()) + list(_EXPORTS))
