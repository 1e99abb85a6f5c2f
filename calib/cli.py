"""The ``calib`` command line; the stable contract is ``shared/CLI.md``.

Every subcommand has ``--help``; every subcommand that reports something has ``--json``, which
prints exactly one JSON object on stdout while progress, logs and warnings go to stderr.
Exit status: 0 success, 1 the work failed (the message says why), 2 bad usage or unreadable
input.

Each subcommand is a pair of functions here, ``_add_<name>`` (its options) and ``_run_<name>``
(the work, returning the exit status); the work itself lives in the noun modules.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time

__all__ = ["main", "UsageError", "WorkFailed"]

EXIT_OK, EXIT_FAILED, EXIT_USAGE = 0, 1, 2


class UsageError(Exception):
    """Bad usage or unreadable input: exit status 2."""


class WorkFailed(Exception):
    """The work failed: exit status 1."""


def _json_default(obj):
    import numpy as np

    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    raise TypeError(f"{type(obj).__name__} is not JSON serialisable")


def _finite_or_none(obj):
    """Replace NaN and infinities (not valid JSON) by None, recursively."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _finite_or_none(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite_or_none(v) for v in obj]
    return obj


def emit_json(obj) -> None:
    """Print exactly one JSON object on stdout."""
    text = json.dumps(_finite_or_none(json.loads(json.dumps(obj, default=_json_default))))
    sys.stdout.write(text + "\n")
    sys.stdout.flush()


def log(message: str) -> None:
    """Progress and notes go to stderr, never stdout."""
    print(message, file=sys.stderr, flush=True)


# ---------------------------------------------------------------------------- simulate
def _add_simulate(sub) -> None:
    p = sub.add_parser(
        "simulate",
        help="one forward FE compression run",
        description="One explicit FE compression run of a cylinder between platens. Writes the "
        "force-travel curve (time_s, displacement_mm, force_N) with --out, or prints it with "
        "--json.",
    )
    p.add_argument("--mu", type=float, default=1875.0, help="shear modulus mu (Pa), default 1875")
    p.add_argument("--alpha", type=float, default=4.9, help="Ogden exponent, default 4.9")
    p.add_argument("--nu", type=float, default=0.499, help="Poisson's ratio, default 0.499")
    p.add_argument("--diameter-mm", type=float, default=38.0, help="sample diameter (mm)")
    p.add_argument("--height-mm", type=float, default=24.0, help="sample height (mm)")
    p.add_argument("--strain", type=float, default=0.3,
                   help="final compression as a fraction of the height, default 0.3")
    p.add_argument("--rate", type=float, default=0.83, help="platen speed (mm/s), default 0.83")
    p.add_argument("--mesh", choices=("axisym", "hex"), default="axisym",
                   help="axisymmetric quads (default) or 3D hexahedra")
    p.add_argument("--platen", choices=("bonded", "frictionless", "coulomb"), default="bonded",
                   help="platen condition, default bonded (sandpaper)")
    p.add_argument("--friction", type=float, default=0.0,
                   help="Coulomb coefficient (with --platen coulomb)")
    p.add_argument("--out", metavar="FILE.csv", help="write the curve as CSV")
    p.add_argument("--vtk", metavar="FILE.vtu",
                   help="write the deformed mesh with displacement and Cauchy / von Mises "
                   "stress fields (.vtu or .vtk, ParaView opens both)")
    p.add_argument("--png", metavar="FILE.png",
                   help="draw the deformed section (axial stress) and the force curve")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    p.set_defaults(handler=_run_simulate)


