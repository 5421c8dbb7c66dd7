"""`replay vessel init --name NAME --layout LAYOUT --lpp L --beam B --mass M ... --output FILE.yaml`: a vessel
description from what an owner knows (principal dimensions, actuator geometry, a thruster datasheet, a known
speed), every hydrodynamic value estimated by a published empirical formula and commented with its source.

One warning line (stderr) per input outside a formula's validity range; the file is written atomically and never
over an existing one without --force; it loads with the vessel loader (`replay simulate --vessel FILE`) and is the
prior `replay identify --vessel FILE --prior ridge|fix` refines. The work: usv_predictor.physics.empirical.
"""
from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from usv_predictor.replay.options import finite_float, log, non_negative_float, positive_float, positive_int

NAME = "vessel"
HELP = "write a vessel description (YAML) from principal dimensions, actuator geometry and a thrust datasheet"
INPUTS = ()
OUTPUTS = {"output": "file"}
ACTIONS = ("init",)


def _thrust_point(text: str) -> tuple[float, float]:
    """COMMAND:NEWTONS (e.g. 1:120, 1900:300, 650:2400) as a pair of finite numbers."""
    parts = text.split(":")
    if len(parts) != 2:
        raise argparse.ArgumentTypeError(f"{text!r} is not COMMAND:NEWTONS (e.g. 1:120)")
    return finite_float(parts[0]), finite_float(parts[1])


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from usv_predictor.physics.actuators import ACTUATOR_LAYOUTS
    from usv_predictor.physics.empirical import THRUST_UNITS
    from usv_predictor.physics.hulls import HULL_MODELS

    parser.add_argument("action", choices=ACTIONS, help="init: estimate and write a vessel YAML")
    hull = parser.add_argument_group("hull (SI; positions from midship, + forward)")
    hull.add_argument("--name", required=True, help="vessel name (the YAML's `name`)")
    hull.add_argument("--layout", required=True, choices=sorted(ACTUATOR_LAYOUTS), help="actuator layout")
    hull.add_argument("--hull-model", choices=sorted(HULL_MODELS), default=None,
                      help="hull equations (default: small_craft for twin_thrusters, mmg for rudder layouts)")
    hull.add_argument("--lpp", type=positive_float, required=True, help="length between perpendiculars / waterline (m)")
    hull.add_argument("--beam", type=positive_float, required=True, help="beam (m; a catamaran's overall beam)")
    hull.add_argument("--mass", type=positive_float, required=True, help="displacement (kg)")
    hull.add_argument("--draught", type=positive_float, default=None,
                      help="mean draught (m; or give --block-coefficient)")
    hull.add_argument("--block-coefficient", type=positive_float, default=None,
                      help="C_b (-; of one pontoon for a catamaran); the other of draught and C_b "
                           "follows from the mass")
    hull.add_argument("--length-overall", type=positive_float, default=None, help="length overall (m, default --lpp)")
    hull.add_argument("--x-g", type=finite_float, default=0.0, help="centre of gravity from midship (m, default 0)")
    hull.add_argument("--k-zz", type=positive_float, default=None, help="yaw radius of gyration / L (-, default 0.25)")
    hull.add_argument("--hulls", type=positive_int, choices=(1, 2), default=1, help="1 monohull (default), 2 catamaran")
    hull.add_argument("--demihull-beam", type=positive_float, default=None, help="beam of one pontoon (m, default B/4)")
    hull.add_argument("--freeboard", type=positive_float, default=None,
                      help="deck height above water (m, default 1.5 d)")
    rudder = parser.add_argument_group("rudder and propeller (rudder layouts)")
    rudder.add_argument("--rudder-area", type=positive_float, default=None, help="rudder area (m^2)")
    rudder.add_argument("--rudder-span", type=positive_float, default=None, help="rudder span (m)")
    rudder.add_argument("--rudder-x", type=finite_float, default=None, help="rudder position (m, default -L/2)")
    rudder.add_argument("--rudder-max", type=positive_float, default=35.0, help="rudder limit (deg, default 35)")
    rudder.add_argument("--rudder-rate", type=positive_float, default=20.0,
                        help="steering-gear rate (deg/s, default 20)")
    rudder.add_argument("--propeller-diameter", type=positive_float, default=None, help="propeller diameter (m)")
    rudder.add_argument("--propeller-x", type=finite_float, default=None,
                        help="propeller position (m, default -0.48 L)")
    rudder.add_argument("--pitch-ratio", type=positive_float, default=None,
                        help="P/D (-, default: from the datasheet's static thrust, else 1.0)")
    rudder.add_argument("--blades", type=positive_int, default=4, help="number of blades (default 4)")
    rudder.add_argument("--blade-area-ratio", type=positive_float, default=0.55, help="A_E/A_0 (-, default 0.55)")
    rudder.add_argument("--gear-ratio", type=positive_float, default=1.0, help="engine rpm / propeller rpm (default 1)")
    rudder.add_argument("--rpm-max", type=positive_float, default=None,
                        help="highest engine speed (rpm; default the datasheet's highest)")
    twin = parser.add_argument_group("thrusters (twin_thrusters)")
    twin.add_argument("--thruster-spacing", type=positive_float, default=None,
                      help="distance between the thrust lines (m)")
    twin.add_argument("--thruster-x", type=finite_float, default=None, help="thruster position (m, default -L/2)")
    data = parser.add_argument_group("datasheet and a known speed")
    data.add_argument("--thrust", type=_thrust_point, action="append", default=[], metavar="COMMAND:N",
                      help="static (bollard) thrust of ONE propulsor at a command (repeatable; astern: negative both)")
    data.add_argument("--thrust-unit", choices=THRUST_UNITS, default="normalised",
                      help="unit of the --thrust and --at commands: rpm (engine), pwm (us), throttle (%%), normalised "
                           "(-1..1; default)")
    data.add_argument("--pwm-range", type=finite_float, nargs=3, default=[1100.0, 1500.0, 1900.0],
                      metavar=("MIN", "NEUTRAL", "MAX"), help="PWM of full astern, neutral, full ahead (us)")
    data.add_argument("--engine-time-constant", type=non_negative_float, default=1.0,
                      help="engine / motor lag (s, default 1)")
    data.add_argument("--speed", type=positive_float, default=None,
                      help="straight-running speed through the water at the --at command (m/s): calibrates resistance")
    data.add_argument("--at", type=finite_float, default=None, metavar="COMMAND",
                      help="the command of --speed (in --thrust-unit; twin: both thrusters)")
    out = parser.add_argument_group("output")
    out.add_argument("--output", type=Path, required=True, help="vessel YAML to write")
    out.add_argument("--force", action="store_true", help="replace an existing --output")


