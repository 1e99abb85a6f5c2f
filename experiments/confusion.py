"""Discovery on generated campaigns with hidden effects: the confusion table, and the null runs
that calibrate the acceptance thresholds.

    python -m experiments.confusion --scenarios all --layers A,D --seeds 1 --out runs/confusion
    python -m experiments.confusion --null 20 --layers A,D --fast --out runs/null

For every (scenario, seed) a campaign is generated (fine mesh unless ``--fast``, with the sensor
model and scatter), ``calib.discover.discover_campaign`` runs on it with the thresholds switched
off (so every round-1 candidate's dBIC and held-out gain is recorded), the named effect is
decided with the current thresholds, and one JSON line per run is appended to
``OUT/runs.jsonl``. ``--summary`` prints the confusion table and, for null runs, the thresholds
that keep the false-positive rate at or below 5 %.

``--contact-noise`` judges with a per-cycle scatter of the contact reading in the noise model
(``calib.fit.FitSettings.contact_noise``); ``--max-level 0.22`` compares at the default levels
up to 22 % strain only, below where the bulging side folds onto the platens.

``--truth-code felupe`` makes the campaigns' curves with FElupe instead of this project's
solver (an independent code; scenarios without Prony terms or Coulomb platens), and a
scenario may carry its own magnitude, e.g. wholly unbonded (frictionless) platens::

    python -m experiments.confusion --truth-code felupe --out runs/felupe \
        --scenarios clean,platen_slip@1000,contact_offset,machine_compliance,compressibility
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from experiments.generator import TRUTH_CODES
from experiments.scenarios import SCENARIOS


def run_one(scenario: str, seed: int, layers: list[str], fast: bool, magnitude: float = 1.0,
            keep: Path | None = None, truth_code: str = "solver",
            axial_ratio: float = 3.0, contact_noise: bool = False,
            max_level: float | None = None) -> dict:
    """Generate one campaign, run discovery with every candidate recorded, return a record.

    ``axial_ratio`` grades both the generating and the fitting meshes along the height;
    ``contact_noise`` gives the judging noise model its contact-reading term; ``max_level``
    keeps the default comparison levels up to that strain (all three
    :class:`calib.fit.FitSettings`).
    """
    from calib.discover import THRESHOLDS, discover_campaign
    from calib.fit import DEFAULT_LEVELS, FitSettings
    from calib.loaders import load_campaign
    from experiments.generator import generate_campaign

    tmp = Path(tempfile.mkdtemp(prefix=f"{scenario}_{seed}_"))
    folder = tmp / "campaign"
    start = time.perf_counter()
    generate_campaign(folder, scenario=scenario, seed=seed, layers=tuple(layers), fast=fast,
                      magnitude=magnitude, truth_code=truth_code, axial_ratio=axial_ratio)
    truth = json.loads((folder / "truth.json").read_text())
    campaign = load_campaign(folder)
    # where the loader read each contact, after the full face's (mm): a travel offset's
    # truth as the fit sees it is minus their mean (a toe is compensated by the loader)
    full_face = {Path(c["file"]).name: c["contact_mm"] for c in truth["cycles"]}
    readings = [c.contact_mm - full_face[Path(c.file).name] for c in campaign.cycles]
    t_gen = time.perf_counter() - start
    # thresholds off: every plausible leading candidate gets its held-out check
    levels = tuple(v for v in DEFAULT_LEVELS if max_level is None or v <= max_level + 1e-9)
    settings = FitSettings(axial_ratio=axial_ratio, contact_noise=contact_noise, levels=levels)
    result = discover_campaign(campaign, settings=settings,
                               progress=False, log=lambda *a: None,
                               thresholds={"delta_bic_per_cycle": math.inf,
                                           "heldout_improvement": -math.inf},
                               max_rounds=1)
    candidates = [c.to_dict() | {"heldout_improvement": c.heldout_improvement}
                  for c in result.rounds[0]]
    named, also_possible = decide_all(candidates, THRESHOLDS, len(campaign.cycles))
    record = {
        "scenario": scenario, "seed": seed, "layers": layers, "fast": fast,
        "magnitude": magnitude, "truth_code": truth_code, "axial_ratio": axial_ratio,
        "contact_noise": contact_noise, "levels": list(levels),
        "truth": truth["scenario"].get("parameters", {}),
        "contact_reading_mm": {"mean": float(np.mean(readings)),
                               "sd": float(np.std(readings, ddof=1))},
        "candidates": candidates,
        "rms_before_N": result.rms_before_N, "rms_after_N": result.rms_after_N,
        "heldout_before": {k: v["rms_N"] for k, v in result.heldout_before.items()},
        "heldout_after": {k: v["rms_N"] for k, v in result.heldout_after.items()},
        "systematic_before": result.systematic_before,
        "systematic_after": result.systematic_after,
        "rms_samples_before_N": result.rms_samples_before_N,
        "rms_samples_after_N": result.rms_samples_after_N,
        "rms_samples_after_fast_N": result.rms_samples_after_fast_N,
        "heldout_samples_before": {k: v["rms_samples_N"]
                                   for k, v in result.heldout_before.items()},
        "heldout_samples_after": {k: v["rms_samples_N"] for k, v in result.heldout_after.items()},
        "heldout_systematic_before": {k: v["systematic"]
                                      for k, v in result.heldout_before.items()},
        "heldout_systematic_after": {k: v["systematic"]
                                     for k, v in result.heldout_after.items()},
        "named_unthresholded": result.effect,
        "uncertainty": result.uncertainty,
        "n_cycles": len(campaign.cycles),
        "named": named,
        "also_possible": also_possible,
        "warning": warning(candidates, named, THRESHOLDS, len(campaign.cycles)),
        "generate_s": t_gen, "discover_s": result.wall_s, "forward_solves": result.n_solves,
    }
    if keep is not None:
        shutil.copytree(folder, keep / f"{scenario}_{seed}", dirs_exist_ok=True)
    shutil.rmtree(tmp, ignore_errors=True)
    return record


def stderr(record: dict) -> str:
    """The standard errors of the unthresholded pick's parameters, as the summary gives them."""
    u = record.get("uncertainty", {}).get(record["scenario"])
    if not u or record["named_unthresholded"] != record["scenario"]:
        return ""
    corr = "" if u["correlation"] is None else f", correlation {u['correlation']:+.2f}"
    return " +- " + ", ".join(f"{k} {v:.2g}" for k, v in u["stderr"].items()) + corr


