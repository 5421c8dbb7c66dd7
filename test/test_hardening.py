"""Bad input, case by case: never a traceback, never touch an input, never leave half a file (the replay side).

Each test is one case of the issue, reproduced on the shipped bags or on short bags simulated here, and run the
way a user runs it (in-process through usv_predictor.replay.cli.main, or as a process where a signal or a
file-size limit is the point). The node's cases are in test_node_smoke.py, test_node.py and test_live.py; the
generated bad inputs in test_fuzz.py.
"""
from __future__ import annotations

import json
import math
import os
import resource
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml
from replay_helpers import (assert_one_line, bag_streams, digest, leftovers, never_returning_model, replay,
                            stop_and_time, write_variant)

from msg_adapters import ROLE_FIELDS
from usv_predictor.atomic import check_outputs, jsonable, write_json_atomic
from usv_predictor.errors import OutputError
from usv_predictor.models.artifact import export_like, load_artifact
from usv_predictor.records import Signal
from usv_predictor.replay import cli
from usv_predictor.replay.options import NUMBER_TYPES
from usv_predictor.replay.recordings import clean_signal

REPO = Path(__file__).resolve().parents[1]
BAGS = REPO / "bags"
ZIGZAG = BAGS / "training" / "zigzag_20_20_port_700rpm"
TURN = BAGS / "sea_trial" / "turning_circle_stbd_15deg_650rpm"
DEFAULT_MODEL = REPO / "models" / "default.pt"


def _simulate(capsys: pytest.CaptureFixture[str], out: Path, *extra: str) -> None:
    for manoeuvre in (["--manoeuvre", "zigzag"], ["--manoeuvre", "turning-circle", "--side", "port"]):
        code, err = replay(capsys, "simulate", *manoeuvre, "--duration", "60", "--no-compress", "--output", out, *extra)
        assert code == 0, err