def _run_simulate(args) -> int:
    import numpy as np

    from solver import CompressionTest, Ogden, SolverInstability, simulate

    from ._io import atomic_write

    try:
        material = Ogden(mu_Pa=args.mu, alpha=args.alpha, nu=args.nu)
        test = CompressionTest(diameter_mm=args.diameter_mm, height_mm=args.height_mm,
                               strain=args.strain, rate_mm_per_s=args.rate,
                               platen=args.platen, friction=args.friction)
    except ValueError as exc:
        raise UsageError(str(exc)) from exc
    for option, path, suffixes in (("--vtk", args.vtk, (".vtu", ".vtk")),
                                   ("--png", args.png, (".png",))):
        if path is not None and not path.lower().endswith(suffixes):
            raise UsageError(f"{option} {path}: the file name must end in "
                             f"{' or '.join(suffixes)}")
    mesh = None
    if args.mesh == "hex":
        from solver import hex_cylinder

        mesh = hex_cylinder(args.diameter_mm, args.height_mm)
        log(f"hexahedral mesh: {mesh.n_cells} elements, {mesh.n_nodes} nodes")
    start = time.perf_counter()
    try:
        result = simulate(material, test, mesh)
    except SolverInstability as exc:
        raise WorkFailed(str(exc)) from exc
    wall = time.perf_counter() - start
    for note in result.notes:
        log(f"note: {note}")
    try:
        if args.vtk:
            result.write_vtk(args.vtk)
            log(f"wrote the deformed mesh to {args.vtk}")
        if args.png:
            result.write_png(args.png)
            log(f"wrote the picture to {args.png}")
    except OSError as exc:
        raise WorkFailed(f"cannot write the output: {exc}") from exc
    if args.out:
        table = np.column_stack([result.time_s, result.displacement_mm, result.force_N])
        with atomic_write(args.out) as fh:
            fh.write("time_s,displacement_mm,force_N\n")
            for row in table:
                fh.write(f"{row[0]:.9g},{row[1]:.9g},{row[2]:.9g}\n")
        log(f"wrote {len(table)} rows to {args.out}")
    if args.json:
        emit_json({
            "time_s": result.time_s, "displacement_mm": result.displacement_mm,
            "force_N": result.force_N, "wall_s": wall, "n_steps": result.n_steps,
            "kinetic_ratio": result.kinetic_ratio, "hourglass_ratio": result.hourglass_ratio,
            "mesh": args.mesh, "n_cells": result.mesh.n_cells,
        })
    elif not args.out:
        print(f"{'displacement_mm':>16} {'force_N':>12}")
        for d, f in zip(result.displacement_mm, result.force_N):
            print(f"{d:16.4f} {f:12.5f}")
    log(f"{result.n_steps} steps in {wall:.3f} s; peak force {result.force_N[-1]:.4f} N at "
        f"{result.displacement_mm[-1]:.3f} mm")
    return EXIT_OK


# ---------------------------------------------------------------------------- export
def _add_export(sub) -> None:
    from .export import FORMATS

    p = sub.add_parser(
        "export",
        help="the per-layer parameter table as csv, json, markdown, latex, Abaqus or FEBio",
        description="Read and validate a per-layer parameter table (parameters.csv as written by "
        "`calib fit`) and render it as csv, json, a markdown or LaTeX (booktabs) table, Abaqus "
        "*HYPERELASTIC, OGDEN cards (with *VISCOELASTIC, TIME=PRONY where fitted) or FEBio "
        "Ogden material XML (c = 2 mu). Writes FILE with --out, otherwise prints to stdout. "
        "Conventions: calib/export.py.",
    )
    p.add_argument("parameters", metavar="PARAMETERS.csv",
                   help="per-layer parameter table (.csv, or .json as written by this command)")
    p.add_argument("--format", dest="fmt", choices=FORMATS, default=None,
                   help="output format; default: from the suffix of --out "
                   "(.csv .json .md .tex .inp .feb)")
    p.add_argument("--out", metavar="FILE", help="write the export to FILE (atomically)")
    p.add_argument("--density", type=float, default=1000.0,
                   help="mass density (kg/m^3) written into the material cards for layers "
                   "without a density_kg_m3 column, default 1000")
    p.add_argument("--json", action="store_true",
                   help="print one JSON object on stdout (format, layers, output file; the "
                   "exported text itself under 'content' when there is no --out)")
    p.set_defaults(handler=_run_export)


def _run_export(args) -> int:
    from ._io import write_text
    from .export import ParameterTableError, export, format_for_path, read_parameters

    fmt = args.fmt
    if fmt is None:
        if not args.out:
            raise UsageError("give --format (csv, json, markdown, latex, abaqus, febio) or an "
                             "--out file whose suffix names one")
        try:
            fmt = format_for_path(args.out)
        except ValueError as exc:
            raise UsageError(f"{exc}; give --format") from exc
    if not (math.isfinite(args.density) and args.density > 0.0):
        raise UsageError(f"--density {args.density}: a density (kg/m^3) must be positive")
    try:
        frame = read_parameters(args.parameters)
        text = export(frame, fmt, density_kg_m3=args.density)
    except ParameterTableError as exc:
        raise UsageError(str(exc)) from exc
    if args.out:
        try:
            write_text(args.out, text)
        except OSError as exc:
            raise WorkFailed(f"cannot write {args.out}: {exc.strerror or exc}") from exc
        log(f"wrote {len(frame)} layer(s) as {fmt} to {args.out}")
    if args.json:
        report = {"format": fmt, "source": args.parameters, "out": args.out,
                  "layers": list(frame["layer"]), "models": list(frame["model"])}
        if not args.out:
            report["content"] = text
        emit_json(report)
    elif not args.out:
        sys.stdout.write(text)
        sys.stdout.flush()
    return EXIT_OK


