"""Builds the API reference from the docstrings with pdoc (the ``docs`` extra) into ``docs/api/``:

    pip install '.[docs]' && python docs/build_api.py

``tests/test_docs.py`` builds the same pages and fails on any warning."""

import sys
from pathlib import Path

#: The package and every subpackage (the package's ``__all__`` holds its public names, so pdoc would
#: not walk into the subpackages by itself).
API_MODULES = ("biped_jax", "biped_jax.robots", "biped_jax.dynamics", "biped_jax.optim", "biped_jax.gait",
               "biped_jax.drives", "biped_jax.codesign", "biped_jax.donald", "biped_jax.humanoid",
               "biped_jax.studies", "biped_jax.report", "biped_jax.checks", "biped_jax.cli", "biped_jax.commands")


def build(output: Path) -> None:
    """The pages of :data:`API_MODULES`, of the package Python imports, into ``output``."""
    import contextlib

    import pdoc
    output = Path(output).resolve()
    output.mkdir(parents=True, exist_ok=True)
    # from the output folder: in a checkout, a module name that is also a folder in the working
    # directory would be ambiguous to pdoc (the installed package or the source tree)
    with contextlib.chdir(output):
        pdoc.pdoc(*API_MODULES, output_directory=output)


if __name__ == "__main__":
    target = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).resolve().parent / "api"
    build(target)
    print(f"wrote the API reference into {target} (open {target / 'index.html'})")