@pytest.fixture(scope="module")
def short_bags(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two 60 s manoeuvres (a 20/20 zig-zag, a port turn), uncompressed sqlite3: enough for identify and diagnose."""
    out = tmp_path_factory.mktemp("short") / "bags"
    for manoeuvre in (["--manoeuvre", "zigzag"], ["--manoeuvre", "turning-circle", "--side", "port"]):
        assert cli.main(["simulate", *manoeuvre, "--duration", "60", "--no-compress", "--output", str(out)]) == 0
    return out


@pytest.fixture(scope="module")
def one_bag_dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """`replay dataset <one bag>`: every manoeuvre goes to training, the validation split is empty."""
    path = tmp_path_factory.mktemp("ds") / "one.npz"
    assert cli.main(["dataset", str(ZIGZAG), "--output", str(path), "--jobs", "1"]) == 0
    return path


def _failing_model(path: Path) -> Path:
    """A TorchScript model with the shipped metadata and vessel description whose code raises when called."""

    class Raises(torch.nn.Module):
        def forward(self, state: torch.Tensor, controls: torch.Tensor) -> torch.Tensor:
            if bool(state.sum() > -1e30):
                raise RuntimeError("boom: this model always fails")
            return torch.zeros(1, state.shape[0], controls.shape[1], 6)

    export_like(path, Raises(), load_artifact(DEFAULT_MODEL))
    return path


# ------------------------------------------------------------------ tracebacks seen

def test_train_without_a_validation_split_writes_json(one_bag_dataset, tmp_path, capsys) -> None:
    """Was: ValueError: Out of range float values are not JSON compliant: nan (the val loss of no val split)."""
    model, result = tmp_path / "m.pt", tmp_path / "train.json"
    code, err = replay(capsys, "train", one_bag_dataset, "--output", model, "--epochs", "3", "--json", result)
    assert_one_line(code, err, "train", allowed=(0,))
    summary = json.loads(result.read_text())
    assert summary["n_val"] == 0
    assert summary["monitor"] == "train"
    assert summary["val_loss"] is None
    assert load_artifact(model).metadata["training"]["val_loss"] == [None]


def test_train_refuses_a_dataset_holding_nan_naming_the_array(one_bag_dataset, tmp_path, capsys) -> None:
    with np.load(one_bag_dataset) as npz:
        arrays = {name: npz[name] for name in npz.files}
    arrays["X"] = arrays["X"].copy()
    arrays["X"][7, 2] = np.nan
    broken = tmp_path / "nan.npz"
    np.savez_compressed(broken, **arrays)
    code, err = replay(capsys, "train", broken, "--output", tmp_path / "m.pt", "--epochs", "2")
    assert_one_line(code, err, "train", allowed=(2,))
    assert "X holds 1 non-finite value(s) (first at row 7, column" in err
    assert str(broken) in err
    assert not (tmp_path / "m.pt").exists()


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_identify_writes_json_without_nan(tmp_path, capsys, storage) -> None:
    """Was: the NaN-in-JSON crash on an mcap bag and with --prior fix: the variance inflation factor of the
    constant bias regressor (Y_0, N_0) of the Abkowitz structure is undefined and was NaN."""
    bags = tmp_path / "bags"
    _simulate(capsys, bags, "--storage", storage)
    result = tmp_path / "id.json"
    code, err = replay(capsys, "identify", bags, "--vessel", "jari_usv", "--prior", "fix", "--structure", "abkowitz",
                       "--output", tmp_path / "id.pt", "--json", result)
    assert_one_line(code, err, "identify", allowed=(0,))
    collinearity = {c["equation"]: c for c in json.loads(result.read_text())["identification"]["collinearity"]}
    for equation, bias in (("Y", "Y_0"), ("N", "N_0")):
        entry = next(c for name, c in collinearity.items() if name.startswith(equation))
        assert entry["constant_regressors"] == [bias]
        assert bias not in entry["vif"]
        assert all(v is not None and v >= 1.0 for v in entry["vif"].values())
    assert load_artifact(tmp_path / "id.pt").metadata["identification"]["collinearity"]


def test_strict_json_names_the_field_and_writes_nothing(tmp_path) -> None:
    value = {"identification": {"collinearity": [{}, {"vif": {"Y_0": np.float64("nan")}}]}}
    with pytest.raises(OutputError, match=r"field identification\.collinearity\[1\]\.vif\.Y_0 is nan"):
        jsonable(value)
    with pytest.raises(OutputError, match=r"out\.json: field a\[2\] is inf"):
        write_json_atomic(tmp_path / "out.json", {"a": [1, 2.0, math.inf]})
    assert list(tmp_path.iterdir()) == []
    assert jsonable({"p": Path("x"), "n": np.arange(2), "t": (np.float32(1.5), None)}) == \
        {"p": "x", "n": [0, 1], "t": [1.5, None]}


def test_a_model_with_nan_metadata_names_the_field(tmp_path) -> None:
    from usv_predictor.errors import ModelError

    shipped = load_artifact(DEFAULT_MODEL)
    with pytest.raises(ModelError, match=r"metadata: field training\.val_loss\[0\] is nan"):
        export_like(tmp_path / "m.pt", shipped.module, shipped, training={"val_loss": [math.nan]})
    assert list(tmp_path.iterdir()) == []


def test_huge_values_are_dropped_with_a_warning_naming_the_field() -> None:
    t = np.arange(100, dtype=np.int64) * 10_000_000
    values = np.zeros((100, 5))
    values[:, 4] = np.nan  # the IMU's orientation is absent (REP-145) and not used: not a reason to drop
    values[40:45, 0] = 1e30  # yaw rate (rad/s)
    warnings: list[str] = []
    signal_in = Signal(t, values, ROLE_FIELDS["imu"])
    cleaned = clean_signal(signal_in, where="bag: topic 'imu/data'", role="imu", dt=0.5, t_ref_ns=0,
                           warn=warnings.append)
    assert len(cleaned) == 95
    assert np.abs(cleaned.values[:, 0]).max() == 0.0
    assert warnings == ["bag: topic 'imu/data': dropped 5 of 100 samples with implausible values (yaw_rate: 5, e.g. "
                        "1e+30 outside [-3, 3]): corrupt samples, or wrong units in the config?"]


@pytest.mark.parametrize(("role", "field"), [("imu", "yaw_rate"), ("engine_rpm", "rpm"), ("velocity", "u")])
def test_diagnose_on_huge_values(short_bags, tmp_path, capsys, role, field) -> None:
    """Was: RuntimeError: index -9223372036854775808 is out of bounds (the actuator delay fitted to NaN)."""
    bags = tmp_path / "huge"
    for bag in sorted(short_bags.iterdir()):
        streams, custom = bag_streams(bag)
        for spec, sig in streams:
            if spec.role == role:
                sig.values[len(sig) // 3: len(sig) // 3 + 5, sig.fields.index(field)] = 1e30
        write_variant(bags / bag.name, streams, custom)
    code, err = replay(capsys, "diagnose", bags, "--hypotheses", "actuator_delay", "--no-gain")
    assert_one_line(code, err, "diagnose", allowed=(0,))
    assert "dropped 5 of" in err
    assert f"{field}: 5, e.g. 1e+30" in err


OPTION_CASES = [
    ("evaluate", "--horizons", "nan"), ("evaluate", "--horizons", "inf"), ("evaluate", "--stride", "nan"),
    ("evaluate", "--stride", "inf"), ("evaluate", "--dt", "nan"), ("report", "--horizons", "nan"),
    ("report", "--stride", "inf"), ("dataset", "--horizon", "0"), ("dataset", "--horizon", "nan"),
    ("dataset", "--horizon", "inf"), ("diagnose", "--horizon", "0"), ("diagnose", "--horizon", "nan"),
    ("diagnose", "--stride", "inf"), ("simulate", "--seed", "-1"), ("train", "--lr", "nan"),
    ("identify", "--dt", "inf"), ("diagnose", "--hypotheses", "bogus"),
]
REQUIRED = {"dataset": [str(ZIGZAG), "--output", "x.npz"], "train": ["ds.npz", "--output", "m.pt"],
            "identify": [str(ZIGZAG), "--vessel", "jari_usv", "--output", "m.pt"], "diagnose": [str(ZIGZAG)],
            "report": ["--output", "r"], "evaluate": [str(ZIGZAG)], "simulate": ["--output", "s"]}


@pytest.mark.parametrize(("command", "option", "value"), OPTION_CASES)
def test_numbers_that_are_not_numbers_are_usage_errors(tmp_path, capsys, monkeypatch, command, option, value) -> None:
    monkeypatch.chdir(tmp_path)
    code, err = replay(capsys, command, *REQUIRED[command], option, value)
    assert_one_line(code, err, command, allowed=(2,))
    assert f"argument {option}" in err
    assert value in err
    assert list(tmp_path.iterdir()) == []  # refused before any work


def test_every_numeric_option_is_parsed_by_a_checked_type() -> None:
    """No bare float/int: each numeric option refuses nan, inf and out-of-range values at parse time."""
    parser = cli.build_parser([])
    subparsers = next(a for a in parser._actions if a.choices and isinstance(a.choices, dict))
    bare = [(name, action.dest) for name, sub in subparsers.choices.items() for action in sub._actions
            if action.type in (float, int)]
    assert bare == []
    checked = [action.type for sub in subparsers.choices.values() for action in sub._actions
               if action.type in NUMBER_TYPES]
    assert len(checked) >= 40


@pytest.mark.parametrize("command", ["identify", "diagnose"])
def test_an_unwritable_report_directory_is_refused_before_any_work(tmp_path, capsys, command) -> None:
    """Was: a PermissionError traceback after the work. Here the directory lies below a regular file (root may
    write anywhere else; os.access cannot tell, so the tool tries to make a file there)."""
    blocker = tmp_path / "file"
    blocker.write_text("x")
    args = [ZIGZAG, "--vessel", "jari_usv", "--output", tmp_path / "m.pt"] if command == "identify" else [ZIGZAG]
    code, err = replay(capsys, command, *args, "--report", blocker / "report")
    assert_one_line(code, err, command, allowed=(2,))
    assert f"cannot write --report {blocker / 'report'}: {blocker} is not a directory" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]


def test_simulate_below_a_regular_file_is_refused_naming_it(tmp_path, capsys) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("x")
    code, err = replay(capsys, "simulate", "--manoeuvre", "zigzag", "--duration", "5", "--output", blocker / "bags")
    assert_one_line(code, err, "simulate", allowed=(2,))
    assert f"cannot write --output {blocker / 'bags'}: {blocker} is not a directory" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]


def test_a_simulation_that_fails_before_its_first_bag_leaves_no_empty_directory(tmp_path, capsys,
                                                                               monkeypatch) -> None:
    """Was: the output directory was made before any work, so a run that failed left it behind, empty."""
    from usv_predictor.errors import BagError
    from usv_predictor.replay import simulate as simulate_module

    def fails(path, *args, **kwargs):
        raise BagError(f"{path}: the simulation failed (made up by the test)")

    monkeypatch.setattr(simulate_module, "simulate_bag", fails)
    out = tmp_path / "new" / "bags"
    code, err = replay(capsys, "simulate", "--manoeuvre", "zigzag", "--duration", "5", "--output", out)
    assert_one_line(code, err, "simulate", allowed=(2,))
    assert "made up by the test" in err
    assert list(tmp_path.iterdir()) == []


def test_info_on_metadata_that_is_not_utf8(tmp_path, capsys) -> None:
    bag = tmp_path / "bag"
    bag.mkdir()
    for f in ZIGZAG.iterdir():
        (bag / f.name).write_bytes(f.read_bytes())
    (bag / "metadata.yaml").write_bytes((ZIGZAG / "metadata.yaml").read_bytes() + b"\n# \xff\xfe \x80\n")
    code, err = replay(capsys, "info", bag)
    assert_one_line(code, err, "info", allowed=(2,))
    assert f"{bag}: cannot read rosbag2 metadata {bag / 'metadata.yaml'}: not UTF-8 text" in err


@pytest.fixture(scope="module")
def evaluation_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("eval")
    assert cli.main(["evaluate", str(ZIGZAG), str(TURN), "--output", str(out)]) == 0
    return out / "evaluation.json"


def _set(data: dict, path: tuple, value: object) -> None:
    for key in path[:-1]:
        data = data[key]
    data[path[-1]] = value


@pytest.mark.parametrize(("path", "value", "message"), [
    (("summary",), None, "field summary is null, expected an object"),
    (("recordings", 0), None, "field recordings[0] is null, expected an object"),
    (("recordings", 1, "turning", "measured"), None, "field recordings[1].turning.measured is null"),
    (("recordings", 1, "closed_loop_rmse"), None, "field recordings[1].closed_loop_rmse is null"),
    (("recordings", 0, "open_loop", "horizons"), None, "field recordings[0].open_loop.horizons is null"),
    (("model",), None, "field model is null, expected an object"),
    (("recordings", 0, "notes"), None, "field recordings[0].notes is null, expected a list"),
    (("open_loop_horizons_s",), "10", "field open_loop_horizons_s is str, expected a list"),
    (("summary", "mean_rmse_u_mps"), "fast", "field summary.mean_rmse_u_mps is str, expected a finite number"),
])
def test_report_on_an_evaluation_file_with_a_null_section(evaluation_file, tmp_path, capsys, path, value,
                                                         message) -> None:
    """Was: AttributeError on a null section. Now: one line naming the file and the field."""
    data = json.loads(evaluation_file.read_text())
    _set(data, path, value)
    edited = tmp_path / "evaluation.json"
    edited.write_text(json.dumps(data))
    code, err = replay(capsys, "report", edited, "--output", tmp_path / "report")
    assert_one_line(code, err, "report", allowed=(2,))
    assert f"{edited}: not an evaluation file of `replay evaluate`: {message}" in err
    assert not (tmp_path / "report").exists()


def test_report_accepts_the_sections_that_may_be_null(evaluation_file, tmp_path, capsys) -> None:
    data = json.loads(evaluation_file.read_text())
    data["recordings"][0]["turning"] = data["recordings"][0]["zigzag"] = data["recordings"][0]["open_loop"] = None
    data.pop("series_file")
    edited = tmp_path / "evaluation.json"
    edited.write_text(json.dumps(data))
    code, err = replay(capsys, "report", edited, "--output", tmp_path / "report")
    assert_one_line(code, err, "report", allowed=(0,))
    assert (tmp_path / "report" / "report.md").is_file()


def test_an_evaluation_file_with_nan_is_refused(evaluation_file, tmp_path, capsys) -> None:
    edited = tmp_path / "evaluation.json"
    edited.write_text(evaluation_file.read_text().replace('"recordings": [', '"x": NaN, "recordings": [', 1))
    code, err = replay(capsys, "report", edited, "--output", tmp_path / "report")
    assert_one_line(code, err, "report", allowed=(2,))
    assert "NaN is not a JSON number" in err


def test_evaluate_with_a_model_whose_code_raises(tmp_path, capsys) -> None:
    model = _failing_model(tmp_path / "raises.pt")
    code, err = replay(capsys, "evaluate", ZIGZAG, "--model", model)
    assert_one_line(code, err, "evaluate", allowed=(2,))
    assert err.strip().splitlines()[-1] == (f"replay evaluate: error: model {model} fails when run: "
                                            f"RuntimeError: boom: "
                                            "this model always fails")


def test_evaluate_refuses_a_model_slower_than_its_budget(tmp_path, capsys) -> None:
    """A rollout deadline: the model's rollout over the longest horizon is timed at load; slower than
    --rollout-budget is one line with the measured time, exit 2; the default budget takes the shipped model."""
    code, err = replay(capsys, "evaluate", ZIGZAG, "--rollout-budget", "1e-9", "--json", tmp_path / "e.json")
    assert_one_line(code, err, "evaluate", allowed=(2,))
    line = err.strip().splitlines()[-1]
    assert line.startswith(f"replay evaluate: error: model {DEFAULT_MODEL} is too slow for replay evaluate "
                           "(--rollout-budget): a rollout of 120 steps takes "), line  # 60 s at dt 0.5 s
    assert line.endswith(" s (best of 3), more than its budget of 1e-09 s"), line
    assert not (tmp_path / "e.json").exists()
    code, err = replay(capsys, "evaluate", ZIGZAG, "--horizons", "10", "--json", tmp_path / "e.json")
    assert code == 0, err


def _replay_process(argv: list[str], cwd: Path) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "usv_predictor.replay", *argv], cwd=cwd, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, env={**os.environ, "PYTHONPATH": str(REPO)})


@pytest.mark.slow
def test_evaluate_refuses_a_model_that_never_returns(tmp_path) -> None:
    """Was: `evaluate` hung for ever in the model's first rollout. Now the first two-step rollout runs in a guard
    thread with a limit (models/loading.FIRST_CALL_S): one line, exit 2, and the process ends (os._exit: with the
    thread inside torch a normal exit aborts)."""
    model = never_returning_model(tmp_path / "never.pt", DEFAULT_MODEL)
    process = _replay_process(["evaluate", str(ZIGZAG), "--model", str(model), "--json", "out.json"], tmp_path)
    out, err = process.communicate(timeout=120)
    assert process.returncode == 2, err[-3000:]
    assert "Traceback" not in err and "terminate called" not in err, err[-3000:]
    assert err.strip().splitlines()[-1] == (f"replay evaluate: error: model {model}: its first two-step rollout did "
                                            "not return within 5 s")
    assert "model: running" in out
    assert not (tmp_path / "out.json").exists()
    assert leftovers(tmp_path) == []


NEVER_RETURNS = {  # command, signal, exit code, the last line's word
    "evaluate_sigint": ("evaluate", signal.SIGINT, cli.EXIT_INTERRUPTED, "interrupted"),
    "evaluate_sigterm": ("evaluate", signal.SIGTERM, cli.EXIT_TERMINATED, "terminated"),
    "report_sigint": ("report", signal.SIGINT, cli.EXIT_INTERRUPTED, "interrupted"),
}


@pytest.mark.slow
@pytest.mark.parametrize("case", sorted(NEVER_RETURNS))
def test_signals_are_honoured_while_a_model_never_returns(case, tmp_path) -> None:
    """Was: Ctrl-C and SIGTERM were ignored while a model's forward never returned (a Python handler cannot run
    while the main thread is inside torch). The model's code runs in a guard thread while the main thread waits
    (here up to the 60 s of --rollout-budget): the signal ends the command within 2 s, 130 / 143, nothing written."""
    command, sig, exit_code, word = NEVER_RETURNS[case]
    model = never_returning_model(tmp_path / "never.pt", DEFAULT_MODEL)
    process = _replay_process([command, str(ZIGZAG), "--model", str(model), "--rollout-budget", "60", "--output",
                               "out"], tmp_path)
    try:
        assert process.stdout is not None
        assert process.stdout.readline().strip() == "model: running"  # inside the model's loop from now on
        time.sleep(0.3)
    except BaseException:
        process.kill()
        raise
    err, took = stop_and_time(process, sig)
    assert process.returncode == exit_code, err[-3000:]
    assert took < 2.0, f"{case}: ended {took:.2f} s after the signal"
    assert "Traceback" not in err and "terminate called" not in err, err[-3000:]
    assert err.strip().splitlines()[-1] == f"replay {command}: {word}"
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").rglob("*"))
    assert leftovers(tmp_path) == []


# ------------------------------------------------------------------ inputs overwritten

@pytest.mark.parametrize("case", ["dataset_onto_metadata", "evaluate_json_onto_metadata", "train_onto_dataset"])
def test_an_output_that_is_or_is_inside_an_input_is_refused(one_bag_dataset, tmp_path, capsys, case) -> None:
    bag = tmp_path / "bag"
    bag.mkdir()
    for f in ZIGZAG.iterdir():
        (bag / f.name).write_bytes(f.read_bytes())
    dataset = tmp_path / "ds.npz"
    dataset.write_bytes(one_bag_dataset.read_bytes())
    argv, expected = {
        "dataset_onto_metadata": (["dataset", bag, "--output", bag / "metadata.yaml"],
                                  f"--output {bag / 'metadata.yaml'} is inside the input {bag}"),
        "evaluate_json_onto_metadata": (["evaluate", bag, "--json", bag / "metadata.yaml"],
                                        f"--json {bag / 'metadata.yaml'} is inside the input {bag}"),
        "train_onto_dataset": (["train", dataset, "--output", dataset],
                               f"--output {dataset} is the input {dataset}: an input is never replaced"),
    }[case]
    before = digest([bag, dataset])
    code, err = replay(capsys, *argv)
    assert_one_line(code, err, argv[0], allowed=(2,))
    assert expected in err and "reading" not in err  # before any work
    assert digest([bag, dataset]) == before


def test_check_outputs_rules(tmp_path) -> None:
    bag = tmp_path / "bags" / "one"
    bag.mkdir(parents=True)
    (bag / "metadata.yaml").write_text("x")
    check_outputs({"--output": tmp_path / "out.npz"}, [bag])  # apart: fine
    check_outputs({"--output": tmp_path / "bags"}, [bag], directories={"--output"})  # a directory beside: fine
    with pytest.raises(OutputError, match="would replace the directory holding the input"):
        check_outputs({"--output": tmp_path / "bags"}, [bag])  # a file where the directory of an input is
    with pytest.raises(OutputError, match="is inside the input"):
        check_outputs({"--output": tmp_path / "bags" / "one" / ".." / "one" / "x"}, [bag])  # resolved paths
    link = tmp_path / "link"
    link.symlink_to(bag)
    with pytest.raises(OutputError, match="is the input"):
        check_outputs({"--output": link}, [bag])


# ------------------------------------------------------------------ partial files (a process with a file-size limit)

def _limited(limit_bytes: int) -> None:
    resource.setrlimit(resource.RLIMIT_FSIZE, (limit_bytes, limit_bytes))


@pytest.mark.slow
@pytest.mark.parametrize("command", ["train", "identify", "diagnose_export"])
def test_a_full_disk_leaves_no_partial_file(one_bag_dataset, short_bags, tmp_path, command) -> None:
    """Was: SIGABRT inside torch's writer and a `.<name>.<random>.partial` left beside the output. The file-size
    limit (ulimit -f) stands in for a full disk; the inputs are uncompressed, so reading them writes nothing."""
    out = tmp_path / "out"
    out.mkdir()
    target = out / "model.pt"
    argv = {"train": ["train", str(one_bag_dataset), "--output", str(target), "--epochs", "2"],
            "identify": ["identify", str(short_bags), "--vessel", "jari_usv", "--prior", "fix", "--output",
                         str(target)],
            "diagnose_export": ["diagnose", str(short_bags), "--hypotheses", "current", "--no-gain",
                                "--export", str(target)]}[command]
    before = digest([one_bag_dataset, short_bags])
    done = subprocess.run([sys.executable, "-m", "usv_predictor.replay", *argv], capture_output=True, text=True,
                          timeout=600, preexec_fn=lambda: _limited(4096), env={**os.environ, "PYTHONPATH": str(REPO)})
    name = argv[0]
    assert done.returncode == 2, done.stderr[-3000:]
    assert "Traceback" not in done.stderr
    assert done.stderr.strip().splitlines()[-1] == (f"replay {name}: error: cannot write model {target}: "
                                                    "no space left (File too large)")
    assert list(out.iterdir()) == []
    assert leftovers(tmp_path) == []
    assert digest([one_bag_dataset, short_bags]) == before


# ------------------------------------------------------------------ Ctrl-C during a long command

def _interrupt_after(argv: list[str], marker: str, cwd: Path, group: bool = False,
                     sig: int = signal.SIGINT) -> subprocess.CompletedProcess:
    """Run `replay ARGV`, send `sig` once `marker` appears on its stderr (to its process group with `group`, as
    a terminal's Ctrl-C does)."""
    process = subprocess.Popen([sys.executable, "-m", "usv_predictor.replay", *argv], cwd=cwd, text=True,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=group,
                               env={**os.environ, "PYTHONPATH": str(REPO)})
    seen = []
    assert process.stderr is not None
    deadline = time.monotonic() + 300
    for line in process.stderr:
        seen.append(line)
        if marker in line:
            break
        assert time.monotonic() < deadline
    if group:
        os.killpg(process.pid, sig)
    else:
        process.send_signal(sig)
    out, err = process.communicate(timeout=300)
    return subprocess.CompletedProcess(process.args, process.returncode, out, "".join(seen) + err)


INTERRUPTED = {
    "train": (["train", "{dataset}", "--output", "out/m.pt", "--epochs", "100000", "--patience", "0",
               "--progress-s", "0"], "epoch 3/"),
    "simulate": (["simulate", "--programme", "training", "--output", "out/bags"], "[1/4]"),
    "dataset": (["dataset", str(BAGS / "sea_trial"), str(BAGS / "training"), "--include-calm", "--jobs", "2",
                 "--output", "out/ds.npz"], "[1/20]"),
    "evaluate": (["evaluate", "--output", "out/eval"], "[1/6]"),
    "report": (["report", "--output", "out/report"], "[1/6]"),
    "identify": (["identify", str(BAGS / "training"), "--vessel", "jari_usv", "--prior", "fix", "--output",
                  "out/id.pt", "--report", "out/id"], "smoothing"),
    "diagnose": (["diagnose", str(BAGS / "sea_trial"), "--report", "out/diagnosis", "--export", "out/x.pt"],
                 "held-out loss"),
    "convert": (["convert", "{raw}/kvlcc2_hsva_simman2008", "--output", "out/bags"], "[1/"),
}


@pytest.mark.slow
@pytest.mark.parametrize("command", sorted(INTERRUPTED))
def test_ctrl_c_during_a_long_command(command, one_bag_dataset, tmp_path, request) -> None:
    """Was: a KeyboardInterrupt traceback. Now: `replay X: interrupted`, exit 130, no output at all."""
    argv, marker = INTERRUPTED[command]
    raw = request.getfixturevalue("raw_data_dir") if command == "convert" else None
    argv = [a.format(dataset=one_bag_dataset, raw=raw) for a in argv]
    inputs = [Path(a) for a in argv[1:] if Path(a).exists()] or [BAGS]
    before = digest(inputs)
    done = _interrupt_after(argv, marker, tmp_path, group=command == "dataset")
    assert done.returncode == cli.EXIT_INTERRUPTED, done.stderr[-3000:]
    assert "Traceback" not in done.stderr
    assert done.stderr.strip().splitlines()[-1] == f"replay {command}: interrupted"
    written = [p for p in (tmp_path / "out").rglob("*") if p.is_file()] if (tmp_path / "out").exists() else []
    assert leftovers(tmp_path) == []
    if command in ("train", "dataset", "evaluate", "report", "identify", "diagnose"):
        assert written == []  # interrupted before the outputs: nothing (every writer is atomic and writes last)
    assert digest(inputs) == before


@pytest.mark.slow
def test_sigterm_during_a_long_command(one_bag_dataset, tmp_path) -> None:
    """SIGTERM (a service manager, a CI timeout) unwinds like Ctrl-C: `terminated`, exit 143, nothing written."""
    argv, marker = INTERRUPTED["train"]
    done = _interrupt_after([a.format(dataset=one_bag_dataset) for a in argv], marker, tmp_path, sig=signal.SIGTERM)
    assert done.returncode == cli.EXIT_TERMINATED == 143, done.stderr[-3000:]
    assert "Traceback" not in done.stderr
    assert done.stderr.strip().splitlines()[-1] == "replay train: terminated"
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").rglob("*"))
    assert leftovers(tmp_path) == []


@pytest.mark.slow
def test_sighup_during_a_long_command(one_bag_dataset, tmp_path) -> None:
    """Was: SIGHUP (the terminal closed) killed the process as signal 1, leaving the atomic writer's temporary
    file. Now it unwinds like SIGTERM: `hung up`, exit 129, nothing written."""
    argv, marker = INTERRUPTED["train"]
    done = _interrupt_after([a.format(dataset=one_bag_dataset) for a in argv], marker, tmp_path, sig=signal.SIGHUP)
    assert done.returncode == cli.EXIT_HUNG_UP == 129, done.stderr[-3000:]
    assert "Traceback" not in done.stderr and done.stderr.strip().splitlines()[-1] == "replay train: hung up"
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").rglob("*"))
    assert leftovers(tmp_path) == []


def test_ctrl_c_inside_exec_still_ends_with_130(tmp_path) -> None:
    """Was: exit by SIGINT (returncode -2) although `interrupted` was printed, when Ctrl-C fell inside exec() (torch
    importing makes its dataclasses with exec: test_fuzz's SIGINT at a random moment found it). CPython marks the
    interpreter when a KeyboardInterrupt leaves exec's code, and a program run with -m then ends itself with SIGINT,
    caught or not. The program's main now ends a Ctrl-C'd run with os._exit(130) after the atexit handlers. Here the
    command raises the interrupt inside exec(), deterministically, in a program run as `python -m` is."""
    (tmp_path / "replay_interrupted_in_exec.py").write_text(
        "import sys\n"
        "from usv_predictor.replay import cli, cmd_info\n"
        "def run(_args):\n"
        "    exec('raise KeyboardInterrupt')\n"
        "cmd_info.run = run\n"
        "sys.exit(cli.main())\n")
    done = subprocess.run([sys.executable, "-m", "replay_interrupted_in_exec", "info", str(BAGS / "training")],
                          capture_output=True, text=True, timeout=120,
                          env={**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), str(tmp_path)])})
    assert done.returncode == cli.EXIT_INTERRUPTED, (done.returncode, done.stderr[-3000:])
    assert done.stderr.strip().splitlines() == ["replay info: interrupted"]