# ---------------------------------------------------------------------------- inspect
def _add_inspect(sub) -> None:
    p = sub.add_parser(
        "inspect",
        help="load a folder of rig logs and report what was found and rejected",
        description="Load a folder of rig logs (shared/RIG_LOGS.md; sub-folders one level "
        "deep) and report every loading cycle found with what was inferred (sign convention, "
        "units, tare, contact point, peak strain, trimmed spans, warnings) and every file "
        "rejected, with the reason. Exit status 2 if DATA is missing, not a folder, or holds no "
        "readable cycle; rejected files alone do not fail the command. How each quantity is "
        "found: calib/loaders.py.",
    )
    p.add_argument("data", metavar="DATA", help="folder of rig logs")
    p.add_argument("--json", action="store_true",
                   help='print one JSON object {"cycles": [...], "rejected": [...]} on stdout')
    p.set_defaults(handler=_run_inspect)


def _run_inspect(args) -> int:
    campaign = _open_campaign(args.data)
    report = campaign.report()
    if args.json:
        for note in campaign.notes:
            log(f"note: {note}")
        emit_json(report)
    else:
        _print_inspect(campaign)
    log(f"{len(campaign.cycles)} cycles loaded, {len(campaign.rejected)} rejected from "
        f"{args.data}")
    _require_cycles(campaign, args.data)
    return EXIT_OK


def _print_inspect(campaign) -> None:
    """Print the inspect report as a table, then warnings, rejections and notes."""
    rows = [("file", "layer", "sample", "test", "rate mm/s", "sign d/f", "tare N",
             "contact mm", "peak strain", "points", "warnings")]
    for c in campaign.cycles:
        rows.append((c.file, c.layer, c.sample, str(c.test), f"{c.rate_mm_per_s:g}",
                     f"{c.sign['displacement']:+d}/{c.sign['force']:+d}", f"{c.tare_N:.4f}",
                     f"{c.contact_mm:.3f}", f"{c.peak_strain:.3f}", str(c.n_points),
                     str(len(c.warnings))))
    widths = [max(len(r[k]) for r in rows) for k in range(len(rows[0]))]
    for r in rows:
        print("  ".join(cell.ljust(w) if k < 3 else cell.rjust(w)
                        for k, (cell, w) in enumerate(zip(r, widths, strict=True))))
    print(f"\n{len(campaign.cycles)} cycles in {len(campaign.layers())} layers "
          f"({', '.join(campaign.layers())})")
    warned = [c for c in campaign.cycles if c.warnings]
    if warned:
        print("\nWarnings:")
        for c in warned:
            for w in c.warnings:
                print(f"  {c.file}: {w}")
    print(f"\nRejected ({len(campaign.rejected)}):")
    for r in campaign.rejected:
        print(f"  {r.file}: {r.reason}")
    if not campaign.rejected:
        print("  none")
    if campaign.notes:
        print("\nNotes:")
        for note in campaign.notes:
            print(f"  {note}")


# ---------------------------------------------------------------------------- generate
def _add_generate(sub) -> None:
    p = sub.add_parser(
        "generate",
        help="write a synthetic campaign from a known truth",
        description="Write a synthetic campaign in the rig log format (shared/RIG_LOGS.md) "
        "from a known truth: layers A-F x 3 samples x 3 rates, simulated with the forward "
        "solver on a fine mesh, with a realistic sensor model and the file variants of the "
        "contract, plus DIR/truth.json (for tests; the pipeline never reads it). Scenarios: "
        "clean, rate_dependence, platen_slip, contact_offset, machine_compliance, "
        "compressibility, second_ogden_term, preconditioning (experiments/scenarios.py).",
    )
    p.add_argument("--scenario", required=True, metavar="S",
                   help="clean or a hidden effect (see the description)")
    p.add_argument("--out", required=True, metavar="DIR",
                   help="target folder: new or empty (or an earlier campaign with --overwrite)")
    p.add_argument("--seed", type=int, default=0, help="master seed (non-negative), default 0")
    p.add_argument("--magnitude", type=float, default=1.0, metavar="M",
                   help="effect magnitude: 1 moderate (default), 0 reduces to clean")
    p.add_argument("--layers", metavar="A,B",
                   help="comma-separated subset of the layers A-F, default all")
    p.add_argument("--fast", action="store_true",
                   help="simulate on the fitting default mesh (cheap null runs)")
    p.add_argument("--truth-code", choices=("solver", "felupe"), default="solver",
                   help="the code that makes the curves: this project's solver (default) or "
                   "FElupe, an independent static code (pip install felupe; bonded or "
                   "frictionless platens, no Prony terms)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace DIR if it holds an earlier generated campaign (truth.json)")
    p.add_argument("--json", action="store_true",
                   help="print one JSON object summarising what was written")
    p.set_defaults(handler=_run_generate)