def run(args: argparse.Namespace) -> dict[str, Any]:
    from usv_predictor.physics.empirical import OwnerData, init_vessel

    owner = OwnerData(
        name=args.name, layout=args.layout, L_pp=args.lpp, B=args.beam, mass_kg=args.mass, d=args.draught,
        C_b=args.block_coefficient, L_oa=args.length_overall, x_G=args.x_g, k_zz=args.k_zz, hull_model=args.hull_model,
        hulls=args.hulls, demihull_beam=args.demihull_beam, freeboard=args.freeboard, rudder_area=args.rudder_area,
        rudder_span=args.rudder_span, rudder_x=args.rudder_x, rudder_max_deg=args.rudder_max,
        rudder_rate_deg_s=args.rudder_rate, propeller_diameter=args.propeller_diameter, propeller_x=args.propeller_x,
        pitch_ratio=args.pitch_ratio, blades=args.blades, blade_area_ratio=args.blade_area_ratio,
        gear_ratio=args.gear_ratio, rpm_max=args.rpm_max, engine_time_constant_s=args.engine_time_constant,
        thruster_spacing=args.thruster_spacing, thruster_x=args.thruster_x, thrust_points=tuple(args.thrust),
        thrust_unit=args.thrust_unit, pwm_range=tuple(args.pwm_range), speed_m_s=args.speed, speed_command=args.at)
    result = init_vessel(owner, args.output, force=args.force)
    for line in result["warnings"]:
        log(f"warning: {line}")
    speeds = ", ".join(f"{v:.3g} m/s at {k}" for k, v in result["straight_speed_m_s"].items())
    log(f"wrote {args.output} ({result['hull_model']} hull, {result['actuator_layout']}; straight running {speeds})")
    return result
