"""`replay diagnose`: what the calm-water model gets wrong on measured bags, the named cause, the extended
model and its measured gain on held-out manoeuvres (usv_predictor.analysis.diagnosis).

JSON result: cause, parameters (DESIGN.md vocabulary and units), uncertainty, confounded_with, additional_causes
(further causes added one at a time while the evidence holds, with their parameters), dropped_causes (causes that
no longer earned their place given the others, and why), further_candidate (a further cause not named for want of
evidence alone: evidence between 3 and 5 given the named causes, with the share of the loss and track error it
removes, its parameters fitted with them, and why; null otherwise), evidence (every
hypothesis: held-out loss, gain, log-likelihood evidence, per-fold parameters), discrepancy (what the calm-water
model gets wrong), baseline / extended / gain (evaluation metrics on held-out manoeuvres), notes, calm_water_fit (the
calm-water model's held-out loss and track error before any hypothesis), wave_filter (the wave-frequency motion
measured in straight running and whether the residuals were filtered, data/wave_motion.py), fit_check
(analysis/fit_check.py: a model that does not fit the bags at all is refused, exit 2, unless --no-fit-check),
mismatch_reasons and
best_environmental_cause (cause model_mismatch: the calm-water model itself is wrong, identify it first),
rejected_extension (causes withdrawn because their extension did not lower the held-out 30 s position error),
inconclusive (cause inconclusive: a candidate that explains the held-out loss of a model that fits, but whose
extension does not predict tracks better: its name, parameters and the reasons it is not named; null otherwise),
unexplained (when no physical cause is named, the learned residual of last resort tried on the same held-out
manoeuvres: its held-out loss, evidence, track and 30 s open-loop gains, accepted or why not; cause `unexplained`
when accepted; null when not tried; analysis/diagnosis_unexplained.py).
The work: usv_predictor.replay.diagnose and usv_predictor.analysis.diagnosis_run.
"""
from __future__ import annotations

import argparse
from pathlib import Path

from usv_predictor.replay.options import add_config_argument, add_scale_argument, log, positive_float, positive_int

NAME = "diagnose"
HELP = "name the physical cause of what the calm-water model gets wrong, extend the model, measure the gain"
INPUTS = ("bags", "model", "config")
OUTPUTS = {"export": "file", "report": "dir"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from usv_predictor.data.wave_motion import FILTER_S, MODES
    from usv_predictor.physics.effects import hypothesis_names

    parser.add_argument("bags", nargs="+", type=Path, metavar="BAG",
                        help="bags or directories of bags (a trial programme)")
    parser.add_argument("--vessel", default=None,
                        help="vessel preset or YAML file of the calm-water model (default: with --model the vessel the "
                             "model embeds, else the config's vessel); with --model it must be the model's: one that "
                             "differs is refused, naming the fields")
    parser.add_argument("--model", type=Path, default=None, metavar="M",
                        help="a grey-box model artifact (from `replay identify`) as the calm-water model "
                             "instead of the preset")
    parser.add_argument("--dt", type=positive_float, default=None,
                        help="model step (s; default: what suits the vessel, the largest of 0.5, 0.25, 0.2, 0.1, "
                             "0.05 s that RK4 integrates its fastest hull mode with: 0.5 for jari_usv, 0.25 for otter)")
    parser.add_argument("--hypotheses", nargs="+", default=None, metavar="H", choices=hypothesis_names(),
                        help=f"hypotheses to test (default: those of the vessel's actuator layout among "
                             f"{' '.join(hypothesis_names())})")
    parser.add_argument("--max-causes", type=positive_int, default=2,
                        help="name up to this many causes, added one at a time while each passes the evidence test "
                             "(default 2)")
    parser.add_argument("--horizon", type=positive_float, default=None,
                        help="segment horizon (s; default 40 of the vessel's model steps: 20 for "
                             "jari_usv, 10 for otter)")
    parser.add_argument("--stride", type=positive_float, default=None,
                        help="time between segment starts (s; default 10 of the vessel's model steps: 5 for jari_usv, "
                             "2.5 for otter)")
    parser.add_argument("--no-gain", action="store_true", help="skip the held-out evaluation of the extended model")
    parser.add_argument("--no-unexplained", action="store_true",
                        help="when no physical cause is named, do not try the learned residual of last resort (the "
                             "answer `unexplained`: a grey box + learned residual hybrid trained on one fold of the "
                             "manoeuvres and measured on the other, about a minute per fold)")
    parser.add_argument("--wave-filter", choices=MODES, default=MODES[0],
                        help=f"smooth the residuals over {FILTER_S:g} s so that the hull's wave-frequency motion, "
                             "which a manoeuvring model does not predict, does not count as its error: auto (default) "
                             "when the straight running before the manoeuvres shows it (data/wave_motion.py), on, off")
    parser.add_argument("--export", type=Path, default=None, metavar="PATH",
                        help="write the extended model (TorchScript artifact) for the node; with the answer "
                             "`unexplained`, the hybrid")
    parser.add_argument("--report", type=Path, default=None, metavar="DIR", help="write report.md + plots into DIR")
    parser.add_argument("--include-calm", action="store_true", help="also read calm/ twins under bag directories")
    add_scale_argument(parser)
    add_config_argument(parser)
    parser.add_argument("--no-fit-check", action="store_true",
                        help="proceed when the calm-water model does not fit the bags at all (its steady speed or yaw "
                             "rate at the recorded commands is far off): the answer is then model_mismatch")


def run(args: argparse.Namespace) -> dict:
    from usv_predictor.analysis.diagnosis_run import DiagnosisOptions, calm_water_model
    from usv_predictor.replay.diagnose import DiagnoseRequest, diagnose_bags

    options = DiagnosisOptions(hypotheses=None if args.hypotheses is None else tuple(args.hypotheses),
                               max_causes=args.max_causes, gain=not args.no_gain, export=args.export,
                               report=args.report, fit_check=not args.no_fit_check,
                               unexplained=not args.no_unexplained, wave_filter=args.wave_filter)
    request = DiagnoseRequest(bags=tuple(args.bags), dt=args.dt, horizon_s=args.horizon, stride_s=args.stride,
                              include_calm=args.include_calm, config=args.config, scale=args.scale, options=options)
    return diagnose_bags(request, calm_water_model(args.vessel, args.model, args.config), progress=log)