def _run_generate(args) -> int:
    from solver import SolverInstability

    try:
        from experiments.generator import CODE_NAMES, CampaignSpec, generate_campaign
    except ImportError as exc:
        raise WorkFailed(f"the experiments package is not importable: {exc}") from exc
    try:
        spec = CampaignSpec(scenario=args.scenario, magnitude=args.magnitude,
                            seed=args.seed, layers=args.layers, fast=args.fast,
                            truth_code=args.truth_code)
    except ValueError as exc:
        raise UsageError(str(exc)) from exc
    try:
        summary = generate_campaign(args.out, spec, overwrite=args.overwrite, progress=log)
    except ImportError as exc:
        raise WorkFailed(f"--truth-code {args.truth_code}: {exc}") from exc
    except FileExistsError as exc:
        raise UsageError(str(exc)) from exc
    except PermissionError as exc:
        raise UsageError(f"{args.out}: {exc.strerror or exc}") from exc
    except SolverInstability as exc:
        raise WorkFailed(f"a forward simulation failed: {exc}") from exc
    except ValueError as exc:
        raise WorkFailed(str(exc)) from exc
    if args.json:
        emit_json(summary.to_dict())
    else:
        print(f"{summary.n_cycles} cycles ({summary.scenario}, M = {summary.magnitude:g}, "
              f"seed {summary.seed}) written to {summary.out}; truth in {summary.truth}")
    log(f"{summary.n_simulations} {CODE_NAMES[summary.truth_code]} runs on a {summary.mesh[0]}x{summary.mesh[1]} mesh; "
        f"{summary.n_bytes / 1e6:.2f} MB in {summary.wall_s:.1f} s")
    return EXIT_OK


# ---------------------------------------------------------------------------- modulus
def _add_modulus(sub) -> None:
    p = sub.add_parser(
        "modulus",
        help="Young's modulus per cycle and its rate dependence per layer",
        description="Young's modulus of every loading cycle from the initial linear region of "
        "its nominal stress-strain curve (the region is chosen from the data and reported), "
        "as the APPARENT modulus of the bonded squat sample and as the MATERIAL modulus "
        "E_apparent / c, c from bonded forward simulations of the sample's own size; then, "
        "per layer, the material modulus against log10(rate): slope per decade with its "
        "confidence interval and p-value (sample as a block, Holm family-wise control over "
        "the layers and a pooled campaign test). Exit status 2 if DATA is missing or holds no "
        "readable cycle, 1 if no modulus can be estimated. Method: calib/modulus.py, "
        "calib/rates.py.",
    )
    p.add_argument("data", metavar="DATA", help="folder of rig logs")
    p.add_argument("--json", action="store_true",
                   help='print one JSON object {"cycles": [...], "layers": [...], ...}')
    p.add_argument("--plot", metavar="FILE.png",
                   help="write the modulus-vs-rate figure (thesis Fig. 11 style) as PNG")
    p.add_argument("--nu", type=float, default=0.499,
                   help="Poisson's ratio of the correction factor's simulations, default 0.499")
    p.add_argument("--alpha", type=float, default=5.0,
                   help="Ogden exponent of the correction factor's simulations, default 5")
    p.add_argument("--significance", type=float, default=0.05,
                   help="family-wise error rate of the rate tests (Holm), default 0.05")
    p.add_argument("--confidence", type=float, default=0.95,
                   help="level of the slope confidence intervals, default 0.95")
    p.set_defaults(handler=_run_modulus)


_MODULUS_CONVENTIONS = {
    "E_apparent_Pa": "slope of nominal stress vs nominal strain in linear_region_strain: the "
                     "APPARENT modulus of the bonded (sandpaper) squat sample, stiffer than "
                     "the material by correction_factor",
    "E_material_Pa": "E_apparent_Pa / correction_factor: the material's small-strain Young's "
                     "modulus, E = 3 mu (incompressible limit; mu the Ogden small-strain shear "
                     "modulus, Abaqus / Miller-Chinzei convention)",
    "initial_mu_Pa": "E_material_Pa / 3, the optimiser's initial guess of mu",
    "correction_factor": "apparent over material modulus of a bonded cylinder of the sample's "
                         "size (shape factor S = R / 2H), from solver.simulate with nu and "
                         "alpha_reference, fitted over the same strain window",
    "slope_per_decade_Pa": "change of E_material_Pa per tenfold increase of the platen speed; "
                           "OLS with one intercept per sample, t-based CI, two-sided p",
    "rate_dependent": "Holm-adjusted p-value <= significance over the layer tests and the "
                      "pooled test",
}


