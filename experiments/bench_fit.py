"""Benchmark of the calibration: forward solves per layer fit, one layer warm, the whole
campaign, and ``calib demo`` from a cold start.

    python -m experiments.bench_fit [--data experiments/campaign] [--skip-demo]

"Warm" means the numba kernels are compiled and cached (a second process) and the forward
model's cache of solves is empty: every solve a fit needs is paid for. Nothing is asserted.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def one_layer(data: str, layer: str) -> dict:
    from calib.fit import FitSettings, fit_layer
    from calib.loaders import load_campaign

    campaign = load_campaign(data)
    cycles = campaign.select(layer=layer)
    fit_layer(cycles[:2] + cycles[-1:], FitSettings(profile=False))  # warm the kernels
    start = time.perf_counter()
    fit = fit_layer(cycles)
    return {"layer": layer, "cycles": len(cycles), "wall_s": time.perf_counter() - start,
            "forward_solves": fit.n_solves, "solve_s": fit.solve_s}


def campaign_fit(data: str) -> dict:
    from calib.fit import fit_campaign
    from calib.loaders import load_campaign

    campaign = load_campaign(data)
    start = time.perf_counter()
    result = fit_campaign(campaign, progress=False)
    return {"layers": len(result.fits), "wall_s": time.perf_counter() - start,
            "forward_solves": sum(f.n_solves for f in result.fits.values())}


def demo_cold() -> dict:
    """``calib demo`` in a fresh interpreter with an empty numba cache."""
    with tempfile.TemporaryDirectory() as tmp:
        env = {**os.environ, "NUMBA_CACHE_DIR": str(Path(tmp) / "numba")}
        start = time.perf_counter()
        subprocess.run([sys.executable, "-m", "calib", "demo", "--out", str(Path(tmp) / "r"),
                        "--json"], env=env, check=True, capture_output=True)
        return {"wall_s": time.perf_counter() - start}


def main(argv=None) -> int:
    from calib.demo import embedded_campaign_path

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", default=str(embedded_campaign_path()))
    p.add_argument("--layer", default="A")
    p.add_argument("--skip-demo", action="store_true")
    args = p.parse_args(argv)
    report = {"one_layer": one_layer(args.data, args.layer),
              "campaign": campaign_fit(args.data)}
    if not args.skip_demo:
        report["demo_cold"] = demo_cold()
    print(json.dumps(report, indent=1))
    o, c = report["one_layer"], report["campaign"]
    print(f"one layer ({o['cycles']} cycles): {o['wall_s']:.1f} s, {o['forward_solves']} "
          f"forward solves ({o['solve_s']:.1f} s in the solver)", file=sys.stderr)
    print(f"campaign ({c['layers']} layers, {os.cpu_count()} cores): {c['wall_s']:.1f} s, "
          f"{c['forward_solves']} forward solves", file=sys.stderr)
    if "demo_cold" in report:
        print(f"calib demo from a cold start: {report['demo_cold']['wall_s']:.0f} s",
              file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