@pytest.mark.slow
def test_ctrl_c_while_the_command_unwinds_ends_with_130(tmp_path) -> None:
    """Was: exit by SIGINT (returncode -2, test_fuzz's Ctrl-C to `dataset` as it finished) when Ctrl-C fell after the
    command's end, while replay's _run unwound (its finally restoring the signal handlers): the interrupt left main
    uncaught. Here _run itself raises it, in a program run as `python -m` is."""
    (tmp_path / "replay_late_interrupt.py").write_text(
        "import sys\n"
        "from usv_predictor.replay import cli\n"
        "def _run(argv):\n"
        "    raise KeyboardInterrupt\n"
        "cli._run = _run\n"
        "sys.exit(cli.main())\n")
    done = subprocess.run([sys.executable, "-m", "replay_late_interrupt", "info", str(BAGS / "training")],
                          capture_output=True, text=True, timeout=120,
                          env={**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), str(tmp_path)])})
    assert done.returncode == cli.EXIT_INTERRUPTED, (done.returncode, done.stderr[-3000:])
    assert done.stderr.strip().splitlines() == ["replay: interrupted"]


def _raises_system_error_from(cause: BaseException | None) -> Callable:
    def run(_args: object) -> dict:
        if cause is None:
            raise SystemError("a bug of a compiled function")
        try:
            raise cause
        except BaseException as err:  # what CPython does when a C function returns a result with an exception set
            raise SystemError("<built-in function> returned a result with an exception set") from err
    return run