def _run_modulus(args) -> int:
    from .modulus import ModulusError, cycle_modulus
    from .rates import analyse_rates, plot_rates, save_figure

    _check_folder(args.data)
    if not (math.isfinite(args.nu) and -1.0 < args.nu < 0.5):
        raise UsageError(f"--nu {args.nu}: Poisson's ratio must lie in (-1, 0.5)")
    if not (math.isfinite(args.alpha) and args.alpha != 0.0):
        raise UsageError(f"--alpha {args.alpha}: the Ogden exponent must be non-zero")
    for name in ("significance", "confidence"):
        if not 0.0 < getattr(args, name) < 1.0:
            raise UsageError(f"--{name} {getattr(args, name)}: must lie in (0, 1)")
    if args.plot and not args.plot.lower().endswith(".png"):
        raise UsageError(f"--plot {args.plot}: the figure is written as PNG; name it *.png")
    campaign = _load_campaign_arg(args.data)

    start = time.perf_counter()
    results = []
    for k, cycle in enumerate(campaign.cycles, start=1):
        try:
            result = cycle_modulus(cycle, nu=args.nu, alpha=args.alpha)
        except ModulusError as exc:  # bad estimator settings only; curves fail softly
            raise UsageError(str(exc)) from exc
        results.append(result)
        if result.ok:
            log(f"[{k}/{len(campaign.cycles)}] {result.file}: E_apparent "
                f"{result.E_apparent_Pa:.0f} Pa, E_material {result.E_material_Pa:.0f} Pa "
                f"(c = {result.correction_factor:.3f}) over strain "
                f"{result.linear_region_strain[0]:.4f}-{result.linear_region_strain[1]:.4f}")
        else:
            log(f"[{k}/{len(campaign.cycles)}] {result.file}: no modulus: {result.reason}")
    log(f"moduli of {len(results)} cycles in {time.perf_counter() - start:.1f} s")
    good = [r for r in results if r.ok]
    if not good:
        raise WorkFailed(f"no cycle's modulus could be estimated; first reason: "
                         f"{results[0].file}: {results[0].reason}")
    analysis = analyse_rates(good, significance=args.significance, confidence=args.confidence)
    if args.plot:
        try:
            save_figure(plot_rates(analysis, good), args.plot)
        except OSError as exc:
            raise WorkFailed(f"cannot write --plot {args.plot}: {exc.strerror or exc}") from exc
        log(f"wrote {args.plot}")
    report = {
        "cycles": [r.to_dict() for r in results],
        "layers": [t.to_dict() for t in analysis.layers],
        "pooled": analysis.pooled.to_dict(),
        "significance": analysis.significance,
        "confidence": analysis.confidence,
        "rejected": [{"file": r.file, "reason": r.reason} for r in campaign.rejected],
        "failed": [{"file": r.file, "reason": r.reason} for r in results if not r.ok],
        "conventions": _MODULUS_CONVENTIONS,
    }
    if args.json:
        emit_json(report)
    else:
        _print_modulus(results, analysis, campaign.rejected)
    return EXIT_OK


def _print_modulus(results, analysis, rejected) -> None:
    """Print the per-cycle moduli, the per-layer rate trends and what was left out."""

    def table(rows, left):
        widths = [max(len(r[k]) for r in rows) for k in range(len(rows[0]))]
        for r in rows:
            print("  ".join(c.ljust(w) if k < left else c.rjust(w)
                            for k, (c, w) in enumerate(zip(r, widths, strict=True))))

    print("Young's modulus per cycle. E_apparent: slope of the linear region of the bonded, "
          "squat sample\n(shape factor S = R/2H); E_material = E_apparent / c, c from bonded "
          "forward simulations;\nmu0 = E_material / 3.\n")
    rows = [("file", "layer", "sample", "rate mm/s", "strain lo-hi", "E_apparent Pa", "+-",
             "c", "E_material Pa", "mu0 Pa")]
    for r in results:
        if r.ok:
            lo, hi = r.linear_region_strain
            rows.append((r.file, r.layer, r.sample, f"{r.rate_mm_per_s:g}",
                         f"{lo:.4f}-{hi:.4f}", f"{r.E_apparent_Pa:.0f}",
                         f"{r.E_apparent_stderr_Pa:.0f}", f"{r.correction_factor:.3f}",
                         f"{r.E_material_Pa:.0f}", f"{r.initial_mu_Pa:.0f}"))
        else:
            rows.append((r.file, r.layer, r.sample, f"{r.rate_mm_per_s:g}", "-", "-", "-",
                         "-", "-", "-"))
    table(rows, 3)
    conf = int(round(100 * analysis.confidence))
    print(f"\nRate dependence of E_material per layer (sample as block; Holm over "
          f"{len(analysis.layers)} layers + pooled, FWER {analysis.significance:g}):\n")
    rows = [("layer", "cycles", "Pa/decade", f"{conf} % CI", "% /decade", "p", "p Holm",
             "rate dependent")]
    for t in analysis.layers:
        lo, hi = t.slope_ci_Pa
        rows.append((t.layer, str(t.n_cycles), f"{t.slope_per_decade_Pa:+.0f}",
                     f"[{lo:+.0f}, {hi:+.0f}]", f"{100 * t.relative_slope_per_decade:+.1f}",
                     f"{t.p_value:.3g}", f"{t.p_holm:.3g}",
                     "yes" if t.rate_dependent else "no"))
    table(rows, 1)
    p = analysis.pooled
    lo, hi = p.relative_change_ci
    print(f"\npooled (ln E ~ sample + log10 rate): {100 * p.relative_change_per_decade:+.1f} % "
          f"per decade [{100 * lo:+.1f}, {100 * hi:+.1f}], p = {p.p_value:.3g}, Holm "
          f"{p.p_holm:.3g}: {'rate dependent' if p.rate_dependent else 'no significant trend'}")
    notes = [f"{t.layer}: {t.note}" for t in analysis.layers if t.note]
    if p.note:
        notes.append(f"pooled: {p.note}")
    failed = [r for r in results if not r.ok]
    if failed:
        print(f"\nNo modulus ({len(failed)}):")
        for r in failed:
            print(f"  {r.file}: {r.reason}")
    if rejected:
        print(f"\nRejected by the loader ({len(rejected)}):")
        for r in rejected:
            print(f"  {r.file}: {r.reason}")
    if notes:
        print("\nNotes:")
        for n in notes:
            print(f"  {n}")


