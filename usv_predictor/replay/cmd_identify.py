"""`replay identify BAGS... --vessel PRESET`: grey-box identification of the hull derivatives (seed 001).

EKF/RTS smoother -> inverse dynamics minus the preset's propeller and semi-empirical rudder (prior) -> linear
regression of each candidate structure -> leave-one-manoeuvre-out CV -> export of the grey box (model_type
"greybox", or "hybrid" with --hybrid: grey box + a learned residual ensemble) through usv_predictor.models.artifact,
with the
coefficients, their 95 % CIs, the structure and the data digest in the metadata. See
usv_predictor.fitting.identification
and docs/identification.md. Coefficients the data cannot determine are an error naming them unless --prior says
what to do (fix: hold at the preset's value; ridge: pull towards it); each one the data leave so is printed with the
trial that would determine it (JSON: identification.held[].would_determine). --val GLOB: bags (or directories) whose
manoeuvres are only evaluated, never fitted. --report DIR: summary.md and force-decomposition plots
(seed 001 Fig. 13) per manoeuvre. The bags are read with the vessel's actuator layout: a small-craft twin-thruster
boat identifies its damping and each side's thrust gain (structures diagonal / coupled), a throttle boat its thrust
map's gain, a rudder boat without propulsion data (rudder_only) the hull at an equivalent engine speed per manoeuvre.
--blocks K cuts each recording into K pieces for cross-validation (one long record). --hybrid --base MODEL:
no identification, the residual is trained on top of MODEL's grey box (`replay diagnose --export`'s extension:
the physics explains the sea, the residual what it leaves). --scale LAMBDA Froude-scales
bags of a hull LAMBDA times as long as the vessel file's (full-scale bags, a model-scale vessel) to its size first. The
work: usv_predictor.replay.identify.
"""
from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from usv_predictor.replay.options import add_config_argument, add_scale_argument, log, positive_float, positive_int

NAME = "identify"
HELP = ("identify the grey box of any actuator layout from bags (hull coefficients, thrust-map gains, engine speeds; "
        "EKF/RTS + inverse-dynamics regression) and export the model")
