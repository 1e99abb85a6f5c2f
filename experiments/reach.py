"""How far the Total Lagrangian paths compress the bonded cylinder, and where they stop.

The thesis this project builds on (du Plessis 2016) modelled the bonded 38 x 24 mm gel
cylinder in Abaqus/Explicit: its Case 1 (ALE adaptive meshing) aborted at 23 % compression
and its Case 2 needed distortion control to reach 30 %. This script runs our axisymmetric
quad path and our 3D hexahedral path on the same bonded problem (mu = 1875 Pa, alpha = 4.9,
nu = 0.499) to increasing compression and prints, per path and level, either the force
reached or the first clear error (:class:`solver.SolverInstability`: step, time, travel,
element and reason).

Run::

    python -m experiments.reach                    # 30 to 70 %, both paths, table on stdout
    python -m experiments.reach --strains 0.3 0.5 --paths axisym --json

Each run is independent (a fresh explicit run to that compression), so a failure at one
level does not hide the next; the table also reports the contact radius (how far the side
has rolled onto the platen), the hourglass energy ratio and the wall time. Runs stop with a
clear error when an element inverts, the energy blows up, or the hourglass energy exceeds
10 % of the strain energy (hourglass modes taking over, where the force would be an
artefact). Each path runs at the solver's hourglass coefficient (0.05) and a stiffer one
(0.3): hourglass control is what limits the one-point elements at extreme compression.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

from solver import (
    CompressionTest,
    Ogden,
    SolverInstability,
    axisymmetric_cylinder,
    hex_cylinder,
    simulate,
)

#: Where the thesis's explicit runs stopped (fraction of the height).
THESIS = {"Case 1 (ALE adaptive mesh)": "aborted at 23 %",
          "Case 2 (distortion control)": "reached 30 % only with distortion control"}

MATERIAL = Ogden(mu_Pa=1875.0, alpha=4.9, nu=0.499)


def meshes(diameter_mm: float = 38.0, height_mm: float = 24.0) -> dict:
    """The two paths' default meshes: the axisymmetric quads and the O-grid hexahedra."""
    return {"axisym": axisymmetric_cylinder(diameter_mm, height_mm),
            "hex": hex_cylinder(diameter_mm, height_mm)}


def reach(strain: float, mesh, material: Ogden = MATERIAL, hourglass: float = 0.05) -> dict:
    """One bonded run to ``strain``; the outcome as a row of the table."""
    test = CompressionTest(strain=strain)
    start = time.perf_counter()
    row = {"strain": strain, "cells": mesh.n_cells, "hourglass": hourglass}
    try:
        r = simulate(material, test, mesh, hourglass=hourglass)
    except SolverInstability as exc:
        row.update(ok=False, wall_s=time.perf_counter() - start, error=str(exc),
                   stopped_at_strain=exc.travel_mm / test.height_mm, step=exc.step,
                   element=exc.element)
        return row
    row.update(ok=True, wall_s=time.perf_counter() - start, force_N=float(r.force_N[-1]),
               nominal_stress_kPa=float(1e3 * r.force_N[-1]
                                        / (np.pi * (test.diameter_mm / 2) ** 2)),
               contact_radius_mm=float(r.contact_radius_mm[-1]),
               hourglass_ratio=r.hourglass_ratio,
               kinetic_ratio_end=float(r.energy["kinetic_J"][-1]
                                       / (r.energy["strain_J"][-1] + r.energy["hourglass_J"][-1])),
               steps=r.n_steps)
    return row


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m experiments.reach",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("--strains", type=float, nargs="+",
                        default=[0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.89])
    parser.add_argument("--paths", nargs="+", choices=("axisym", "hex"),
                        default=["axisym", "hex"])
    parser.add_argument("--hourglass", type=float, nargs="+", default=[0.05, 0.3],
                        help="hourglass coefficients kappa to run (default: the solver's "
                        "0.05 and a stiffer 0.3)")
    parser.add_argument("--json", action="store_true", help="one JSON object on stdout")
    args = parser.parse_args(argv)

    grids = meshes()
    rows = []
    for path in args.paths:
        for kappa in args.hourglass:
            for strain in args.strains:
                print(f"{path} kappa {kappa} to {strain:.0%} ...", file=sys.stderr, flush=True)
                row = {"path": path, **reach(strain, grids[path], hourglass=kappa)}
                rows.append(row)
                print(f"  {_line(row)}", file=sys.stderr, flush=True)
    if args.json:
        print(json.dumps({"thesis": THESIS, "rows": rows}))
        return 0
    print("Thesis (Abaqus/Explicit, 6000 hexahedra): " + "; ".join(
        f"{k}: {v}" for k, v in THESIS.items()))
    print(f"{'path':7} {'cells':>6} {'kappa':>5} {'strain':>6}  outcome")
    for row in rows:
        print(f"{row['path']:7} {row['cells']:6d} {row['hourglass']:5.2f} {row['strain']:6.0%}  "
              f"{_line(row)}")
    return 0


def _line(row: dict) -> str:
    if row["ok"]:
        return (f"reached: {row['force_N']:.3f} N ({row['nominal_stress_kPa']:.2f} kPa), "
                f"contact radius {row['contact_radius_mm']:.2f} mm, hourglass/strain "
                f"{row['hourglass_ratio']:.2%}, {row['steps']} steps, {row['wall_s']:.1f} s")
    return f"STOPPED at {row['stopped_at_strain']:.1%}: {row['error']} ({row['wall_s']:.1f} s)"


if __name__ == "__main__":
    raise SystemExit(main())
