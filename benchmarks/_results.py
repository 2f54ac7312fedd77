"""Saving benchmark results with the machine and library versions they were measured on."""

import platform
import time
from pathlib import Path

import jax
import numpy as np

from biped_jax.report import outputs


def median_seconds(function, args, repeats: int) -> float:
    """Median wall time of ``function(*args)`` over ``repeats`` calls after one warm-up call, s."""
    jax.block_until_ready(function(*args))
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        jax.block_until_ready(function(*args))
        times.append(time.perf_counter() - started)
    return float(np.median(times))


def save_results(benchmark: str, settings: dict, rows: list, folder: Path) -> Path:
    """Writes ``{folder}/{benchmark}_{platform}.json`` (strict JSON: NaN and infinities as null) and
    returns its path."""
    import mujoco
    device = jax.devices()[0]
    result = {"benchmark": benchmark, "date": time.strftime("%Y-%m-%d"), "device": str(device),
              "device_kind": getattr(device, "device_kind", "cpu"), "platform": platform.platform(),
              "processor": platform.processor(), "jax": jax.__version__, "mujoco": mujoco.__version__,
              **settings, "rows": rows}
    path = folder / f"{benchmark}_{device.platform}.json"
    outputs.write_json(path, result)  # strict JSON (a missing figure is null), written atomically
    print(f"device {device} ({result['device_kind']}); saved {path}")
    return path
