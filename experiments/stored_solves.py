"""Make the forward solves stored with the package (``calib/data/stored_solves.npz``).

Platen slip's up-front discretisation correction on the campaign-wide alpha lattice
(:class:`calib.discover.PlatenSlip`, :func:`calib.discover._mesh_rows`) for the rig's nominal
sample, 38 x 24 mm, at the default fit settings: every lattice alpha from 1 to ``--alpha-max``,
each solve on the fitting and on the correction mesh; and the rest of slip's table on that
lattice (its other frictions, on the fitting mesh only; see
:attr:`calib.discover._GridForwardEffect.grid_on_lattice`). See :mod:`calib.stored` for why
the curves hold for any sample of the same aspect ratio and how they are used.

    python -m experiments.stored_solves [--alpha-max 14] [--workers N]

About 70 CPU seconds per alpha (490 s for the 14 alphas with two workers on 2026-12-07, at
seven frictions; 50 s per alpha at the five before). With the table's one friction more,
0.03, 316 s with two workers on 2026-12-08, on a machine about twice as fast. A solve that
goes unstable before the strain the fits need is left out (the toolkit then solves it, and
fails the same way).
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import time

import numpy as np

from calib.discover import MESH_ALPHA_STEP, _grid_keys, _mesh_keys, make_effect
from calib.fit import FitSettings, ForwardModel
from calib.stored import PATH, StoredSolves, normal_key
from solver import SolverInstability

#: The rig's nominal sample (diameter, height) in mm.
NOMINAL_MM = (38.0, 24.0)
#: The effects whose campaign-wide corrections are stored.
EFFECTS = ("platen_slip",)


def _solve(alpha: float):
    """Every stored solve at one lattice alpha: [(normal key, strain, force / h^2)]."""
    settings = FitSettings()
    forward = ForwardModel.for_settings(settings)
    forward.use_stored = False
    d, h = NOMINAL_MM
    out = []
    for name in EFFECTS:
        effect = make_effect(name)
        mesh = _mesh_keys(settings, effect, alpha, NOMINAL_MM)
        grid = [k for k in _grid_keys(settings, effect, alpha, NOMINAL_MM).values()
                if k not in mesh.values()]
        for key, scales in [(k, (settings.mesh_scale, settings.mesh_correction))
                            for k in mesh.values()] + [(k, (settings.mesh_scale,)) for k in grid]:
            for scale in scales:
                try:
                    spline = forward.curve(key, scale)
                except SolverInstability as exc:
                    print(f"alpha {alpha:g} {key.platen} {key.friction:g} mesh x{scale:g}: "
                          f"left out ({exc})", flush=True)
                    continue
                out.append((normal_key(key, scale, forward), spline.x / h,
                            spline(spline.x) / (h * h)))
    return alpha, out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--alpha-max", type=float, default=14.0)
    parser.add_argument("--workers", type=int, default=None)
    parser.add_argument("--out", default=str(PATH))
    args = parser.parse_args(argv)
    step = MESH_ALPHA_STEP
    alphas = [round(k * step, 9) for k in range(1, int(args.alpha_max / step + 1e-9) + 1)]
    start = time.perf_counter()
    rows = {}
    with cf.ProcessPoolExecutor(max_workers=args.workers) as pool:
        for alpha, out in pool.map(_solve, alphas[::-1]):  # the stiff (slow) ones first
            rows[alpha] = out
            print(f"alpha {alpha:g}: {len(out)} solves ({time.perf_counter() - start:.0f} s)",
                  flush=True)
    keys, strain, force = [], [], []
    for alpha in sorted(rows):
        for k, s, f in rows[alpha]:
            keys.append(k)
            strain.append(s)
            force.append(f)
    if len({len(s) for s in strain}) != 1:
        raise RuntimeError("solves of different lengths: " + str({len(s) for s in strain}))
    aspect = NOMINAL_MM[0] / NOMINAL_MM[1]
    StoredSolves.save(args.out, [aspect] * len(keys), keys, np.array(strain), np.array(force))
    print(f"{len(keys)} solves at {len(rows)} alphas stored in {args.out} "
          f"({time.perf_counter() - start:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
