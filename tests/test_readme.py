"""The README's quickstart is run as written, and its numbers are checked."""

import re
from pathlib import Path

import numpy as np
import pytest

README = Path(__file__).resolve().parent.parent / "README.md"


def _python_blocks():
    return re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)


@pytest.mark.xdist_group("mjx_quickstart")  # the rollout and touchdown programs of tests/test_dynamics.py
def test_quickstart_runs_and_gives_physical_numbers():
    namespace = {}
    exec(compile(_python_blocks()[0], "README quickstart", "exec"), namespace)
    trajectory, landing = namespace["trajectory"], namespace["landing"]
    assert trajectory.q.shape == (51, 5)
    # At the start the torques are zero and the robot is moving: the foot force holds it up.
    assert 0 < float(trajectory.ground_force[0, 1]) < 3 * 12 * 9.81
    assert np.all(np.isfinite(np.asarray(landing.impulse)))
    heavy = namespace["heavy"]
    assert abs(float(heavy.pinned.body_mass.sum()) - 17.998) < 1e-9


def test_model_loading_snippet():
    namespace = {}
    exec(compile(_python_blocks()[1], "README models", "exec"), namespace)
    assert namespace["mj_model"].nu == 5
    assert namespace["mjx_model"].nv == 22


@pytest.mark.xdist_group("test_gait")  # the batch of M1-M4 the gait tests' fixture compiles: one worker, one compile
def test_gait_snippet_solves_m2_within_the_power_limit():
    namespace = {}
    exec(compile(_python_blocks()[2], "README gait", "exec"), namespace)
    m2 = namespace["m2"]
    assert m2.status == "converged", (m2.status, m2.violations)
    assert 1.0 < m2.cost < 10.0  # J of M2 in small spaces: 2.8 (48 spans) to about 4.5 (4 spans)
    assert np.max(np.abs(m2.trajectory.joint_power)) <= 20.0 + 1e-3


def test_every_public_name_imports():
    import biped_jax
    for name in biped_jax.__all__:
        assert getattr(biped_jax, name) is not None, name
