"""The README's quickstart is run as written, and its numbers are checked."""

import re
from pathlib import Path

import numpy as np

README = Path(__file__).resolve().parent.parent / "README.md"


def _python_blocks():
    return re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)


def test_quickstart_runs_and_gives_physical_numbers():
    namespace = {}
    exec(compile(_python_blocks()[0], "README quickstart", "exec"), namespace)
    trajectory, impact = namespace["trajectory"], namespace["impact"]
    assert trajectory.q.shape == (51, 5)
    # At the start the torques are zero and the robot is moving: the foot force holds it up.
    assert 0 < float(trajectory.ground_force[0, 1]) < 3 * 12 * 9.81
    assert np.all(np.isfinite(np.asarray(impact.impulse)))
    heavy = namespace["heavy"]
    assert abs(float(heavy.pinned.body_mass.sum()) - 17.998) < 1e-9


def test_model_loading_snippet():
    namespace = {}
    exec(compile(_python_blocks()[1], "README models", "exec"), namespace)
    assert namespace["mj_model"].nu == 5
    assert namespace["mjx_model"].nv == 22
