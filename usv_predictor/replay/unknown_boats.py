"""One boat the tool has never seen, through the public commands: the unknown-boat acceptance pipeline that
test/test_unknown_boats.py and benchmarks/bench_unknown_boats.py share.

    truth (analysis.unknown_boats.draw_boat) --simulate--> a calm day (the layout's: the `training` programme of a
    rudder-and-propeller boat, the calm-day trials docs/your_boat.md asks for of the others, SuiteLayout) and an
    effect day (`diagnosis` programme, one hidden effect, --blind); the truth file is then DELETED, so nothing
    downstream can read it (the bags name it in their custom_data: the layout check finds no file and skips)
    owner's data --`replay vessel init`--> a description (the prior)
    calm day + description --`replay identify --structure S --prior fix`--> the calm-water grey box (S the
    layout's: mmg for a rudder boat, the structure `diagnose --model` takes (it refuses an abkowitz model, naming
    --structure mmg); auto among the small-craft ones for twin thrusters); when identify warns that another prior
    cross-validates far better (`cv_warning`), identify again with the best candidate diagnose takes (what
    docs/your_boat.md tells a user to do)
    effect day + model + description --`replay diagnose --model`--> the named cause, compared with the truth

The calm-day trials of a layout without a programme are simulated as `replay simulate` simulates a programme
(replay.simulate.simulate_bag: the same seeds per manoeuvre, headings and places, blind), one bag per trial.

A fit-check refusal of `diagnose` (exit 2: the identified model does not fit the effect day) is recorded as the
answer `model_mismatch` with `refused: true`: the tool declined to answer, which is what it must do then.
"""
from __future__ import annotations

import contextlib
import io
import json
import time
from pathlib import Path
from typing import Any

from usv_predictor.analysis.hidden_effects import Draw, within_tolerance
from usv_predictor.analysis.unknown_boats import SUITE_LAYOUTS, CalmTrial, UnknownBoat

EFFECT_PROGRAMME = "diagnosis"  # the effect day: turns and zig-zags both ways
PRIOR = "fix"  # docs/your_boat.md step 2: keep the description's value where the data cannot determine a term
STRUCTURE = "mmg"  # the hull structure `diagnose --model` accepts for a rudder-and-propeller boat


def _replay(argv: list[str], log: list[str]) -> int:
    """Run `replay ARGV` in this process; its stderr lines are appended to `log` (one entry per command)."""
    from usv_predictor.replay.cli import main

    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        code = main(argv)
    log.append(f"$ replay {' '.join(argv)}\n{err.getvalue()}(exit {code})")
    return code


def _recommended(identify_json: dict[str, Any], structures: tuple[str, ...] = (STRUCTURE,)) -> str | None:
    """The prior to identify with again when identify's cv_warning says the chosen one cross-validates far worse:
    the best-scoring other candidate of `structures` (the ones diagnose takes); None without a warning or such one."""
    if not identify_json.get("cv_warning"):
        return None
    scored = [c for c in identify_json["cv_candidates"]
              if c["cv_score"] is not None and not c["chosen"] and c["structure"] in structures]
    return min(scored, key=lambda c: c["cv_score"])["prior"] if scored else None


def _simulate_trials(trials: tuple[CalmTrial, ...], vessel: Path, seed: int, heading_deg: float, output: Path,
                     log: list[str]) -> None:
    """The calm day of `trials` (one bag each, output/<trial.bag>) in calm water, blind, as `replay simulate` makes a
    programme's bags (manoeuvre k: seed + 1000 k, its heading and start place); one log entry."""
    from usv_predictor.physics.dynamics import ManoeuvringModel
    from usv_predictor.physics.scenario import make_scenario
    from usv_predictor.physics.vessel import load_vessel
    from usv_predictor.replay.bagio import prepare_outputs
    from usv_predictor.replay.simulate import SimulationRequest, simulate_bag

    command = (f"replay.simulate.simulate_bag x {len(trials)} ({', '.join(t.bag for t in trials)}) --vessel {vessel} "
               f"--blind --seed {seed} --heading {heading_deg:g} --output {output}")
    boat = load_vessel(str(vessel))  # the truth file, read once
    request = SimulationRequest(output=output, vessel=boat, vessel_label=str(vessel), heading_deg=heading_deg,
                                blind=True, seed=seed, command=command)
    scenario = make_scenario(boat, {}, label=str(vessel))
    paths = [output / t.bag for t in trials]
    prepare_outputs(output, paths, overwrite=False)
    model = ManoeuvringModel(boat)
    for index, (path, trial) in enumerate(zip(paths, trials)):
        simulate_bag(path, trial.manoeuvre, scenario, request, seed=seed + 1000 * index, index=index, model=model)
    log.append(f"$ {command}\n(exit 0)")