def reading(record: dict) -> str:
    """The loader's contact reading after the full face's, as the summary gives it."""
    r = record.get("contact_reading_mm")
    return (f"; contact read {1e3 * r['mean']:+.1f} um (sd {1e3 * r['sd']:.1f}) from the "
            f"full face's" if r else "")


def warning(candidates: list[dict], named: str, thresholds, n_cycles: int) -> str:
    """discover's doubt about ``named`` from round-1 candidate records (a candidate ended at
    an edge of its box that gains more: ``calib.discover.beyond_range_warning``)."""
    from types import SimpleNamespace

    from calib.discover import beyond_range_warning

    records = [SimpleNamespace(effect=c["effect"], delta_bic=c["delta_bic"],
                               plausible=c["plausible"], parameters=c["parameters"],
                               edge=c.get("at_edge", "")) for c in candidates]
    chosen = next((c for c in records if c.effect == named), None)
    return beyond_range_warning(records, chosen, thresholds["delta_bic_per_cycle"] * n_cycles)


def decide(candidates: list[dict], thresholds, n_cycles: int) -> str:
    """The effect named by the acceptance rules from round-1 candidate records."""
    return decide_all(candidates, thresholds, n_cycles)[0]


def decide_all(candidates: list[dict], thresholds, n_cycles: int) -> tuple[str, list[str]]:
    """The named effect and those named beside it as equally possible (discover's rules:
    among the passing candidates within max(10, 10 %) of the best dBIC, the first by
    ``calib.discover.rank_near_ties``; beside it, the passing ones within the margin of its
    dBIC)."""
    from calib.discover import _margin, direct_confirms, rank_near_ties

    limit = thresholds["delta_bic_per_cycle"] * n_cycles

    def passes(c):
        gains = c.get("heldout_improvement")
        return not (c["delta_bic"] > limit or not c["plausible"] or gains is None
                    or not direct_confirms(c.get("direct_delta_bic", -math.inf),
                                           c["delta_bic"], limit)
                    or any(v < thresholds["heldout_improvement"] for v in gains.values()))

    passing = [c for c in sorted(candidates, key=lambda c: c["delta_bic"]) if passes(c)]
    if not passing:
        return "none", []
    passing = rank_near_ties(passing, lambda c: c["delta_bic"], lambda c: c.get("systematic", 0.0),
                             lambda c: c["heldout_improvement"])
    best = passing[0]
    return best["effect"], [c["effect"] for c in passing[1:]
                            if c["delta_bic"] - best["delta_bic"] < _margin(best["delta_bic"])]