@pytest.mark.parametrize("cause, code, word", [(KeyboardInterrupt(), cli.EXIT_INTERRUPTED, "interrupted"),
                                               (cli._Terminated(signal.SIGTERM), cli.EXIT_TERMINATED, "terminated")])
def test_a_system_error_caused_by_a_signal_ends_as_that_signal(monkeypatch, capsys, cause, code, word) -> None:
    """A stop signal raised inside the Python code a compiled function's wrapper runs comes out of the call as a
    SystemError caused by it: the command ends as the signal does, one line, no traceback."""
    from usv_predictor.replay import cmd_info

    monkeypatch.setattr(cmd_info, "run", _raises_system_error_from(cause))
    assert cli.main(["info", str(BAGS / "training")]) == code
    err = capsys.readouterr().err
    assert "Traceback" not in err and err.strip().splitlines() == [f"replay info: {word}"]


def test_a_system_error_without_a_signal_stays_a_bug(monkeypatch) -> None:
    from usv_predictor.replay import cmd_info

    monkeypatch.setattr(cmd_info, "run", _raises_system_error_from(None))
    with pytest.raises(SystemError, match="a bug of a compiled function"):
        cli.main(["info", str(BAGS / "training")])


# ------------------------------------------------------------------ bounded reading, typed fields, model metadata

