"""Benchmark of one forward solve, printed beside FElupe on the same machine in one run.

    python -m experiments.bench_forward [--repeat 5] [--skip-felupe]

The default bonded 30 % curve (mu = 1875 Pa, alpha = 4.9, nu = 0.499, 38 x 24 mm, default
axisymmetric mesh): our warm time of the whole ``simulate`` call, set-up included (best of
``--repeat``; FElupe's time is its whole solve too), element-steps per second, the JIT
compile time from a cold numba cache and the start-up time from a warm one (both measured in
fresh subprocesses), our accuracy against FElupe's converged reference
(a 16 x 16 FElupe mesh, error below 0.06 %), and FElupe's time for the same curve at the same
accuracy, with the ratio. Timings are wall clock on this machine; nothing is asserted.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

CASE = {"mu_Pa": 1875.0, "alpha": 4.9, "nu": 0.499}
LEVELS_MM = (2.4, 4.8, 7.2)

_CHILD = r"""
import json, time
t0 = time.perf_counter()
from solver import CompressionTest, Ogden, simulate
t1 = time.perf_counter()
r = simulate(Ogden(mu_Pa=1875.0, alpha=4.9, nu=0.499), CompressionTest())
t2 = time.perf_counter()
r = simulate(Ogden(mu_Pa=1875.0, alpha=4.9, nu=0.499), CompressionTest())
t3 = time.perf_counter()
print(json.dumps({"import_s": t1 - t0, "first_s": t2 - t1, "second_s": t3 - t2}))
"""


def _child(cache_dir: str) -> dict:
    env = {**os.environ, "NUMBA_CACHE_DIR": cache_dir}
    start = time.perf_counter()
    out = subprocess.run([sys.executable, "-c", _CHILD], env=env, capture_output=True,
                         text=True, check=True)
    record = json.loads(out.stdout.strip().splitlines()[-1])
    record["process_s"] = time.perf_counter() - start
    return record


def startup() -> dict:
    """Cold (empty numba cache) and cached start-up, each in a fresh interpreter."""
    with tempfile.TemporaryDirectory() as cache:
        cold = _child(cache)
        cached = _child(cache)
    return {
        "compile_cold_s": cold["first_s"] - cold["second_s"],
        "first_solve_cold_s": cold["first_s"],
        "first_solve_cached_s": cached["first_s"],
        "startup_cached_s": cached["import_s"] + cached["first_s"] - cached["second_s"],
        "import_s": cached["import_s"],
    }


def reference() -> list[float]:
    """Forces at 10/20/30 % from FElupe on a 16 x 16 graded Q2/P1 mesh (error < 0.06 %)."""
    import numpy as np

    from experiments.felupe_reference import compression_curve

    ref = compression_curve(**CASE, n_radial=16, n_axial=16)
    return np.interp(LEVELS_MM, ref["displacement_mm"], ref["force_N"]).tolist()


def warm(repeat: int, reference_N) -> dict:
    """Best-of-``repeat`` warm solve in this process, its accuracy against the reference."""
    import numpy as np

    from solver import CompressionTest, Ogden, simulate

    material = Ogden(**CASE)
    simulate(material, CompressionTest())  # compile or load
    best = None
    for _ in range(repeat):
        start = time.perf_counter()
        r = simulate(material, CompressionTest())
        call_s = time.perf_counter() - start
        if best is None or call_s < best[0]:
            best = (call_s, r)
    call_s, best = best
    reference = np.asarray(reference_N)
    ours = np.interp(LEVELS_MM, best.displacement_mm, best.force_N)
    error = ours / reference - 1.0
    n_elem = best.mesh.n_cells
    return {"wall_s": call_s, "loop_s": best.wall_s, "n_steps": best.n_steps,
            "n_elements": n_elem, "element_steps_per_s": n_elem * best.n_steps / best.wall_s,
            "volumetric_mass": best.volumetric_mass,
            "force_N": ours.tolist(), "reference_N": reference.tolist(),
            "rel_error": error.tolist(), "max_rel_error": float(np.max(np.abs(error)))}


def felupe(accuracy: float, repeat: int) -> dict:
    """FElupe's time for the same curve on the mesh whose error matches ``accuracy``."""
    from experiments.felupe_reference import time_at_accuracy

    return time_at_accuracy(accuracy, repeat=repeat, **CASE)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--repeat", type=int, default=5)
    p.add_argument("--skip-felupe", action="store_true")
    p.add_argument("--json", action="store_true")
    args = p.parse_args(argv)
    report = {"case": CASE, "startup": startup(), "ours": warm(args.repeat, reference())}
    if not args.skip_felupe:
        report["felupe"] = felupe(max(report["ours"]["max_rel_error"], 0.0025), 3)
        report["ratio"] = report["felupe"]["wall_s"] / report["ours"]["wall_s"]
    if args.json:
        print(json.dumps(report, indent=1))
        return 0
    o, s = report["ours"], report["startup"]
    print("Forward solve: bonded 30 % compression, mu 1875 Pa, alpha 4.9, nu 0.499, 38 x 24 mm")
    mass = "volumetric selective mass" if o["volumetric_mass"] else "lumped mass"
    print(f"  ours (numba TLED, {mass}, {o['n_elements']} quads, {o['n_steps']} steps): "
          f"{o['wall_s']:.4f} s warm for the whole call (time loop {o['loop_s']:.4f} s, "
          f"{o['element_steps_per_s'] / 1e6:.1f} M element-steps/s)")
    print("  accuracy vs converged FElupe at 10/20/30 %: "
          + ", ".join(f"{100 * e:+.2f} %" for e in o["rel_error"]))
    print(f"  JIT compile from a cold cache {s['compile_cold_s']:.1f} s; cached start-up "
          f"(import + first solve beyond a warm one) {s['startup_cached_s']:.2f} s")
    if "felupe" in report:
        f = report["felupe"]
        print(f"  FElupe (static Newton, Q2/P1, {f['n_radial']}x{f['n_axial']} mesh, "
              f"{f['n_dofs']} dofs, error {100 * f['rel_error']:.2f} %): {f['wall_s']:.3f} s")
        print(f"  ratio FElupe / ours: {report['ratio']:.1f}x")
    print("  (thesis: Abaqus/Explicit, 6000 hexahedra: 23 minutes)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