#: what makes two runs' campaigns alike but for the hidden effect (see :func:`gap_above_floor`)
_LIKE = ("seed", "layers", "fast", "truth_code", "axial_ratio", "contact_noise", "levels")


def excess(value: float, floor: float) -> float:
    """The part of an RMS gap above a floor that is independent of it: sqrt(value^2 - floor^2).

    0 where the gap is at or below the floor.
    """
    return math.sqrt(max(value * value - floor * floor, 0.0))


def gap_above_floor(records: list[dict]) -> list[dict]:
    """Each effect run's held-out gaps, before and after, above those of its clean twin.

    A held-out gap has a floor no effect can remove: the sensor's noise, the samples' scatter
    about the model and the fitting mesh's differences from the generating one. The clean
    run of the same seed, layers and settings measures it (its gap before, with nothing to
    find). Independent of what an effect adds, it adds in quadrature, so the effect's own part
    is :func:`excess`; a gap that an effect brings back to the floor shrinks to 0 there, while
    the gap itself cannot halve if the floor was most of it.

    The gaps after are those of the model of the run's unthresholded pick, which need not be
    the true effect's (``after_model``). Returns one row per effect run with a clean twin and
    per held-out kind: the gap of each sample at its own mu and alpha (N) and the systematic
    part (fraction), each as ``(before, after, floor, ratio of the excesses)``; the ratio is
    NaN without an excess before.
    """
    def alike(a, b):
        return all(a.get(k) == b.get(k) for k in _LIKE)

    done = [r for r in records if "failed" not in r]
    rows = []
    for r in done:
        if r["scenario"] == "clean" or "heldout_samples_before" not in r:
            continue
        twin = next((c for c in done if c["scenario"] == "clean" and alike(c, r)
                     and "heldout_samples_before" in c), None)
        if twin is None:
            continue
        for kind in r["heldout_samples_before"]:
            # the gaps after are those of the unthresholded pick's model (see run_one)
            row = {"scenario": r["scenario"], "seed": r["seed"], "kind": kind,
                   "after_model": r.get("named_unthresholded", r["scenario"])}
            for name, key in (("samples", "heldout_samples"),
                              ("systematic", "heldout_systematic")):
                floor = twin[f"{key}_before"].get(kind)
                before, after = r[f"{key}_before"][kind], r[f"{key}_after"][kind]
                if floor is None:
                    continue
                b, a = excess(before, floor), excess(after, floor)
                row[name] = (before, after, floor, a / b if b > 0 else math.nan)
            rows.append(row)
    return rows


