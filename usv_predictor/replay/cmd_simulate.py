"""`replay simulate`: write rosbag2 recordings of simulated manoeuvres, with the sea and hidden effects.

One bag per manoeuvre, named after it, with the default topics of config/predictor.yaml plus the ground
truth (`ground_truth/odometry`, never used for fitting). The bag's custom_data records how it was made
(command, vessel, scenario, seed, software version), or with --blind only a SHA-256 digest of the scenario so
that a tool under test cannot read the answer from it. The work: usv_predictor.replay.simulate.
"""
from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path

from usv_predictor.replay.options import finite_float, log, non_negative_int, positive_float
from usv_predictor.replay.simulate import KINDS, SEAS, SIDES, STORAGES, SimulationRequest

NAME = "simulate"
HELP = "simulate manoeuvres (turning circles, zig-zags, pull-outs, spirals, random) and write rosbag2 bags"
INPUTS = ()
OUTPUTS = {"output": "dir"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from usv_predictor.physics.manoeuvres import PROGRAMME_NAMES
    from usv_predictor.physics.scenario import EFFECTS

    what = parser.add_argument_group("what to simulate")
    what.add_argument("--programme", choices=PROGRAMME_NAMES,
                      help="a trial programme: sea_trial (seed 000 Table 3 turns), training, diagnosis; calm_day "
                           "(twin_thrusters: docs/your_boat.md \"Calm-day trials per layout\")")
    what.add_argument("--manoeuvre", choices=KINDS, help="one manoeuvre instead of a programme")
    what.add_argument("--rudder", type=finite_float, default=None,
                      help="rudder angle (deg, default 20; rudder layouts)")
    what.add_argument("--check", type=finite_float, default=None,
                      help="zig-zag check angle (deg, default = --rudder, or 20 for a differential)")
    what.add_argument("--rpm", type=finite_float, default=None,
                      help="engine speed (rpm, default 650; rudder_propeller and rudder_only)")
    what.add_argument("--differential", type=finite_float, default=None,
                      help="twin thrusters: normalised command port - starboard in (0, 2], + turns to starboard "
                           "(default 0.4)")
    what.add_argument("--throttle", type=finite_float, default=None,
                      help="normalised propulsion command in (0, 1]: the throttle of rudder_throttle, the mean of "
                           "both thrusters of twin_thrusters (default 0.6)")
    what.add_argument("--side", choices=SIDES, default="starboard", help="first turn to (default starboard)")
    what.add_argument("--duration", type=positive_float, default=None, help="duration (s; default per manoeuvre)")
    what.add_argument("--heading", type=finite_float, default=0.0, help="initial heading (deg clockwise from north)")
    what.add_argument("--vessel", default="jari_usv",
                      help="vessel preset in config/vessels or a vessel YAML file (default jari_usv)")
    sea = parser.add_argument_group("sea and hidden effects (DESIGN.md vocabulary)")
    sea.add_argument("--sea", choices=SEAS, default="calm",
                     help="calm water, or the seed 000 trial sea: current + wind + waves (default calm)")
    sea.add_argument("--effect", action="append", default=[], choices=sorted(EFFECTS),
                     help="add a hidden effect (repeatable); its parameters below")
    for effect, params in EFFECTS.items():
        for p in params:
            unit = "PCT" if p.unit == "%" else p.unit.upper().replace("/", "_")
            text = f"{effect}: {p.help} ({p.unit}, default {p.default:g}, range {p.low:g}..{p.high:g})"
            sea.add_argument(p.flag, dest=p.name, type=finite_float, default=None, metavar=unit,
                             help=text.replace("%", "%%"))  # argparse %-formats help texts
    out = parser.add_argument_group("output")
    out.add_argument("--output", type=Path, default=Path("out/simulated"),
                     help="directory for the bags (default out/simulated)")
    out.add_argument("--calm-twin", action="store_true",
                     help="also write the calm-water twin of each bag into OUTPUT/calm")
    out.add_argument("--storage", choices=STORAGES, default="sqlite3", help="rosbag2 storage (default sqlite3)")
    out.add_argument("--no-compress", action="store_true", help="do not zstd-compress the bags")
    out.add_argument("--overwrite", action="store_true", help="replace existing bags")
    out.add_argument("--blind", action="store_true", help="record only a digest of the scenario in the bag metadata")
    out.add_argument("--seed", type=non_negative_int, default=0,
                     help="random seed (noise, gusts, waves, random manoeuvre)")
    out.add_argument("--dt", type=positive_float, default=0.05, help="integration step (s, default 0.05)")


def _effects(args: argparse.Namespace) -> dict[str, dict[str, float]]:
    """--effect NAME and the effects' parameter flags -> {effect: {parameter: value}}; a flag whose effect is
    neither added nor part of --sea is an error."""
    from usv_predictor.errors import ConfigError
    from usv_predictor.physics.scenario import EFFECTS, RIZHAO_SEA

    chosen: dict[str, dict[str, float]] = {name: {} for name in args.effect}
    of_sea = set(RIZHAO_SEA) if args.sea == "rizhao" else set()
    for effect, params in EFFECTS.items():
        for p in params:
            value = getattr(args, p.name)
            if value is None:
                continue
            if effect not in chosen and effect not in of_sea:
                raise ConfigError(f"{p.flag} belongs to effect {effect!r}: add --effect {effect}")
            chosen.setdefault(effect, {})[p.name] = value
    return chosen


def run(args: argparse.Namespace) -> dict:
    from usv_predictor.models.loading import resolve_vessel
    from usv_predictor.replay.simulate import simulate

    request = SimulationRequest(
        output=args.output, vessel=resolve_vessel(args.vessel), vessel_label=args.vessel, programme=args.programme,
        manoeuvre=args.manoeuvre,
        rudder_deg=args.rudder, check_deg=args.check, rpm=args.rpm, differential=args.differential,
        throttle=args.throttle, side=args.side, duration_s=args.duration,
        heading_deg=args.heading, sea=args.sea, effects=_effects(args), calm_twin=args.calm_twin,
        storage=args.storage, compress=not args.no_compress, overwrite=args.overwrite, blind=args.blind,
        seed=args.seed, dt=args.dt, command=shlex.join(["replay", *sys.argv[1:]]) if sys.argv else "replay simulate")
    return simulate(request, progress=log)