def _alias_bomb(levels: int = 9, width: int = 9) -> str:
    """The "billion laughs": `levels` anchors of `width` aliases of the one before, width**levels nodes expanded."""
    lines = [f"lol0: &a0 [{', '.join(['lol'] * width)}]"]
    lines += [f"lol{i}: &a{i} [{', '.join([f'*a{i - 1}'] * width)}]" for i in range(1, levels + 1)]
    return "\n".join(lines)


DEEP = 100_000  # levels of nesting: far past Python's recursion limit


@pytest.fixture(scope="module")
def plain_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One 20 s zig-zag, uncompressed sqlite3 (its message definitions can be edited in place)."""
    out = tmp_path_factory.mktemp("plain") / "bags"
    assert cli.main(["simulate", "--manoeuvre", "zigzag", "--duration", "20", "--no-compress", "--output",
                     str(out)]) == 0
    return next(out.iterdir())


def _recursive_definition(bag: Path) -> None:
    import sqlite3

    with sqlite3.connect(next(bag.glob("*.db3"))) as db:
        db.execute("UPDATE message_definitions SET encoded_message_definition = ? WHERE topic_type = ?",
                   ("sensor_msgs/Imu inner\nfloat64 x\n", "sensor_msgs/msg/Imu"))


def _metadata_to_dev_zero(bag: Path) -> None:
    (bag / "metadata.yaml").unlink()
    os.symlink("/dev/zero", bag / "metadata.yaml")


def _db3_fifo(bag: Path) -> None:
    db3 = next(bag.glob("*.db3"))
    db3.unlink()
    os.mkfifo(db3)


def _metadata_edit(extra: str) -> Callable[[Path], None]:
    def edit(bag: Path) -> None:
        text = (bag / "metadata.yaml").read_text()
        (bag / "metadata.yaml").write_text(text.replace("rosbag2_bagfile_information:\n",
                                                        "rosbag2_bagfile_information:\n" + extra + "\n", 1))
    return edit


BAG_CASES: dict[str, tuple[Callable[[Path], None], str]] = {  # how the bag is broken -> what the one line says
    "recursive_message_definition": (_recursive_definition, "a message definition it carries refers to itself"),
    "metadata_is_dev_zero": (_metadata_to_dev_zero, "character device, expected a regular file"),
    "db3_is_a_fifo": (_db3_fifo, "FIFO (named pipe), expected a regular file"),
    "deep_custom_data": (_metadata_edit("  custom_data_deep: " + "[" * DEEP + "]" * DEEP), "nested deeper than"),
    "alias_bomb": (_metadata_edit("\n".join("  " + line for line in _alias_bomb().splitlines())),
                   "expands to more than"),
    "python_tag": (_metadata_edit("  x: !!python/object/apply:os.system ['echo never']"), "constructor for the tag"),
}


@pytest.mark.parametrize("command", ["info", "dataset", "evaluate"])
@pytest.mark.parametrize("case", sorted(BAG_CASES))
def test_a_bag_that_cannot_be_read_within_bounds_is_one_line(plain_bag, tmp_path, capsys, case, command) -> None:
    """Was: RecursionError, MemoryError tracebacks, a hang (sqlite opening a FIFO), exit 1. Now one line, exit 2."""
    bag = tmp_path / "in" / plain_bag.name
    shutil.copytree(plain_bag, bag)
    make, expected = BAG_CASES[case]
    make(bag)
    before = digest([f for f in bag.iterdir() if f.is_file()])
    argv = {"info": [bag], "dataset": [bag, "--output", tmp_path / "ds.npz", "--jobs", "1"],
            "evaluate": [bag, "--output", tmp_path / "eval"]}[command]
    code, err = replay(capsys, command, *argv)
    assert_one_line(code, err, command, allowed=(2,))
    if command == "info" or case not in ("metadata_is_dev_zero",):  # a directory without a readable metadata.yaml
        assert expected in err, err                                   # is no bag to a command that searches
    assert digest([f for f in bag.iterdir() if f.is_file()]) == before and leftovers(tmp_path) == []


def test_a_bag_tree_with_links_to_itself_is_searched_once(plain_bag, tmp_path, capsys) -> None:
    """Was: a hang (two links to `.` make the search exponential). Now each directory is searched once."""
    root = tmp_path / "tree"
    shutil.copytree(plain_bag, root / plain_bag.name)
    os.symlink(".", root / "again")
    os.symlink(".", root / "and_again")
    os.symlink("..", root / plain_bag.name / "up")
    code, err = replay(capsys, "dataset", root, "--output", tmp_path / "ds.npz", "--jobs", "1")
    assert_one_line(code, err, "dataset", allowed=(0,))
    from usv_predictor.replay.recordings import find_bags

    assert [b.path for b in find_bags([root])] == [root / plain_bag.name]


def _vessel_file(tmp_path: Path, file_name: str = "boat.yaml", **changes: object) -> Path:
    """jari_usv as a vessel file, with `changes` (section.field or top-level key -> value)."""
    raw = yaml.safe_load((REPO / "config" / "vessels" / "jari_usv.yaml").read_text())
    for key, value in changes.items():
        section, _, field = key.partition("__")
        if field:
            raw[section][field] = value
        else:
            raw[section] = value
    path = tmp_path / file_name
    path.write_text(yaml.safe_dump(raw))
    return path


def _text_file(text: str) -> Callable[[Path], Path]:
    def make(tmp_path: Path) -> Path:
        path = tmp_path / "boat.yaml"
        path.write_text(text)
        return path
    return make


def _fifo(tmp_path: Path) -> Path:
    os.mkfifo(tmp_path / "boat.yaml")
    return tmp_path / "boat.yaml"


def _huge(tmp_path: Path) -> Path:
    path = tmp_path / "boat.yaml"
    with path.open("wb") as out:  # 200 MB that take no disk: a sparse file, refused by its size before any read
        out.truncate(200 << 20)
    return path


def _link_loop(tmp_path: Path) -> Path:
    os.symlink(tmp_path / "boat.yaml", tmp_path / "boat.yaml")
    return tmp_path / "boat.yaml"


VESSEL_CASES: dict[str, tuple[Callable[[Path], Path], str]] = {
    "mass_as_a_list": (lambda t: _vessel_file(t, geometry__displacement_kg=[1.0, 2.0]),
                       "section 'geometry'.displacement_kg must be a finite number, got [1.0, 2.0]"),
    "coefficients_as_a_number": (lambda t: _vessel_file(t, wave_drift__a_x=0.5), "wave_drift'.a_x must be a list"),
    "section_as_a_list": (lambda t: _vessel_file(t, geometry=[1, 2]), "missing section 'geometry'"),
    "layout_as_a_list": (lambda t: _vessel_file(t, actuator_layout=["rudder_propeller"]),
                         "actuator_layout must be a text"),
    "name_as_a_path": (lambda t: _vessel_file(t, name="../../etc/boat"), "is not a vessel name"),
    "deep_nesting": (_text_file("geometry: " + "[" * DEEP + "]" * DEEP), "nested deeper than"),
    "alias_bomb": (_text_file(_alias_bomb()), "expands to more than"),
    "python_tag": (_text_file("name: !!python/object/apply:os.system ['echo never']\n"), "constructor for the tag"),
    "a_cycle": (_text_file("geometry: &g\n  inner: *g\n"), "refers to a node that holds it"),
    "fifo": (_fifo, "FIFO (named pipe), expected a regular file"),
    "200_MB": (_huge, "more than the"),
    "link_loop": (_link_loop, "a loop of symbolic links"),
}


@pytest.mark.parametrize("case", sorted(VESSEL_CASES))
def test_a_vessel_file_is_type_checked_and_read_within_bounds(tmp_path, capsys, case) -> None:
    """Was: a TypeError traceback (a mass given as a list), RecursionError (deep nesting), a hang (a FIFO, 200 MB).
    Now one line naming the file and the field, exit 2, before any work."""
    make, expected = VESSEL_CASES[case]
    path = make(tmp_path)
    out = tmp_path / "out"
    code, err = replay(capsys, "simulate", "--vessel", path, "--manoeuvre", "zigzag", "--duration", "5",
                       "--output", out)
    assert_one_line(code, err, "simulate", allowed=(2,))
    assert expected in err and str(path) in err, err
    assert not out.exists() or not any(out.iterdir())


PREDICTOR_CASES: dict[str, tuple[str | None, str]] = {
    "alias_bomb": ("predictor:\n  ros__parameters:\n" + "\n".join("    " + line for line in _alias_bomb().splitlines()),
                   "expands to more than"),
    "python_tag": ("predictor:\n  ros__parameters: !!python/object/new:dict {}\n", "constructor for the tag"),
    "deep_nesting": ("predictor:\n  ros__parameters:\n    inputs: " + "{a: " * DEEP + "1" + "}" * DEEP,
                     "nested deeper than"),
    "dev_zero": (None, "character device, expected a regular file"),
}


@pytest.mark.parametrize("case", sorted(PREDICTOR_CASES))
def test_a_predictor_config_is_read_within_bounds(plain_bag, tmp_path, capsys, case) -> None:
    """Was: a parser's caret lines, a MemoryError (/dev/zero). Now one line naming the file, exit 2."""
    text, expected = PREDICTOR_CASES[case]
    config = Path("/dev/zero") if text is None else tmp_path / "predictor.yaml"
    if text is not None:
        config.write_text(text)
    code, err = replay(capsys, "dataset", plain_bag, "--config", config, "--output", tmp_path / "ds.npz")
    assert_one_line(code, err, "dataset", allowed=(2,))
    assert expected in err and f"predictor config {config}" in err, err