def run_unknown_boat(boat: UnknownBoat, truth: Draw, workdir: Path, seed: int, *, gain: bool = True,
                     interaction: str = "identify", output_error: str | None = None) -> dict[str, Any]:
    """The pipeline of the module docstring for one boat and one hidden effect, in `workdir` (created).

    interaction: `identify --interaction` of a layout with a rudder behind a propeller (identify: the interaction
    factors searched with the hull, identify's and the benchmark's default; fix: the description's). output_error:
    `identify --output-error` (on / off), or None for identify's default. Returns cause,
    parameters, within_tolerance, errors, the identification chosen (with the terms held and the trial that would
    determine each), the fit check, timings and the commands' logs. A failing simulate or vessel init is a
    RuntimeError (a bug of the suite, not an answer).
    """
    workdir = Path(workdir)
    workdir.mkdir(parents=True, exist_ok=True)
    log: list[str] = []
    started = time.perf_counter()
    truth_file = boat.write_truth(workdir / "truth" / f"{boat.name}.yaml")
    heading = seed % 360
    layout = SUITE_LAYOUTS[boat.layout]
    days = {"calm": (layout.calm_programme, [], seed), "effect": (EFFECT_PROGRAMME, truth.cli_flags(), seed + 1)}
    for day, (programme, flags, day_seed) in days.items():
        if programme is None:  # the layout's calm-day trials
            _simulate_trials(layout.calm_trials, truth_file, day_seed, heading, workdir / day, log)
            continue
        argv = ["simulate", "--programme", programme, "--vessel", str(truth_file), *flags, "--blind",
                "--seed", str(day_seed), "--heading", str((heading + 97 * (day == "effect")) % 360),
                "--output", str(workdir / day)]
        if _replay(argv, log) != 0:
            raise RuntimeError(f"simulating the {day} day failed:\n{log[-1]}")
    truth_file.unlink()  # from here on the truth exists nowhere on disk
    truth_file.parent.rmdir()
    simulated = time.perf_counter()
    description = workdir / f"{boat.owner.name}.yaml"
    if _replay(boat.vessel_init_argv(description), log) != 0:
        raise RuntimeError(f"vessel init failed:\n{log[-1]}")
    model, identify_json = workdir / "calm_water.pt", workdir / "identify.json"
    prior = PRIOR
    out: dict[str, Any] = {"boat": boat.name, "layout": boat.layout, "size_class": boat.size_class,
                           "L_pp_m": boat.owner.L_pp,
                           "truth": truth.effect, "truth_parameters": dict(truth.parameters), "refused": False,
                           "identify_failed": False}
    for attempt in range(2):
        argv = ["identify", str(workdir / "calm"), "--vessel", str(description), "--structure", layout.structure,
                "--prior", prior, *(("--interaction", interaction) if layout.interaction else ()),
                *(("--output-error", output_error) if output_error else ()),
                "--output", str(model), "--json", str(identify_json)]
        if _replay(argv, log) != 0:
            out.update(identify_failed=True, cause="identify_failed", parameters={}, within_tolerance=False,
                       errors={}, log=log, seconds=time.perf_counter() - started)
            return out
        identified = json.loads(identify_json.read_text())
        better = _recommended(identified, layout.diagnosable_structures)
        if better is None or attempt == 1:
            break
        prior = better
    out["identification"] = {"structure": identified["identification"].get("structure"), "prior": prior,
                             "cv_warning": identified.get("cv_warning"),
                             "interaction": identified["identification"].get("interaction"),
                             "held": identified["identification"].get("held", [])}
    identified_at = time.perf_counter()
    diagnosis_json = workdir / "diagnosis.json"
    argv = ["diagnose", str(workdir / "effect"), "--model", str(model), "--vessel", str(description),
            "--json", str(diagnosis_json), *(() if gain else ("--no-gain",))]
    code = _replay(argv, log)
    if code == 2 and not diagnosis_json.exists() and "does not fit these bags" in log[-1]:
        result: dict[str, Any] = {"cause": "model_mismatch", "parameters": {}, "message": log[-1].splitlines()[-2]}
        out["refused"] = True
    elif code != 0:
        raise RuntimeError(f"diagnose failed:\n{log[-1]}")
    else:
        result = json.loads(diagnosis_json.read_text())
    cause = result["cause"]
    ok, errors = within_tolerance(truth, result["parameters"]) if cause == truth.effect else (False, {})
    calm = result.get("calm_water_fit") or {}
    out.update(cause=cause, parameters=result["parameters"], within_tolerance=ok, errors=errors,
               message=result.get("message", ""), confounded_with=result.get("confounded_with", []),
               mismatch_reasons=result.get("mismatch_reasons", []),
               best_environmental_cause=result.get("best_environmental_cause", ""),
               calm_water_heldout_loss=calm.get("heldout_loss"), fit_check=result.get("fit_check"),
               gain=result.get("gain"), rejected_extension=result.get("rejected_extension"),
               seconds={"simulate": simulated - started,
                        "identify": identified_at - simulated, "diagnose": time.perf_counter() - identified_at},
               log=log)
    return out
