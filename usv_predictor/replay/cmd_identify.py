"""`replay identify BAGS... --vessel PRESET`: grey-box identification of the hull derivatives (seed 001).

EKF/RTS smoother -> inverse dynamics minus the preset's propeller and semi-empirical rudder (prior) -> linear
regression of each candidate structure -> leave-one-manoeuvre-out CV -> export of the grey box (model_type
"greybox", or "hybrid" with --hybrid: grey box + MLP residual) through usv_predictor.models.artifact, with the
coefficients, their 95 % CIs, the structure and the data digest in the metadata. See usv_predictor.fitting.identification
and docs/identification.md. Coefficients the data cannot determine are an error naming them unless --prior says
what to do (fix: hold at the preset's value; ridge: pull towards it). --val GLOB: bags (or directories) whose
manoeuvres are only evaluated, never fitted. --report DIR: summary.md and force-decomposition plots
(seed 001 Fig. 13) per manoeuvre.
"""
from __future__ import annotations

import argparse
import glob
import sys
from pathlib import Path
from typing import Any

NAME = "identify"
HELP = "identify the grey-box hull coefficients from bags (EKF/RTS + inverse-dynamics regression) and export the model"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("bags", nargs="+", type=Path, metavar="BAG", help="bags or directories of bags to fit")
    parser.add_argument("--vessel", required=True, help="vessel preset name or YAML path (mass, added mass, rudder, "
                                                        "propeller: the prior knowledge)")
    parser.add_argument("--structure", choices=("mmg", "abkowitz", "auto"), default="auto",
                        help="hull model structure (auto: compare by cross-validation, default)")
    parser.add_argument("--prior", choices=("none", "fix", "ridge"), default="none",
                        help="what to do with coefficients the data cannot determine (default none: refuse, naming them)")
    parser.add_argument("--hybrid", action="store_true", help="add an MLP residual on the accelerations (model_type hybrid)")
    parser.add_argument("--dt", type=float, default=0.2, help="step (s) of the resampled data and the model (default 0.2)")
    parser.add_argument("--val", default=None, metavar="GLOB", help="bags to validate on only (glob)")
    parser.add_argument("--output", type=Path, required=True, help="model file to write (.pt)")
    parser.add_argument("--report", type=Path, default=None, metavar="DIR", help="write summary.md and plots into DIR")


def _log(message: str) -> None:
    print(message, file=sys.stderr)


def _load(paths: list[Path], dt: float) -> list:
    from usv_predictor.errors import BagError, DatasetError
    from usv_predictor.replay.recordings import load_recordings

    try:
        return load_recordings(paths, dt, progress=_log)
    except BagError as err:
        if "engine_rpm" in str(err):
            raise DatasetError(f"identification needs the engine speed (engine_rpm): without it the propeller thrust "
                               f"and the rudder inflow are unknown, so R0 and every speed-dependent hull term cannot be "
                               f"separated from them ({err})") from err
        raise


def run(args: argparse.Namespace) -> dict[str, Any]:
    from usv_predictor.analysis.evaluation import evaluate
    from usv_predictor.errors import DatasetError
    from usv_predictor.fitting import hybrid_fit as hybrid
    from usv_predictor.fitting import identification
    from usv_predictor.physics.vessel import load_vessel

    vessel = load_vessel(args.vessel)
    recordings = _load(list(args.bags), args.dt)
    if not recordings:
        raise DatasetError(f"no usable recordings in {[str(b) for b in args.bags]}")
    result = identification.identify(vessel, recordings, structure=args.structure, prior=args.prior, progress=_log)
    digest = identification.data_digest(recordings)
    hybrid_info = None
    if args.hybrid:
        _log("training the MLP residual")
        module, hybrid_info = hybrid.train_hybrid(result, args.dt)
    else:
        module = hybrid.greybox_module(result, args.dt)
    artifact = hybrid.export_identified(str(args.output), module, result, dt=args.dt, training_data_sha256=digest,
                                       model_type="hybrid" if args.hybrid else "greybox", hybrid=hybrid_info)
    _log(f"wrote {args.output} (model {artifact.model_id}, {artifact.metadata['model_type']}, structure "
         f"{result.structure})")
    out: dict[str, Any] = {"model": str(args.output), "model_id": artifact.model_id,
                           "model_type": artifact.metadata["model_type"], "training_data_sha256": digest,
                           "identification": result.to_json(), "hybrid": hybrid_info}
    if args.val:
        paths = sorted(Path(p) for p in glob.glob(args.val))
        if not paths:
            raise DatasetError(f"--val {args.val!r} matches no bag")
        val = _load(paths, args.dt)
        evaluation = evaluate(artifact, val, progress=_log)
        out["validation"] = evaluation.to_json()
    for c in result.fit.coefficients():
        _log(f"  {c.name:7s} {c.estimate:+.5f}  [{c.ci95[0]:+.5f}, {c.ci95[1]:+.5f}]  prior {c.prior:+.5f}  {c.status}")
    if args.report is not None:
        out["report"] = str(write_report(args.report, result, out))
    return out


