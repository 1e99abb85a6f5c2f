"""Benchmark of the solves stored with the package (calib.stored): discovery with and without.

    python -m experiments.bench_stored [--data experiments/campaign] [--layers A]

Runs ``discover_campaign`` on the same layers twice in this process, one worker each: first
with every solve made afresh (the store replaced by an empty one), then reading the stored
ones, and prints both times, their ratio and whether the two name the same effect with the
same gaps. The numba kernels are warmed first. Nothing is asserted.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time


def run(data: str, layers: list[str]) -> dict:
    import calib.stored as stored
    from calib.discover import discover_campaign
    from calib.fit import CurveKey, ForwardModel
    from calib.loaders import load_campaign

    campaign = load_campaign(data)
    campaign = dataclasses.replace(campaign, cycles=tuple(
        c for c in campaign.cycles if c.layer in layers))
    ForwardModel(use_stored=False).curve(CurveKey(alpha=(5.0,), diameter_mm=38.0,
                                                  height_mm=24.0, platen="coulomb",
                                                  friction=0.15))  # warm the kernels
    package = stored.stored_solves

    def discover():
        start = time.perf_counter()
        result = discover_campaign(campaign, workers=1, progress=False, log=lambda *a: None)
        return result, time.perf_counter() - start

    try:
        stored.stored_solves = lambda: stored.StoredSolves([], [], [], [])
        fresh, fresh_s = discover()
    finally:
        stored.stored_solves = package
    read, read_s = discover()
    return {"data": data, "layers": layers, "fresh_s": fresh_s, "stored_s": read_s,
            "ratio": fresh_s / read_s, "fresh_solves": fresh.n_solves,
            "stored_solves": read.n_solves, "effect": [fresh.effect, read.effect],
            "rms_after_mN": [1e3 * fresh.rms_after_N, 1e3 * read.rms_after_N],
            "heldout_rate_after_mN": [1e3 * fresh.heldout_after["rate"]["rms_N"],
                                      1e3 * read.heldout_after["rate"]["rms_N"]]}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default=None, help="default: the embedded campaign")
    parser.add_argument("--layers", default="A")
    args = parser.parse_args(argv)
    if args.data is None:
        from calib.demo import embedded_campaign_path

        args.data = str(embedded_campaign_path())
    out = run(args.data, args.layers.split(","))
    print(json.dumps(out, indent=1))
    print(f"discovery on {args.layers}: {out['fresh_s']:.1f} s solving everything, "
          f"{out['stored_s']:.1f} s reading the stored solves: {out['ratio']:.2f} x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