MODEL_CASES: dict[str, tuple[dict[str, object], tuple[str, ...], str]] = {  # metadata changes, keys dropped, message
    "control_layout_int": ({"control_layout": 3}, (), "control_layout = 3 must be a non-empty list"),
    "control_layout_null": ({"control_layout": None}, (), "control_layout = None must be a non-empty list"),
    "ensemble_size_five": ({"ensemble_size": "five"}, (), "ensemble_size = 'five' must be an integer >= 1"),
    "dt_as_text": ({"dt": "0.5"}, (), "dt = '0.5' must be a finite number"),
    "vessel_name_a_path": ({"vessel": "../../../tmp/boat"}, ("vessel_sha256",), "is not a vessel name"),
    "vessel_name_a_file": ({"vessel": "boat.yaml"}, ("vessel_sha256",), "is not a vessel name"),
}


@pytest.mark.parametrize("case", sorted(MODEL_CASES))
def test_model_metadata_is_checked_field_by_field(tmp_path, capsys, case) -> None:
    """Was: a TypeError traceback in evaluate (control_layout an int or null), an evaluation through a vessel named
    by a `../` path. Now one line naming the file and the field, exit 2, nothing written."""
    from replay_helpers import write_model_with_metadata

    changes, drop, expected = MODEL_CASES[case]
    model = write_model_with_metadata(tmp_path / "model.pt", DEFAULT_MODEL, drop=drop, **changes)
    code, err = replay(capsys, "evaluate", ZIGZAG, "--model", model, "--output", tmp_path / "eval")
    assert_one_line(code, err, "evaluate", allowed=(2,))
    assert expected in err and str(model) in err, err
    assert not (tmp_path / "eval").exists()