# ------------------------------------------------------------------ report


def _plot_forces(path: Path, result: Any, k: int) -> None:
    """Seed 001 Fig. 13: hull / rudder / propeller decomposition and measured vs identified total over time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from usv_predictor.fitting.identification import hull_forces

    d = result.data[k]
    values = result.fit.values()
    hull = hull_forces(result.vessel, values, d.nu, result.fit.u0)
    hull_v = hull_forces(result.vessel, values, d.nu, result.fit.u0,
                         names=[n for n in values if "v" in n.split("_", 1)[-1] and "r" not in n.split("_", 1)[-1]])
    hull_r = hull_forces(result.vessel, values, d.nu, result.fit.u0,
                         names=[n for n in values if "r" in n.split("_", 1)[-1] and "v" not in n.split("_", 1)[-1]])
    model_total = hull + d.rudder + d.propeller
    fig, axes = plt.subplots(3, 1, figsize=(9, 8), sharex=True)
    labels = ("X (N)", "Y (N)", "N (N m)")
    for i, ax in enumerate(axes):
        ax.plot(d.t_s, d.total[:, i], color="k", lw=1.5, label="measured (inverse dynamics)")
        ax.plot(d.t_s, model_total[:, i], color="tab:red", lw=1.0, ls="--", label="identified total")
        ax.plot(d.t_s, hull[:, i], color="tab:blue", lw=0.9, label="hull")
        if i > 0:
            ax.plot(d.t_s, hull_v[:, i], color="tab:cyan", lw=0.7, label="hull(v)")
            ax.plot(d.t_s, hull_r[:, i], color="tab:purple", lw=0.7, label="hull(r)")
        ax.plot(d.t_s, d.rudder[:, i], color="tab:green", lw=0.9, label="rudder (prior)")
        if i == 0:
            ax.plot(d.t_s, d.propeller[:, i], color="tab:orange", lw=0.9, label="propeller (prior)")
        ax.set_ylabel(labels[i])
        ax.grid(alpha=0.3)
        ax.axvspan(d.t_s[0], d.t_s[np.argmax(d.keep)] if d.keep.any() else d.t_s[0], color="0.9")
    axes[0].legend(fontsize=7, ncol=3)
    axes[1].legend(fontsize=7, ncol=3)
    axes[-1].set_xlabel("time (s)")
    fig.suptitle(f"{d.name}: force decomposition ({result.structure}, prior {result.fit.prior_policy})")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_report(directory: Path, result: Any, out: dict[str, Any]) -> Path:
    """summary.md (coefficients, CIs, collinearity, CV) and forces_<k>.png for each manoeuvre."""
    directory.mkdir(parents=True, exist_ok=True)
    lines = [f"# Grey-box identification: {result.vessel.name}", "",
             f"Model `{out['model']}` ({out['model_type']}, id `{out['model_id']}`), structure **{result.structure}**, "
             f"prior policy **{result.fit.prior_policy}**, data sha256 `{out['training_data_sha256'][:16]}`.", "",
             "Manoeuvres: " + ", ".join(d.name for d in result.data), "",
             "## Coefficients (non-dimensional, 95 % CI)", "", "| name | estimate | 95 % CI | prior | status |",
             "|---|---|---|---|---|"]
    for c in result.fit.coefficients():
        lines.append(f"| {c.name} | {c.estimate:+.5f} | [{c.ci95[0]:+.5f}, {c.ci95[1]:+.5f}] | {c.prior:+.5f} | {c.status} |")
    lines += ["", "## Collinearity", ""]
    for e in result.fit.equations:
        pairs = ", ".join(f"{a}~{b} ({rho:+.2f})" for a, b, rho in e.collinearity.pairs) or "none"
        lines.append(f"- {e.equation}: condition number {e.collinearity.condition_number:.3g}; |rho| > 0.9: {pairs}")
    lines += ["", "## Cross-validation (leave one manoeuvre out, hull force NMSE)", ""]
    for cv in result.cross_validation:
        per = ", ".join(f"{k} {v:.4f}" for k, v in cv.per_equation.items())
        lines.append(f"- {cv.structure}: {cv.score:.4f} ({per})")
    lines += ["", "## Notes", ""] + [f"- {n}" for n in result.notes] + ["", "## Force decomposition (seed 001 Fig. 13)", ""]
    for k, d in enumerate(result.data):
        name = f"forces_{k}.png"
        _plot_forces(directory / name, result, k)
        lines.append(f"![{d.name}]({name})")
    path = directory / "summary.md"
    path.write_text("\n".join(lines) + "\n")
    return path