# ---------------------------------------------------------------------------- shared
def _check_folder(path: str) -> None:
    """Raise UsageError (exit 2) unless ``path`` is an existing folder."""
    import os

    if not os.path.exists(path):
        raise UsageError(f"{path}: no such folder")
    if not os.path.isdir(path):
        raise UsageError(f"{path}: not a folder")


def _open_campaign(path: str):
    """Load the campaign folder named on the command line; unreadable: UsageError (exit 2)."""
    from .loaders import load_campaign

    _check_folder(path)
    try:
        return load_campaign(path)
    except OSError as exc:
        raise UsageError(f"{path}: {exc.strerror or exc}") from exc


def _require_cycles(campaign, path: str) -> None:
    """Raise UsageError (exit 2) if no cycle of the campaign could be read."""
    if not campaign.cycles:
        what = (f"{len(campaign.rejected)} entries rejected" if campaign.rejected
                else "no files found")
        raise UsageError(f"{path}: no readable cycle ({what})")


def _load_campaign_arg(path: str):
    """Load the campaign, log its rejections, require a readable cycle (else exit 2)."""
    campaign = _open_campaign(path)
    for r in campaign.rejected:
        log(f"rejected {r.file}: {r.reason}")
    _require_cycles(campaign, path)
    return campaign


def _csv_list(text: str | None, name: str, convert=str) -> list | None:
    if text is None:
        return None
    try:
        items = [convert(x.strip()) for x in text.split(",") if x.strip()]
    except ValueError as exc:
        raise UsageError(f"--{name} {text!r}: {exc}") from exc
    if not items:
        raise UsageError(f"--{name} {text!r}: empty list")
    return items


