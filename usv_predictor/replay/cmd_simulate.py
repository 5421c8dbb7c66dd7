"""`replay simulate`: write rosbag2 recordings of simulated manoeuvres, with the sea and hidden effects.

One bag per manoeuvre, named after it, with the default topics of config/predictor.yaml plus the ground
truth (`ground_truth/odometry`, never used for fitting). The bag's custom_data records how it was made
(command, vessel, scenario, seed, software version), or with --blind only a SHA-256 digest of the scenario so
that a tool under test cannot read the answer from it.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import math
import shlex
import sys
import time
from pathlib import Path

NAME = "simulate"
HELP = "simulate manoeuvres (turning circles, zig-zags, pull-outs, spirals, random) and write rosbag2 bags"

KINDS = ("turning-circle", "zigzag", "pullout", "spiral", "random")
EPOCH_NS = 1_622_527_200 * 1_000_000_000  # 2021-06-01 06:00 UTC: the simulated trial day starts here
GAP_S = 60.0  # time between consecutive manoeuvres of a programme (s)
SPACING_M = 400.0  # distance between the start points of consecutive manoeuvres (m)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from usv_predictor.physics.manoeuvres import PROGRAMMES
    from usv_predictor.physics.scenario import EFFECTS

    what = parser.add_argument_group("what to simulate")
    what.add_argument("--programme", choices=sorted(PROGRAMMES),
                      help="a trial programme: sea_trial (seed 000 Table 3 turns), training, diagnosis")
    what.add_argument("--manoeuvre", choices=KINDS, help="one manoeuvre instead of a programme")
    what.add_argument("--rudder", type=float, default=20.0, help="rudder angle (deg, default 20)")
    what.add_argument("--check", type=float, default=None, help="zig-zag check angle (deg, default = --rudder)")
    what.add_argument("--rpm", type=float, default=650.0, help="engine speed (rpm, default 650)")
    what.add_argument("--side", choices=("starboard", "port"), default="starboard", help="first rudder to (default starboard)")
    what.add_argument("--duration", type=float, default=None, help="duration (s; default per manoeuvre)")
    what.add_argument("--heading", type=float, default=0.0, help="initial heading (deg clockwise from north)")
    what.add_argument("--vessel", default="jari_usv", help="vessel preset in config/vessels (default jari_usv)")
    sea = parser.add_argument_group("sea and hidden effects (DESIGN.md vocabulary)")
    sea.add_argument("--sea", choices=("calm", "rizhao"), default="calm",
                     help="calm water, or the seed 000 trial sea: current + wind + waves (default calm)")
    sea.add_argument("--effect", action="append", default=[], choices=sorted(EFFECTS),
                     help="add a hidden effect (repeatable); its parameters below")
    for effect, params in EFFECTS.items():
        for p in params:
            unit = "PCT" if p.unit == "%" else p.unit.upper().replace("/", "_")
            text = f"{effect}: {p.help} ({p.unit}, default {p.default:g}, range {p.low:g}..{p.high:g})"
            sea.add_argument(p.flag, dest=p.name, type=float, default=None, metavar=unit,
                             help=text.replace("%", "%%"))  # argparse %-formats help texts
    out = parser.add_argument_group("output")
    out.add_argument("--output", type=Path, default=Path("out/simulated"), help="directory for the bags (default out/simulated)")
    out.add_argument("--calm-twin", action="store_true", help="also write the calm-water twin of each bag into OUTPUT/calm")
    out.add_argument("--storage", choices=("sqlite3", "mcap"), default="sqlite3", help="rosbag2 storage (default sqlite3)")
    out.add_argument("--no-compress", action="store_true", help="do not zstd-compress the bags")
    out.add_argument("--overwrite", action="store_true", help="replace existing bags")
    out.add_argument("--blind", action="store_true", help="record only a digest of the scenario in the bag metadata")
    out.add_argument("--seed", type=int, default=0, help="random seed (noise, gusts, waves, random manoeuvre)")
    out.add_argument("--dt", type=float, default=0.05, help="integration step (s, default 0.05)")


def _effects(args: argparse.Namespace) -> dict[str, dict[str, float]]:
    """Effects from --sea and --effect with their flags; a flag without its effect is an error."""
    from usv_predictor.errors import ConfigError
    from usv_predictor.physics.scenario import EFFECTS, RIZHAO_SEA

    chosen = {name: dict(values) for name, values in (RIZHAO_SEA.items() if args.sea == "rizhao" else ())}
    for name in args.effect:
        chosen.setdefault(name, {})
    for effect, params in EFFECTS.items():
        for p in params:
            value = getattr(args, p.name)
            if value is None:
                continue
            if effect not in chosen:
                raise ConfigError(f"{p.flag} belongs to effect {effect!r}: add --effect {effect}")
            chosen[effect][p.name] = value
    return chosen


def _manoeuvres(args: argparse.Namespace, vessel) -> list:
    from usv_predictor.errors import ConfigError
    from usv_predictor.physics import manoeuvres as mv

    if args.programme and args.manoeuvre:
        raise ConfigError("give either --programme or --manoeuvre, not both")
    limit = vessel.actuators.rudder_max_deg
    if not 0.0 <= args.rudder <= limit:
        raise ConfigError(f"--rudder {args.rudder:g} deg is outside the preset's range [0, {limit:g}] deg")
    a = vessel.actuators
    if not a.rpm_min <= args.rpm <= a.rpm_max or args.rpm <= 0.0:
        raise ConfigError(f"--rpm {args.rpm:g} is outside the preset's range ({max(a.rpm_min, 0):g}, {a.rpm_max:g}] rpm")
    if args.duration is not None and not 1.0 <= args.duration <= 3600.0:
        raise ConfigError(f"--duration {args.duration:g} s is outside [1, 3600] s")
    if args.programme:
        return mv.PROGRAMMES[args.programme]()
    side = 1 if args.side == "starboard" else -1
    extra = {} if args.duration is None else {"duration_s": args.duration}
    kind = args.manoeuvre or "turning-circle"
    if kind == "turning-circle":
        return [mv.TurningCircle(args.rudder, args.rpm, side=side, **extra)]
    if kind == "zigzag":
        check = args.rudder if args.check is None else args.check
        if not 0.0 < check <= 90.0:
            raise ConfigError(f"--check {check:g} deg is outside (0, 90] deg")
        return [mv.ZigZag(args.rudder, check, args.rpm, side=side, **extra)]
    if kind == "pullout":
        return [mv.PullOut(args.rudder, args.rpm, side=side, **extra)]
    if kind == "spiral":
        steps = tuple(d for d in (args.rudder, 0.6 * args.rudder, 0.3 * args.rudder, 0.15 * args.rudder, 0.0))
        return [mv.Spiral(rudder_steps_deg=steps + tuple(-d for d in reversed(steps[:-1])), rpm=args.rpm)]
    return [mv.RandomManoeuvre(seed=args.seed, rpm=args.rpm, rudder_max_deg=args.rudder, **extra)]


def _topic_specs():
    from usv_predictor.config import input_topics, load_predictor_config
    from usv_predictor.replay.bagio import TopicSpec

    cfg = load_predictor_config()
    return {t.role: TopicSpec(t.topic, t.role, t.ros_type, t.options, t.frame_id or cfg.base_frame_id)
            for t in input_topics(cfg, include_ground_truth=True)}, cfg


def simulate_bag(path: Path, manoeuvre, scenario, *, seed: int, index: int, args: argparse.Namespace,
                 model=None) -> dict:
    """Simulate one manoeuvre under `scenario` and write its bag; returns a summary."""
    from usv_predictor import __version__
    from usv_predictor.physics.dynamics import ManoeuvringModel
    from usv_predictor.physics.sensors import measure
    from usv_predictor.physics.simulator import NS, simulate
    from usv_predictor.physics.vessel import load_vessel
    from usv_predictor.replay.bagio import write_bag

    model = model or ManoeuvringModel(load_vessel(scenario.vessel))
    start_ns = EPOCH_NS + int(index * (GAP_S + 300.0) * NS)
    heading = args.heading + 37.0 * index  # vary the approach heading across a programme
    traj = simulate(model, manoeuvre, scenario.environment, heading_deg=heading, dt=args.dt,
                    faults=scenario.faults, seed=seed, start_ns=start_ns)
    # Manoeuvres of a trial day start at different places, along a line to the north-east.
    shifted = traj.eta.copy()
    shifted[:, 0] += SPACING_M * index
    shifted[:, 1] += SPACING_M * index
    traj = dataclasses.replace(traj, eta=shifted)
    signals = measure(traj, scenario.environment, scenario.sensor_spec, scenario.faults, seed=seed + 1)
    specs, cfg = _topic_specs()
    streams = [(specs[role], signals[role]) for role in specs if role in signals]
    provenance = {"generator": "usv_predictor replay simulate", "version": __version__,
                  "command": shlex.join(["replay", *sys.argv[1:]]) if sys.argv else "replay simulate",
                  "vessel": scenario.vessel, "manoeuvre": json.dumps(dataclasses.asdict(manoeuvre)),
                  "seed": str(seed), "scenario_sha256": scenario.digest(),
                  "datum": f"{scenario.sensors.datum_lat_deg},{scenario.sensors.datum_lon_deg}"}
    if not args.blind:
        provenance["scenario"] = json.dumps(scenario.describe(), sort_keys=True)
    write_bag(path, streams, storage=args.storage, compress=not args.no_compress,
              metadata=provenance, overwrite=args.overwrite)
    speed = math.hypot(*traj.nu[-1, :2])
    return {"bag": str(path), "manoeuvre": manoeuvre.name, "duration_s": manoeuvre.duration_s,
            "messages": int(sum(len(s) for _, s in streams)), "final_speed_mps": speed,
            "heading_change_deg": math.degrees(traj.psi_unwrapped[-1] - traj.psi_unwrapped[0]),
            "size_bytes": sum(p.stat().st_size for p in Path(path).rglob("*") if p.is_file())}


def run(args: argparse.Namespace) -> dict:
    from usv_predictor.physics.dynamics import ManoeuvringModel
    from usv_predictor.physics.scenario import make_scenario
    from usv_predictor.physics.vessel import load_vessel
    from usv_predictor.replay.bagio import prepare_outputs

    vessel = load_vessel(args.vessel)
    manoeuvres = _manoeuvres(args, vessel)
    scenario = make_scenario(args.vessel, _effects(args))
    jobs = [(args.output / m.name, m, scenario) for m in manoeuvres]
    if args.calm_twin:
        jobs += [(args.output / "calm" / m.name, m, scenario.calm_twin()) for m in manoeuvres]
    prepare_outputs(args.output, [p for p, _, _ in jobs], args.overwrite)
    model = ManoeuvringModel(vessel)
    results = []
    for k, (path, manoeuvre, scen) in enumerate(jobs):
        index = k % len(manoeuvres)  # a calm twin has the same seed, time and place as its sea bag
        started = time.perf_counter()
        summary = simulate_bag(path, manoeuvre, scen, seed=args.seed + 1000 * index, index=index, args=args, model=model)
        results.append(summary)
        print(f"[{k + 1}/{len(jobs)}] {path}  {manoeuvre.duration_s:.0f} s, {summary['messages']} messages, "
              f"{summary['size_bytes'] / 1e6:.2f} MB ({time.perf_counter() - started:.2f} s)", file=sys.stderr)
    return {"bags": results, "scenario": None if args.blind else scenario.describe(),
            "scenario_sha256": scenario.digest()}
