"""Benchmark of the 3D hexahedral path at the thesis's problem size.

The thesis (du Plessis 2016) ran the bonded 38 x 24 mm cylinder at 30 % compression in
Abaqus/Explicit with 6000 reduced-integration hexahedra (6741 nodes): 23 minutes per run.
This script times our hexahedral TLED path on a mesh of the same size (``hex_cylinder`` with
8 x 8 core, 7 rings, 21 layers: 6048 hexahedra, 6710 nodes; mu = 1875 Pa, alpha = 4.9,
nu = 0.499, bonded, 30 %), serial and parallel, and prints beside it

- the thesis's 23 minutes,
- FElupe's time for a static 3D solution of the same problem on a hexahedral mesh of about
  the same size (hex8 with a cell-wise constant pressure, 10 increments, rollover contact;
  experiments.felupe_reference), with each code's force error against a converged
  reference (our axisymmetric path on a 3x refined mesh, Richardson-checked against the
  4x mesh in the convergence tests) - the accuracy at which the times compare;
- element-steps per second per core for the serial and the parallel run.

Run::

    python -m experiments.bench_hex                 # all of it (FElupe takes minutes)
    python -m experiments.bench_hex --no-felupe --repeat 3 --json

Timings on a machine shared with other jobs are preliminary; the parallel run suffers most
(its threads wait for each other twice per step).
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numba
import numpy as np

from solver import CompressionTest, Ogden, axisymmetric_cylinder, hex_cylinder, simulate

THESIS_MINUTES = 23.0
THESIS_ELEMENTS, THESIS_NODES = 6000, 6741
MATERIAL = Ogden(mu_Pa=1875.0, alpha=4.9, nu=0.499)
LEVELS_MM = (2.4, 4.8, 7.2)  # 10, 20, 30 % of 24 mm
#: The thesis-size mesh: 6048 hexahedra, 6710 nodes.
THESIS_MESH = {"n_core": 8, "n_ring": 7, "n_axial": 21}


def _log(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def reference_forces() -> np.ndarray:
    """Converged bonded forces (N) at 10/20/30 %: axisymmetric path, 3x the default mesh."""
    r = simulate(MATERIAL, CompressionTest(), axisymmetric_cylinder(38.0, 24.0, 42, 54))
    return np.interp(LEVELS_MM, r.displacement_mm, r.force_N)


def time_ours(mesh, parallel: bool, repeat: int) -> dict:
    """Best of ``repeat`` warm runs: total wall time (set-up + loop) and loop time."""
    best = None
    for _ in range(repeat):
        start = time.perf_counter()
        r = simulate(MATERIAL, CompressionTest(), mesh, parallel=parallel)
        total = time.perf_counter() - start
        if best is None or total < best["total_s"]:
            best = {"total_s": total, "loop_s": r.wall_s, "result": r}
    r = best.pop("result")
    threads = numba.get_num_threads() if parallel else 1
    element_steps = r.n_steps * mesh.n_cells
    best.update(parallel=parallel, threads=threads, steps=r.n_steps,
                element_steps_per_s_per_core=element_steps / r.wall_s / threads,
                forces_N=np.interp(LEVELS_MM, r.displacement_mm, r.force_N).tolist(),
                hourglass_ratio=r.hourglass_ratio)
    return best


def time_felupe(n_radial: int = 6, n_axial: int = 21) -> dict:
    """FElupe's static 3D solution on an O-grid hex8 mesh of about the thesis's size."""
    from experiments.felupe_reference import compression_curve

    out = compression_curve(MATERIAL.mu_Pa[0], MATERIAL.alpha[0], MATERIAL.nu,
                            axisymmetric=False, n_radial=n_radial, n_axial=n_axial,
                            order="linear")
    return {"wall_s": out["wall_s"], "cells": int(out["mesh"].ncells),
            "n_dofs": out["n_dofs"], "forces_N": np.interp(
                LEVELS_MM, out["displacement_mm"], out["force_N"]).tolist()}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m experiments.bench_hex",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=1, help="warm runs, best taken")
    parser.add_argument("--no-felupe", action="store_true", help="skip the FElupe timing")
    parser.add_argument("--json", action="store_true", help="one JSON object on stdout")
    args = parser.parse_args(argv)

    mesh = hex_cylinder(38.0, 24.0, **THESIS_MESH)
    _log(f"mesh: {mesh.n_cells} hexahedra, {mesh.n_nodes} nodes "
         f"(thesis: {THESIS_ELEMENTS}, {THESIS_NODES})")
    _log("reference: axisymmetric path on 42 x 54 quads ...")
    ref = reference_forces()
    _log("warming up the JIT (compiles once, cached afterwards) ...")
    start = time.perf_counter()
    simulate(MATERIAL, CompressionTest(strain=0.02), hex_cylinder(38.0, 24.0, 2, 1, 2))
    simulate(MATERIAL, CompressionTest(strain=0.02), hex_cylinder(38.0, 24.0, 2, 1, 2),
             parallel=False)
    warm_s = time.perf_counter() - start
    runs = []
    for parallel in (False, True):
        _log(f"{'parallel' if parallel else 'serial'} run ...")
        runs.append(time_ours(mesh, parallel, args.repeat))
    felupe = None
    if not args.no_felupe:
        _log("FElupe 3D static solution (minutes) ...")
        felupe = time_felupe()

    def error(forces):
        return (np.asarray(forces) / ref - 1.0).tolist()

    report = {"mesh": {"cells": mesh.n_cells, "nodes": mesh.n_nodes, **THESIS_MESH},
              "reference_N": ref.tolist(), "jit_warmup_s": warm_s,
              "thesis": {"minutes": THESIS_MINUTES, "elements": THESIS_ELEMENTS},
              "ours": [{**r, "error": error(r["forces_N"])} for r in runs],
              "felupe": None if felupe is None else {**felupe,
                                                      "error": error(felupe["forces_N"])}}
    if args.json:
        print(json.dumps(report))
        return 0
    print(f"Bonded 30 % compression, {mesh.n_cells} hexahedra / {mesh.n_nodes} nodes, "
          f"mu 1875 Pa, alpha 4.9, nu 0.499")
    print("reference forces at 10/20/30 %: " + ", ".join(f"{f:.4f}" for f in ref) + " N")
    print(f"{'run':34} {'wall (s)':>9} {'vs thesis':>10}  {'error at 10/20/30 %':>24}  "
          f"{'element-steps/s/core':>20}")
    print(f"{'thesis, Abaqus/Explicit':34} {60 * THESIS_MINUTES:9.0f} {1:>9.0f}x  "
          f"{'(not reported)':>24}  {'':>20}")
    for r in report["ours"]:
        name = f"ours, {'parallel x' + str(r['threads']) if r['parallel'] else 'serial'}"
        errs = " ".join(f"{100 * e:+.2f}%" for e in r["error"])
        print(f"{name:34} {r['total_s']:9.1f} {60 * THESIS_MINUTES / r['total_s']:9.0f}x  "
              f"{errs:>24}  {r['element_steps_per_s_per_core']:20.3g}")
        print(f"{'  (time loop only, ' + str(r['steps']) + ' steps)':34} {r['loop_s']:9.1f}")
    if felupe is not None:
        errs = " ".join(f"{100 * e:+.2f}%" for e in report["felupe"]["error"])
        name = f"FElupe 3D static, {felupe['cells']} hex8"
        print(f"{name:34} {felupe['wall_s']:9.1f} {60 * THESIS_MINUTES / felupe['wall_s']:9.0f}x  "
              f"{errs:>24}  {'':>20}")
    print(f"JIT warm-up (cached compile) {warm_s:.1f} s; timings on a shared machine are "
          f"preliminary")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