def _device_copy(path: Path) -> Path:
    """A copy of /dev/null (a character device, made with mknod: root only, skipped otherwise)."""
    try:
        os.mknod(path, 0o666 | __import__("stat").S_IFCHR, os.stat("/dev/null").st_rdev)
    except PermissionError:
        pytest.skip("mknod needs root")
    return path


SPECIAL_OUTPUTS: dict[str, Callable[[Path], Path]] = {
    "a_copy_of_dev_null": _device_copy,
    "a_link_to_stdout": lambda p: (os.symlink("/dev/stdout", p), p)[1],
    "a_fifo": lambda p: (os.mkfifo(p), p)[1],
    "a_link_to_a_file": lambda p: (p.with_name("target.json").write_text("{}"), os.symlink("target.json", p), p)[2],
}


@pytest.mark.parametrize("case", sorted(SPECIAL_OUTPUTS))
def test_an_output_that_is_a_special_file_is_refused_never_replaced(tmp_path, capsys, case) -> None:
    """Was: `--json /dev/null-copy` (or a link to stdout) replaced by a regular file. Now refused before any work,
    the special file left as it was; the same for a file written inside an output directory."""
    target = SPECIAL_OUTPUTS[case](tmp_path / "result.json")
    before = os.lstat(target)
    code, err = replay(capsys, "info", ZIGZAG, "--json", target)
    assert_one_line(code, err, "info", allowed=(2,))
    assert f"--json {target} is a" in err and "an output replaces only a regular file" in err, err
    after = os.lstat(target)
    assert (after.st_mode, after.st_ino, after.st_rdev) == (before.st_mode, before.st_ino, before.st_rdev)
    out = tmp_path / "eval"
    out.mkdir()
    inner = SPECIAL_OUTPUTS[case](out / "evaluation.json")  # what evaluate writes into its output directory
    code, err = replay(capsys, "evaluate", ZIGZAG, "--output", out)
    assert_one_line(code, err, "evaluate", allowed=(2,))
    assert f"{inner} is a" in err and "replaces only a regular file" in err
    assert os.lstat(inner).st_mode == before.st_mode
    assert leftovers(tmp_path) == []


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_a_hash_in_an_output_path_writes_where_it_says(tmp_path, capsys, storage) -> None:
    """Was: sqlite read `out#1/...` as the URI `out` with a fragment: its database landed in a file `out` beside the
    folder, and the bag had none. Now the bag is where the path says, readable; nothing is written beside it."""
    out = tmp_path / "out#1?x%41"
    code, err = replay(capsys, "simulate", "--manoeuvre", "zigzag", "--duration", "5", "--storage", storage,
                       "--no-compress", "--output", out)
    assert_one_line(code, err, "simulate", allowed=(0,))
    assert sorted(p.name for p in tmp_path.iterdir()) == [out.name]
    bag = next(out.iterdir())
    code, err = replay(capsys, "info", bag, "--json", tmp_path / "info.json")
    assert_one_line(code, err, "info", allowed=(0,))
    assert json.loads((tmp_path / "info.json").read_text())["bags"][0]["message_count"] > 900  # 5 s of every topic