INPUTS = ("bags", "vessel", "base", "config")
OUTPUTS = {"output": "file", "report": "dir"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("bags", nargs="+", type=Path, metavar="BAG", help="bags or directories of bags to fit")
    parser.add_argument("--vessel", default=None, help="vessel preset name or YAML path (mass, added mass, rudder, "
                                                       "propeller, thrusters: the prior knowledge); its actuator "
                                                       "layout says which control topics the bags must carry "
                                                       "(required, unless --base gives it)")
    parser.add_argument("--structure", choices=("mmg", "abkowitz", "diagonal", "coupled", "auto"), default="auto",
                        help="hull model structure: mmg / abkowitz for the MMG hull, diagonal / coupled for the "
                             "small-craft hull (auto: compare the hull model's by cross-validation, default)")
    parser.add_argument("--prior", choices=("none", "fix", "ridge"), default="none",
                        help="what to do with coefficients the data cannot determine (default none: "
                             "refuse, naming them)")
    parser.add_argument("--interaction", choices=("identify", "fix"), default=None,
                        help="rudder_propeller: search the rudder lift gradient, gamma_R, eta, w_P0 and t_P with the "
                             "hull (rudder_only: the rudder's three) on the multi-step simulation error, candidates "
                             "with an implausible steady turn left out, and keep them when the held-out simulation "
                             "error drops (identify, default), or hold the vessel file's (fix; with --base nothing is "
                             "identified); "
                             "usv_predictor/fitting/interaction.py, docs/results/unknown_boats.md")
    parser.add_argument("--output-error", choices=("on", "off"), default="off",
                        help="after the force fit, fit the whole calm-water model on its multi-step simulation error "
                             "over all calm manoeuvres (hull, thrust gains, interaction factors, motor lag; the "
                             "description as a prior), kept when it predicts held-out manoeuvres better, and check it "
                             "stable over the trials' envelope (on), or stop at the force fit (off, default: on the "
                             "unknown-boat suite it names more right causes on twin-thruster boats, 30 against 25 of "
                             "50, but more wrong ones confidently, 5 against 2; docs/results/unknown_boats.md); "
                             "usv_predictor/fitting/output_error.py")
    parser.add_argument("--hybrid", action="store_true",
                        help="add a learned residual on the accelerations: an ensemble of 5 bounded MLPs on "
                             "non-dimensional features, trained by a multi-step loss with early stopping on held-out "
                             "manoeuvres (model_type hybrid; docs/identification.md)")
    parser.add_argument("--hybrid-members", type=positive_int, default=5, metavar="N",
                        help="--hybrid: ensemble members, each its own seed (default 5)")
    parser.add_argument("--hybrid-epochs", type=positive_int, default=150, metavar="N",
                        help="--hybrid: training epochs at most, early stopping on held-out manoeuvres (default 150)")
    parser.add_argument("--base", type=Path, default=None, metavar="MODEL",
                        help="--hybrid: add the residual to this grey box instead of identifying one: `replay diagnose "
                             "--export`'s extended model (calm-water hull + the diagnosed current, wave drift, ...) or "
                             "a `replay identify --structure mmg` model; the physics carries what it explains, the "
                             "residual (bounded by what the base leaves) the rest (model_type hybrid+<causes>)")
    parser.add_argument("--dt", type=positive_float, default=0.2,
                        help="step (s) of the resampled data and the model (default 0.2)")
    parser.add_argument("--val", default=None, metavar="GLOB", help="bags to validate on only (glob)")
    parser.add_argument("--output", type=Path, required=True, help="model file to write (.pt)")
    parser.add_argument("--report", type=Path, default=None, metavar="DIR", help="write summary.md and plots into DIR")
    parser.add_argument("--blocks", type=positive_int, default=1, metavar="K",
                        help="cut each recording into K contiguous pieces, each held out in turn by the cross-"
                             "validation (a single long record; default 1)")
    parser.add_argument("--family", choices=("greybox", "nomoto", "auto"), default="greybox",
                        help="the model family: greybox (the grey box of the vessel's hull model, default: what "
                             "`diagnose` and --hybrid build on), nomoto (the low-order model: Nomoto yaw, a speed "
                             "equation and a drift proportional to r, fitted by output error; what one zig-zag at one "
                             "speed without propulsion data supports), auto (both fitted on the first half of each "
                             "recording and the one that predicts the second half better at 30 s, then 10 s, "
                             "identified on all the data; the errors of both printed); docs/identification.md")
    parser.add_argument("--order", type=positive_int, choices=(1, 2), default=1,
                        help="--family nomoto / auto: the yaw equation's order (default 1)")
    add_scale_argument(parser)
    add_config_argument(parser)


def run(args: argparse.Namespace) -> dict[str, Any]:
    from usv_predictor.fitting.hybrid_fit import HybridTraining
    from usv_predictor.replay.identify import IdentifyRequest, identification_vessel, identify_bags

    if args.family != "greybox":
        from usv_predictor.errors import DatasetError
        from usv_predictor.replay.low_order import LowOrderRequest, identify_low_order

        if args.hybrid or args.base is not None or args.val is not None or args.report is not None \
                or args.vessel is None:
            raise DatasetError(f"--family {args.family} needs --vessel and takes no --hybrid, --base, --val or "
                               "--report (grey-box options)")
        return identify_low_order(LowOrderRequest(
            tuple(args.bags), args.output, args.vessel, family=args.family, order=args.order, dt=args.dt,
            structure=args.structure, prior=args.prior, interaction=args.interaction, blocks=args.blocks,
            config=args.config, scale=args.scale), progress=log)

    training = HybridTraining(members=args.hybrid_members, epochs=args.hybrid_epochs) if args.hybrid else None
    request = IdentifyRequest(bags=tuple(args.bags), output=args.output, structure=args.structure, prior=args.prior,
                              interaction=args.interaction, hybrid=training, dt=args.dt, validation=args.val,
                              report=args.report, blocks=args.blocks, config=args.config, scale=args.scale,
                              base=args.base, output_error=args.output_error == "on")
    vessel, base = identification_vessel(request, args.vessel)
    return identify_bags(request, vessel, base, progress=log)