# ---------------------------------------------------------------------------- fit
def _add_fit_options(p) -> None:
    p.add_argument("--layers", metavar="A,B", help="comma-separated layers to fit (default all)")
    p.add_argument("--rates", metavar="R1,R2",
                   help="only cycles at these platen speeds, mm/s (default all)")
    p.add_argument("--model", choices=("ogden",), default="ogden",
                   help="constitutive model: one-term Ogden (default)")
    p.add_argument("--nu", type=float, default=0.499, help="Poisson's ratio assumed, default 0.499")
    p.add_argument("--residual", choices=("absolute", "relative"), default="absolute",
                   help="residuals in newtons (default) or relative to the measured force")
    p.add_argument("--workers", type=int, default=None,
                   help="local processes (default: one per core; 1 = in this process)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="fit on a Dask distributed scheduler, e.g. tcp://host:8786")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")


def _add_fit(sub) -> None:
    p = sub.add_parser(
        "fit",
        help="FE-coupled Ogden fit per layer",
        description="Fit Ogden mu and alpha per layer by running the explicit FE simulation of "
        "the bonded compression of every cycle (its own geometry) and comparing at strain "
        "levels along the loading branch. Writes DIR/parameters.csv, per-layer fit and residual "
        "plots and text reports.",
    )
    p.add_argument("data", help="folder of rig logs")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    _add_fit_options(p)
    p.set_defaults(handler=_run_fit)


def _fit_settings(args):
    from .fit import FitSettings

    if not (math.isfinite(args.nu) and -1.0 < args.nu < 0.5):
        raise UsageError(f"--nu {args.nu}: Poisson's ratio must lie in (-1, 0.5)")
    if args.workers is not None and args.workers < 1:
        raise UsageError(f"--workers {args.workers}: must be at least 1")
    return FitSettings(nu=args.nu, residual=args.residual)


def _run_fit_step(args, campaign, out_dir):
    """Fit the layers asked for and write the fit outputs; shared by fit and demo."""
    from .fit import fit_campaign
    from .report import summary_table, write_fit_report

    settings = _fit_settings(args)
    layers = _csv_list(getattr(args, "layers", None), "layers")
    rates = _csv_list(getattr(args, "rates", None), "rates", float)
    if layers:
        missing = sorted(set(layers) - set(campaign.layers()))
        if missing:
            raise UsageError(f"--layers: no cycles of layer(s) {missing} in the data "
                             f"(layers present: {campaign.layers()})")
    result = fit_campaign(campaign, settings, layers=layers, rates=rates,
                          max_workers=args.workers, scheduler=args.scheduler,
                          progress=not args.json)
    for layer, reason in sorted(result.failed.items()):
        log(f"layer {layer} not fitted: {reason}")
    for layer, fit in sorted(result.fits.items()):
        for w in fit.warnings:
            log(f"layer {layer}: {w}")
    if not result.fits:
        raise WorkFailed("no layer could be fitted: "
                         + "; ".join(f"{k}: {v}" for k, v in sorted(result.failed.items())))
    written = write_fit_report(result, campaign, out_dir)
    if not args.json:
        print(summary_table(result))
    log(f"fitted {len(result.fits)} layer(s) in {result.wall_s:.1f} s; wrote "
        f"{written['parameters']}")
    return result, written


def _run_fit(args) -> int:
    campaign = _load_campaign_arg(args.data)
    result, written = _run_fit_step(args, campaign, args.out)
    if args.json:
        emit_json({
            "parameters": result.table().to_dict(orient="records"),
            "failed": result.failed,
            "outputs": written,
            "wall_s": result.wall_s,
            "forward_solves": {k: f.n_solves for k, f in result.fits.items()},
            "warnings": {k: list(f.warnings) for k, f in result.fits.items()},
        })
    return EXIT_OK


# ---------------------------------------------------------------------------- discover
def _add_discover(sub) -> None:
    p = sub.add_parser(
        "discover",
        help="find, name and add the missing effect",
        description="The discrepancy workflow: fit the base model (one-term Ogden, bonded, nu "
        "assumed), find where it disagrees with the data, name the missing effect among "
        "rate_dependence, platen_slip, contact_offset, machine_compliance, compressibility, "
        "second_ogden_term and preconditioning (or none), add it, refit, and show the gap "
        "shrink on fitted and held-out data. Writes a report and plots in DIR.",
    )
    p.add_argument("data", help="folder of rig logs")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.add_argument("--effects", metavar="E1,E2", help="candidate effects (default all)")
    p.add_argument("--nu", type=float, default=0.499, help="Poisson's ratio assumed, default 0.499")
    p.add_argument("--workers", type=int, default=None,
                   help="local processes for the base fits, the effect grids and the candidate "
                        "fits (default: one per core)")
    p.add_argument("--scheduler", metavar="ADDRESS", help="a Dask scheduler to run on")
    p.add_argument("--contact-noise", action="store_true",
                   help="judge with each cycle's scatter of the contact reading in the noise "
                        "model (off by default; see the README's limits)")
    p.add_argument("--max-level", type=float, metavar="STRAIN",
                   help="compare at the default strain levels up to this one only (fraction, "
                        "e.g. 0.22: below where the bulging side folds onto the platens)")
    p.add_argument("--axial-ratio", type=float, default=3.0, metavar="R",
                   help="largest over smallest element height of the fitting mesh, graded "
                        "towards the platens (default 3)")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    p.set_defaults(handler=_run_discover, residual="absolute")


def _discover_settings(args):
    """FitSettings of ``calib discover``: the fit's, its comparison levels and mesh grading."""
    from .fit import DEFAULT_LEVELS

    levels = DEFAULT_LEVELS
    if args.max_level is not None:
        if not (math.isfinite(args.max_level) and DEFAULT_LEVELS[0] <= args.max_level < 0.9):
            raise UsageError(f"--max-level {args.max_level}: must be a strain (fraction) from "
                             f"{DEFAULT_LEVELS[0]} (the first level) to below 0.9")
        levels = tuple(v for v in DEFAULT_LEVELS if v <= args.max_level + 1e-9)
    if not (math.isfinite(args.axial_ratio) and args.axial_ratio >= 1.0):
        raise UsageError(f"--axial-ratio {args.axial_ratio}: must be a number >= 1 (largest "
                         "over smallest element height)")
    return dataclasses.replace(_fit_settings(args), levels=levels,
                               axial_ratio=args.axial_ratio, contact_noise=args.contact_noise)


def _run_discover(args) -> int:
    from .discover import EFFECTS, discover_campaign, write_discovery_report

    settings = _discover_settings(args)
    campaign = _load_campaign_arg(args.data)
    effects = _csv_list(args.effects, "effects") or list(EFFECTS)
    unknown = sorted(set(effects) - set(EFFECTS))
    if unknown:
        raise UsageError(f"--effects: unknown {unknown}; known: {', '.join(EFFECTS)}")
    try:
        result = discover_campaign(campaign, settings=settings, effects=effects,
                                   workers=args.workers, scheduler=args.scheduler,
                                   progress=not args.json, log=log)
    except ValueError as exc:
        raise WorkFailed(str(exc)) from exc
    written = write_discovery_report(result, campaign, args.out)
    if args.json:
        emit_json({**result.to_dict(), "outputs": written})
    else:
        print(f"missing effect: {result.effect}"
              + (f" (equally possible: {', '.join(result.also_possible)})"
                 if result.also_possible else ""))
        for w in result.warnings:
            print(f"warning: {w}")
        print(f"RMS gap: {1e3 * result.rms_before_N:.2f} mN before, "
              f"{1e3 * result.rms_after_N:.2f} mN after; systematic part "
              f"{100 * result.systematic_before:.2f} -> {100 * result.systematic_after:.2f} %")
        print(f"each sample at its own mu, alpha: {1e3 * result.rms_samples_before_N:.2f} mN "
              f"before, {1e3 * result.rms_samples_after_N:.2f} mN after")
        for kind in result.heldout_before:
            b, a = result.heldout_before[kind], result.heldout_after[kind]
            # a sample held out whole has no parameters of its own: only the layer's curve
            own = ("" if kind == "sample" else
                   f" (each sample at its own: {1e3 * b['rms_samples_N']:.2f} -> "
                   f"{1e3 * a['rms_samples_N']:.2f} mN)")
            print(f"held-out (leave one {kind} out): {1e3 * b['rms_N']:.2f} -> "
                  f"{1e3 * a['rms_N']:.2f} mN{own}; "
                  f"systematic {100 * b['systematic']:.2f} -> {100 * a['systematic']:.2f} %")
        print(f"report: {written['markdown']}")
    return EXIT_OK


# ---------------------------------------------------------------------------- demo
def _add_demo(sub) -> None:
    p = sub.add_parser(
        "demo",
        help="the main job on the embedded campaign",
        description="Load the embedded campaign (experiments/campaign), estimate moduli and the "
        "strain-rate dependence, fit Ogden mu and alpha per layer with the FE simulation, "
        "export the table in every format, run the discrepancy workflow, and write everything "
        "into a report folder; prints the per-layer table.",
    )
    p.add_argument("--out", default="demo_report", metavar="DIR",
                   help="report folder (default ./demo_report)")
    p.add_argument("--workers", type=int, default=None,
                   help="local processes (default: one per core)")
    p.add_argument("--scheduler", metavar="ADDRESS", help="a Dask scheduler to run on")
    p.add_argument("--no-discover", action="store_true",
                   help="skip the discrepancy workflow")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    p.set_defaults(handler=_run_demo)


def _run_demo(args) -> int:
    from .demo import run_demo

    if args.workers is not None and args.workers < 1:
        raise UsageError(f"--workers {args.workers}: must be at least 1")
    try:
        summary = run_demo(args.out, workers=args.workers, scheduler=args.scheduler,
                           progress=not args.json, log=log, discover=not args.no_discover)
    except FileNotFoundError as exc:
        raise WorkFailed(str(exc)) from exc
    table = summary.pop("table_text")
    if args.json:
        emit_json(summary)
    else:
        print(table)
        disc = summary.get("discovery")
        if disc:
            print(f"\nmissing effect: {disc['effect']} (RMS gap {1e3 * disc['rms_before_N']:.1f} "
                  f"-> {1e3 * disc['rms_after_N']:.1f} mN)")
        print(f"\nreport: {summary['out']}/summary.md")
    log(f"demo finished in {summary['timings']['total_s']:.1f} s")
    return EXIT_OK


# ---------------------------------------------------------------------------- parser
_SUBCOMMANDS = [_add_demo, _add_inspect, _add_modulus, _add_simulate, _add_fit,
                _add_discover, _add_export, _add_generate]


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with every subcommand."""
    parser = argparse.ArgumentParser(
        prog="calib",
        description="Calibrate Ogden laws of soft-tissue phantoms by fitting an explicit FE "
        "simulation of bonded-platen compression to rig force-displacement logs.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for add in _SUBCOMMANDS:
        add(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``calib`` command; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.handler(args))
    except UsageError as exc:
        print(f"calib {args.command}: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except WorkFailed as exc:
        print(f"calib {args.command}: {exc}", file=sys.stderr)
        return EXIT_FAILED
    except KeyboardInterrupt:
        print(f"calib {args.command}: interrupted", file=sys.stderr)
        return EXIT_FAILED