def summarise(records: list[dict]) -> str:
    """Confusion table (true scenario x named effect) and threshold calibration of nulls."""
    from calib.discover import THRESHOLDS

    failed = [r for r in records if "failed" in r]
    records = [r for r in records if "failed" not in r]
    names = sorted({r["named"] for r in records} | {"none"})
    scen = sorted({r["scenario"] for r in records})
    lines = ["| true \\ named | " + " | ".join(names) + " |",
             "| --- |" + " --- |" * len(names)]
    for s in scen:
        row = [sum(1 for r in records if r["scenario"] == s and r["named"] == n) for n in names]
        lines.append(f"| {s} | " + " | ".join(str(v) for v in row) + " |")
    nulls = [r for r in records if r["scenario"] == "clean"]
    if nulls:
        fp = sum(1 for r in nulls if r["named"] != "none")
        lines += ["", f"null runs: {len(nulls)}, named an effect: {fp} "
                  f"({100 * fp / len(nulls):.1f} %) with thresholds {THRESHOLDS}", "",
                  "false-positive rate of null runs for thresholds (dBIC per cycle x held-out "
                  "gain); the smallest passing candidate per run:"]
        grid_x = [-1.0, -2.0, -3.0, -4.0, -6.0, -8.0]
        grid_y = [0.0, 0.02, 0.05, 0.08, 0.12]
        lines.append("| dBIC/cycle \\ gain | " + " | ".join(f"{y:.2f}" for y in grid_y) + " |")
        lines.append("| --- |" + " --- |" * len(grid_y))
        for x in grid_x:
            row = []
            for y in grid_y:
                th = {"delta_bic_per_cycle": x, "heldout_improvement": y}
                rate = sum(decide(r["candidates"], th, r["n_cycles"]) != "none" for r in nulls)
                row.append(f"{rate}/{len(nulls)}")
            lines.append(f"| {x:g} | " + " | ".join(row) + " |")
        for r in nulls:
            ok = [c for c in r["candidates"] if c["plausible"] and c.get("heldout_improvement")]
            desc = ", ".join(f"{c['effect']} {c['delta_bic'] / r['n_cycles']:.1f}/cycle "
                             f"gain {min(c['heldout_improvement'].values()):+.3f}" for c in ok)
            lines.append(f"- seed {r['seed']}: {desc or 'no plausible candidate'}")
    effects = [r for r in records if r["scenario"] != "clean"]
    if effects:
        lines += ["", "effect runs, the true effect's candidate:"]
        for r in effects:
            true = [c for c in r["candidates"] if c["effect"] == r["scenario"]]
            c = true[0] if true else None
            gain = (min(c["heldout_improvement"].values()) if c and c.get("heldout_improvement")
                    else float("nan"))
            held = ", ".join(f"{k} {1e3 * v:.1f} -> {1e3 * r['heldout_after'][k]:.1f}"
                             for k, v in r["heldout_before"].items())
            sys_fit = (f"{100 * r['systematic_before']:.2f} -> "
                       f"{100 * r['systematic_after']:.2f} %"
                       if "systematic_before" in r else "not recorded")
            sys_held = ", ".join(f"{k} {100 * v:.2f} -> "
                                 f"{100 * r['heldout_systematic_after'][k]:.2f} %"
                                 for k, v in r.get("heldout_systematic_before", {}).items())
            samples = (f"{1e3 * r['rms_samples_before_N']:.1f} -> "
                       f"{1e3 * r['rms_samples_after_N']:.1f}, held out " + ", ".join(
                           f"{k} {1e3 * v:.1f} -> {1e3 * r['heldout_samples_after'][k]:.1f}"
                           for k, v in r["heldout_samples_before"].items())
                       if "rms_samples_before_N" in r else "not recorded")
            also = decide_all(r["candidates"], THRESHOLDS, r["n_cycles"])[1]
            named = r["named"] + (f" (equally possible: {', '.join(also)})" if also else "")
            lines.append(f"- {r['scenario']} seed {r['seed']}: named {named}; true effect "
                         f"{c['delta_bic'] / r['n_cycles']:.1f}/cycle, gain {gain:+.3f}, "
                         f"{c['parameters']}{stderr(r)} (truth {r['truth']}{reading(r)}); RMS gap "
                         f"(mN) fitted "
                         f"{1e3 * r['rms_before_N']:.1f} -> {1e3 * r['rms_after_N']:.1f}, "
                         f"held out {held}; each sample at its own mu, alpha: fitted "
                         f"{samples}; systematic part fitted {sys_fit}, held out "
                         f"{sys_held} (model of the unthresholded pick, "
                         f"{r['named_unthresholded']})" if c else "")
    above = gap_above_floor(records)
    if above:
        lines += ["", "held-out gaps above the clean run's of the same seed (the floor; "
                  "excess = sqrt(gap^2 - floor^2)): each sample at its own mu, alpha (mN) | "
                  "systematic part (%)",
                  "| scenario | held out by | gap before -> after (floor) | excess ratio | "
                  "systematic before -> after (floor) | excess ratio |",
                  "| --- | --- | --- | --- | --- | --- |"]
        for row in above:
            cells = []
            for name, unit in (("samples", 1e3), ("systematic", 100.0)):
                if name not in row:
                    cells += ["", ""]
                    continue
                b, a, f, ratio = row[name]
                cells += [f"{unit * b:.2f} -> {unit * a:.2f} ({unit * f:.2f})", f"{ratio:.2f}"]
            after = row["after_model"]
            other = ("" if after == row["scenario"] else "; after: the base model"
                     if after == "none" else f"; after: {after}'s model")
            lines.append(f"| {row['scenario']} (seed {row['seed']}{other}) | {row['kind']} | "
                         + " | ".join(cells) + " |")
    warned = [r for r in records if r.get("warning")]
    if warned:
        lines += ["", "runs whose name discover doubts (a candidate at the edge of its box "
                  "gains more):"]
        lines += [f"- {r['scenario']} seed {r['seed']} (magnitude {r['magnitude']:g}): "
                  f"{r['warning']}" for r in warned]
    if failed:
        lines += ["", "runs that failed (not in the table):"]
        lines += [f"- {r['scenario']} seed {r['seed']} (magnitude {r['magnitude']:g}, "
                  f"{r.get('truth_code', 'solver')}): {r['failed']}" for r in failed]
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scenarios", default="all", help="comma-separated, or 'all'")
    p.add_argument("--null", type=int, default=0,
                   help="number of clean runs (seeds FIRST..FIRST+N-1, see --first-seed)")
    p.add_argument("--first-seed", type=int, default=1,
                   help="seed of the first clean run (default 1), to add runs to a record")
    p.add_argument("--seeds", default="1", help="comma-separated seeds for the scenarios")
    p.add_argument("--layers", default="A,D", help="layers of each generated campaign")
    p.add_argument("--fast", action="store_true", help="generate on the fitting mesh")
    p.add_argument("--magnitude", type=float, default=1.0,
                   help="of every scenario without its own (NAME@M in --scenarios)")
    p.add_argument("--truth-code", choices=TRUTH_CODES, default="solver",
                   help="the code that makes the campaigns' curves")
    p.add_argument("--axial-ratio", type=float, default=3.0,
                   help="largest over smallest element height of the generating and the "
                        "fitting meshes (default 3)")
    p.add_argument("--contact-noise", action="store_true",
                   help="judge with a per-cycle scatter of the contact reading in the noise "
                        "model (FitSettings.contact_noise)")
    p.add_argument("--max-level", type=float, default=None,
                   help="compare at the default levels up to this strain only (fraction)")
    p.add_argument("--out", required=True,
                   help="folder for runs.jsonl (with --summary, also a .jsonl file)")
    p.add_argument("--summary", action="store_true", help="only print the summary of OUT")
    args = p.parse_args(argv)
    if args.max_level is not None and not 0.02 <= args.max_level < 0.9:
        p.error(f"--max-level {args.max_level}: must be a strain from 0.02 (the first level) "
                "to below 0.9")
    out = Path(args.out)
    log = out if args.summary and out.suffix == ".jsonl" else out / "runs.jsonl"
    if args.summary and not log.is_file():
        p.error(f"{log}: no runs recorded there (run without --summary first)")
    if not args.summary:
        out.mkdir(parents=True, exist_ok=True)
        layers = args.layers.split(",")
        jobs = []
        if args.null:
            jobs += [("clean", seed)
                     for seed in range(args.first_seed, args.first_seed + args.null)]
        else:
            names = list(SCENARIOS) if args.scenarios == "all" else args.scenarios.split(",")
            seeds = [int(s) for s in args.seeds.split(",")]
            jobs += [(s, seed) for s in names for seed in seeds]
        for name, seed in jobs:
            scenario, _, own = name.partition("@")
            if scenario not in SCENARIOS:
                p.error(f"unknown scenario {scenario!r}; known: {', '.join(SCENARIOS)}")
            magnitude = float(own) if own else args.magnitude
            try:
                record = run_one(scenario, seed, layers, args.fast, magnitude,
                                 truth_code=args.truth_code, axial_ratio=args.axial_ratio,
                                 contact_noise=args.contact_noise, max_level=args.max_level)
            except Exception as exc:  # one run's failure must not lose the others
                record = {"scenario": scenario, "seed": seed, "layers": layers,
                          "fast": args.fast, "magnitude": magnitude,
                          "truth_code": args.truth_code, "axial_ratio": args.axial_ratio,
                          "contact_noise": args.contact_noise, "max_level": args.max_level,
                          "failed": f"{type(exc).__name__}: {exc}"}
                print(f"{scenario} seed {seed}: failed ({record['failed']})", file=sys.stderr,
                      flush=True)
            else:
                print(f"{scenario} seed {seed}: named {record['named']} "
                      f"(unthresholded {record['named_unthresholded']}), "
                      f"{record['discover_s']:.0f} s", file=sys.stderr, flush=True)
            with log.open("a") as fh:
                fh.write(json.dumps(record, default=float) + "\n")
    records = [json.loads(line) for line in log.read_text().splitlines() if line.strip()]
    print(summarise(records))
    return 1 if any("failed" in r for r in records) else 0


if __name__ == "__main__":
    sys.exit(main())