def test_a_bag_left_half_written_is_never_read_as_a_bag(plain_bag, tmp_path, capsys) -> None:
    """What a run killed with SIGKILL while installing a bag leaves: the writer's hidden work directory, a complete
    bag inside. A search of the output folder does not read it (it is hidden), so no half-made run is trained on."""
    out = tmp_path / "bags"
    shutil.copytree(plain_bag, out / plain_bag.name)
    shutil.copytree(plain_bag, out / f".{plain_bag.name}.k2j4x.partial" / plain_bag.name)
    from usv_predictor.replay.recordings import find_bags

    assert [b.path for b in find_bags([out])] == [out / plain_bag.name]


@pytest.mark.slow
def test_simulate_killed_leaves_no_bag(tmp_path) -> None:
    """SIGKILL at any moment of `simulate`: what is left is either a whole bag or a hidden work directory that no
    search reads (every bag is written under a hidden temporary name and renamed when complete)."""
    out = tmp_path / "bags"
    argv = [sys.executable, "-m", "usv_predictor.replay", "simulate", "--programme", "training", "--duration", "30",
            "--no-compress", "--output", str(out)]
    proc = subprocess.Popen(argv, stderr=subprocess.PIPE, text=True, cwd=tmp_path)
    for line in proc.stderr:  # the first bag is complete: kill during the second
        if line.startswith("[1/"):
            break
    proc.kill()
    proc.wait(timeout=30)
    from usv_predictor.replay.recordings import find_bags

    for bag in find_bags([out]) if out.exists() else []:
        code = cli.main(["info", str(bag.path)])
        assert code == 0, bag.path  # every bag a search finds is whole


def test_train_on_a_dataset_holding_an_object_array(one_bag_dataset, tmp_path, capsys) -> None:
    """Once seen to leave a file: an object array (pickled, never loaded) is one line, exit 2, nothing written."""
    with np.load(one_bag_dataset, allow_pickle=False) as npz:
        arrays = {name: npz[name] for name in npz.files}
    arrays["X"] = np.array([object(), 1], dtype=object)
    spoiled = tmp_path / "object.npz"
    np.savez(spoiled, **arrays)
    out = tmp_path / "out"
    code, err = replay(capsys, "train", spoiled, "--epochs", "1", "--output", out / "model.pt")
    assert_one_line(code, err, "train", allowed=(2,))
    assert "Object arrays cannot be loaded" in err and not out.exists() and leftovers(tmp_path) == []


def test_two_runs_onto_one_output_at_once(tmp_path, capsys) -> None:
    """Was: two `evaluate` into one folder at once left files of both. Now the second is refused before any work
    while the first holds the output; the first ends normally."""
    out = tmp_path / "eval"
    first = subprocess.Popen([sys.executable, "-m", "usv_predictor.replay", "evaluate", str(ZIGZAG), "--output",
                              str(out)], stderr=subprocess.PIPE, text=True, cwd=tmp_path)
    try:
        for line in first.stderr:  # it holds the output's lock from before it reads
            if "reading" in line:
                break
        code, err = replay(capsys, "evaluate", ZIGZAG, "--output", out)
        assert_one_line(code, err, "evaluate", allowed=(2,))
        assert f"--output {out} is being written by another run" in err
        first.stderr.read()
        assert first.wait(timeout=300) == 0
    finally:
        if first.poll() is None:
            first.kill()
    assert (out / "evaluation.json").is_file() and leftovers(tmp_path) == []
    code, err = replay(capsys, "evaluate", ZIGZAG, "--output", out, "--json", tmp_path / "again.json")
    assert_one_line(code, err, "evaluate", allowed=(0,))  # the lock went with the first process
