"""A small writer of rig logs in the primary CSV form of shared/RIG_LOGS.md, for tests."""

from pathlib import Path

import numpy as np


def write_primary(path, cycle, approach_mm=0.5, hz=100.0):
    """Write ``cycle`` (a calib.loaders.Cycle or alike) as a rig log with an approach segment.

    The platen approaches at the cycle's rate for ``approach_mm`` with zero force, then follows
    the cycle's branch; travel is logged from the start of logging.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    rate = cycle.rate_mm_per_s
    n_app = max(int(approach_mm / rate * hz), 10)
    t_app = np.arange(n_app) / hz
    d_app = rate * t_app
    t0 = approach_mm / rate
    time = np.concatenate([t_app, t0 + np.asarray(cycle.time_s)])
    travel = np.concatenate([d_app, approach_mm + np.asarray(cycle.displacement_mm)])
    force = np.concatenate([np.zeros(n_app), np.asarray(cycle.force_N)])
    lines = [f"# layer: {cycle.layer}", f"# sample: {cycle.sample}", f"# test: {cycle.test}",
             f"# rate_mm_per_s: {rate}", f"# diameter_mm: {cycle.diameter_mm}",
             f"# height_mm: {cycle.height_mm}", "time_s,displacement_mm,force_N"]
    lines += [f"{t:.5f},{d:.6f},{f:.6f}" for t, d, f in zip(time, travel, force)]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path
