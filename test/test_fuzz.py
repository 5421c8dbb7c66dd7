"""Bad input, generated: every replay command against broken bags, numbers that are not numbers, outputs on top of
inputs, foreign and failing model files, broken datasets and evaluation files, and interrupts.

Deterministic: every case draws from numpy's generator seeded with SEED and the case's name, so a failure
reproduces with `-k <case>`. Every run must end with exit 0 or 2 (130 when interrupted), never a traceback, an
error in one line naming the command, the inputs byte-identical (sha256 before and after) and no temporary file
of an atomic writer left anywhere. Commands run in this process (usv_predictor.replay.cli.main) except where a
signal or a file-size limit is the point; those cases, and the slower identify/diagnose runs, are marked slow.
Each test counts its runs (Checked.runs); README.md "What happens on bad input" and docs/bad_input.md quote the totals.
"""
from __future__ import annotations

import _thread
import json
import os
import resource
import shutil
import signal
import subprocess
import sys
import threading
import time
import zlib
from collections import Counter
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest
import torch
from replay_helpers import assert_one_line, bag_streams, digest, leftovers, replay, write_variant

from usv_predictor.models.artifact import export_like, load_artifact
from usv_predictor.physics.scenario import EFFECTS
from usv_predictor.records import Signal
from usv_predictor.replay import cli
from usv_predictor.replay.bagio import TopicSpec
from usv_predictor.replay.options import NUMBER_TYPES

SEED = 12
REPO = Path(__file__).resolve().parents[1]
SHIPPED_MODEL = REPO / "models" / "default.pt"
REQUIRED_ROLES = ("imu", "velocity", "heading", "rudder_angle", "engine_rpm")
USED_FIELDS = {"imu": ("yaw_rate",), "velocity": ("u", "v"), "heading": ("psi",), "rudder_angle": ("delta",),
               "engine_rpm": ("rpm",), "gnss": ("lat", "lon")}


TALLY: Counter[str] = Counter()  # runs by group and exit code (printed at the end of the module, with -s)


@pytest.fixture(scope="module", autouse=True)
def tally() -> Iterator[None]:
    yield
    total = sum(v for k, v in TALLY.items() if k.startswith("exit "))
    print(f"\nfuzz: {total} runs; " + ", ".join(f"{k} {v}" for k, v in sorted(TALLY.items())), file=sys.__stderr__)


def rng_for(name: str) -> np.random.Generator:
    """The case's own generator: the same draws whatever else runs."""
    return np.random.default_rng([SEED, zlib.crc32(name.encode())])


# ------------------------------------------------------------------ material: short bags, a dataset, an evaluation


@pytest.fixture(scope="module")
def base(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Two 60 s manoeuvres (zig-zag, port turn; uncompressed), a dataset, an evaluation and a model copy."""
    root = tmp_path_factory.mktemp("fuzz_base")
    bags = root / "bags"
    for manoeuvre in (["--manoeuvre", "zigzag"], ["--manoeuvre", "turning-circle", "--side", "port"]):
        assert cli.main(["simulate", *manoeuvre, "--duration", "60", "--no-compress", "--output", str(bags)]) == 0
    assert cli.main(["dataset", str(bags), "--output", str(root / "ds.npz"), "--jobs", "1"]) == 0
    assert cli.main(["evaluate", str(bags), "--output", str(root / "eval")]) == 0
    shutil.copy(SHIPPED_MODEL, root / "model.pt")
    return {"root": root, "bags": bags, "zigzag": bags / "zigzag_20_20_stbd_650rpm",
            "turn": bags / "turning_circle_port_20deg_650rpm", "dataset": root / "ds.npz",
            "evaluation": root / "eval" / "evaluation.json", "model": root / "model.pt"}


class Checked:
    """Runs commands on inputs and checks what every run must leave behind (module docstring)."""

    def __init__(self, capsys: pytest.CaptureFixture[str], inputs: list[Path], out: Path) -> None:
        self.capsys, self.inputs, self.out = capsys, inputs, out
        self.before = digest(inputs)
        self.runs = 0

    def __call__(self, command: str, *args: object, allowed: tuple[int, ...] = (0, 2)) -> tuple[int, str]:
        code, err = replay(self.capsys, command, *args)
        self.runs += 1
        TALLY[f"exit {code}"] += 1
        TALLY[f"group {os.environ.get('PYTEST_CURRENT_TEST', '').split('::')[-1].split('[')[0].split(' ')[0]}"] += 1
        assert_one_line(code, err, command, allowed)
        return code, err

    def finish(self) -> None:
        assert digest(self.inputs) == self.before, "an input changed"
        assert leftovers(self.out) == []
        assert all(leftovers(p) == [] for p in self.inputs if p.is_dir())


@pytest.fixture()
def checked(capsys: pytest.CaptureFixture[str], base: dict[str, Path], tmp_path: Path) -> Iterator[Callable]:
    made: list[Checked] = []

    def make(*inputs: Path) -> Checked:
        made.append(Checked(capsys, [*inputs, base["bags"], base["dataset"], base["evaluation"].parent,
                                     base["model"]], tmp_path))
        return made[-1]

    yield make
    for c in made:
        c.finish()


# ------------------------------------------------------------------ broken bags


def _copy(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    return dst


def _db3(bag: Path) -> Path:
    return next(bag.glob("*.db3"))


def _rewrite(src: Path, dst: Path, change: Callable[[list[tuple[TopicSpec, Signal]]], list]) -> Path:
    streams, custom = bag_streams(src)
    return write_variant(dst, change(streams), custom)


def _edit_role(role: str, edit: Callable[[Signal], Signal]) -> Callable[[list], list]:
    return lambda streams: [(spec, edit(sig) if spec.role == role else sig) for spec, sig in streams]


def _with_values(sig: Signal, rows: np.ndarray, field: str, value: float) -> Signal:
    values = sig.values.copy()
    values[rows, sig.fields.index(field)] = value
    return Signal(sig.t_ns, values, sig.fields)


def _rows(rng: np.random.Generator, n: int, share: float) -> np.ndarray:
    return rng.choice(n, size=max(1, int(share * n)), replace=False)


def _mutations() -> dict[str, Callable[[np.random.Generator, Path, Path], Path]]:
    def role(rng: np.random.Generator, roles: tuple[str, ...] = REQUIRED_ROLES) -> str:
        return str(rng.choice(roles))

    def nan_field(value: float, share: float) -> Callable:
        def make(rng: np.random.Generator, src: Path, dst: Path) -> Path:
            r = role(rng, tuple(USED_FIELDS))
            f = str(rng.choice(USED_FIELDS[r]))
            return _rewrite(src, dst, _edit_role(r, lambda s: _with_values(s, _rows(rng, len(s), share), f, value)))
        return make

    def truncate(share: float) -> Callable:
        def make(rng: np.random.Generator, src: Path, dst: Path) -> Path:
            bag = _copy(src, dst)
            data = _db3(bag).read_bytes()
            _db3(bag).write_bytes(data[: int(len(data) * share * rng.uniform(0.5, 1.0))])
            return bag
        return make

    def garbage_db3(rng: np.random.Generator, src: Path, dst: Path) -> Path:
        bag = _copy(src, dst)
        data = bytearray(_db3(bag).read_bytes())
        for at in rng.integers(0, len(data), size=64):
            data[int(at)] = int(rng.integers(0, 256))
        _db3(bag).write_bytes(bytes(data))
        return bag

    def metadata(change: Callable[[np.random.Generator, bytes], bytes | None]) -> Callable:
        def make(rng: np.random.Generator, src: Path, dst: Path) -> Path:
            bag = _copy(src, dst)
            new = change(rng, (bag / "metadata.yaml").read_bytes())
            if new is None:
                (bag / "metadata.yaml").unlink()
            else:
                (bag / "metadata.yaml").write_bytes(new)
            return bag
        return make

    def corrupt_yaml(rng: np.random.Generator, text: bytes) -> bytes:
        data = bytearray(text)
        for at in rng.integers(0, len(data), size=12):
            data[int(at)] = ord(str(rng.choice(list(":[{}]&*!|>'\""))))
        return bytes(data)

    def drop_role(rng: np.random.Generator, src: Path, dst: Path) -> Path:
        r = role(rng)
        return _rewrite(src, dst, lambda streams: [(s, x) for s, x in streams if s.role != r])

    def empty_role(rng: np.random.Generator, src: Path, dst: Path) -> Path:
        return _rewrite(src, dst, _edit_role(role(rng), lambda s: Signal(s.t_ns[:0], s.values[:0], s.fields)))

    def one_sample(rng: np.random.Generator, src: Path, dst: Path) -> Path:
        return _rewrite(src, dst, _edit_role(role(rng), lambda s: Signal(s.t_ns[:1], s.values[:1], s.fields)))

    def wrong_type(rng: np.random.Generator, src: Path, dst: Path) -> Path:
        def change(streams: list) -> list:
            return [(TopicSpec(s.topic, s.role, "geometry_msgs/msg/QuaternionStamped") if s.role == "heading" else s,
                     x) for s, x in streams]
        return _rewrite(src, dst, change)

    def shuffled_stamps(rng: np.random.Generator, src: Path, dst: Path) -> Path:
        def edit(s: Signal) -> Signal:
            t = s.t_ns.copy()
            a = int(rng.integers(0, len(t) - 50))
            t[a:a + 50] = t[a:a + 50][::-1]  # a block of header stamps backwards
            return Signal(t, s.values, s.fields)
        return _rewrite(src, dst, _edit_role(str(rng.choice(("imu", "velocity", "gnss"))), edit))

    def duplicated_stamps(rng: np.random.Generator, src: Path, dst: Path) -> Path:
        def edit(s: Signal) -> Signal:
            k = np.sort(_rows(rng, len(s), 0.1))
            values = np.concatenate([s.values, s.values[k] + rng.normal(0, 1, (len(k), s.values.shape[1]))])
            t = np.concatenate([s.t_ns, s.t_ns[k]])
            order = np.argsort(t, kind="stable")
            return Signal(t[order], values[order], s.fields)
        return _rewrite(src, dst, _edit_role(role(rng), edit))

    def gap(everywhere: bool) -> Callable:
        def make(rng: np.random.Generator, src: Path, dst: Path) -> Path:
            chosen = role(rng)
            start = float(rng.uniform(5.0, 35.0))

            def edit(s: Signal) -> Signal:
                t = (s.t_ns - s.t_ns[0]) / 1e9
                keep = (t < start) | (t > start + 20.0)
                return Signal(s.t_ns[keep], s.values[keep], s.fields)
            return _rewrite(src, dst, lambda streams: [(spec, edit(x) if everywhere or spec.role == chosen else x)
                                                        for spec, x in streams])
        return make

    def shifted(rng: np.random.Generator, src: Path, dst: Path) -> Path:
        offset = int(rng.choice([-1, 1]) * 10**15)  # 11.6 days away: no overlap with the other topics
        return _rewrite(src, dst, _edit_role(role(rng), lambda s: Signal(s.t_ns + offset, s.values, s.fields)))

    def scaled(rng: np.random.Generator, src: Path, dst: Path) -> Path:
        r = role(rng)
        factor = float(rng.choice([57.2958, -1.0, 100.0, 3.6]))  # deg read as rad, a sign, rpm x 100, km/h
        return _rewrite(src, dst, _edit_role(r, lambda s: Signal(s.t_ns, s.values * factor, s.fields)))

    def short(rng: np.random.Generator, src: Path, dst: Path) -> Path:
        seconds = float(rng.uniform(0.5, 3.0))
        return _rewrite(src, dst, lambda streams: [(s, Signal(x.t_ns[(x.t_ns - x.t_ns[0]) < seconds * 1e9],
                                                               x.values[(x.t_ns - x.t_ns[0]) < seconds * 1e9],
                                                               x.fields)) for s, x in streams])

    return {
        "zero_byte_db3": truncate(0.0), "truncated_db3": truncate(0.9), "garbage_db3": garbage_db3,
        "metadata_not_utf8": metadata(lambda rng, t: t + b"\n# \xff\xfe\x80\n"),
        "metadata_corrupt": metadata(corrupt_yaml), "metadata_empty": metadata(lambda rng, t: b""),
        "metadata_not_a_mapping": metadata(lambda rng, t: b"- just\n- a list\n"),
        "metadata_missing": metadata(lambda rng, t: None),
        "missing_topic": drop_role, "empty_topic": empty_role, "one_sample_topic": one_sample,
        "wrong_type": wrong_type, "nan_samples": nan_field(np.nan, 0.01), "inf_samples": nan_field(np.inf, 0.01),
        "minus_inf_samples": nan_field(-np.inf, 0.3), "all_nan_topic": nan_field(np.nan, 1.0),
        "huge_values": nan_field(1e30, 0.01), "max_float_values": nan_field(-1.7e308, 0.05),
        "backwards_stamps": shuffled_stamps, "duplicate_stamps": duplicated_stamps, "gap_in_one_topic": gap(False),
        "gap_everywhere": gap(True), "topic_days_away": shifted, "wrong_units_or_sign": scaled, "two_seconds": short,
    }


MUTATIONS = _mutations()
DEEP = ("nan_samples", "huge_values", "backwards_stamps", "gap_in_one_topic", "wrong_units_or_sign", "truncated_db3")


@pytest.mark.parametrize("mutation", sorted(MUTATIONS))
def test_broken_bags(mutation: str, base: dict[str, Path], tmp_path: Path, checked: Callable) -> None:
    """info, dataset and evaluate on a broken copy of a bag (the original is an input too: never touched)."""
    rng = rng_for(mutation)
    bag = MUTATIONS[mutation](rng, base[str(rng.choice(["zigzag", "turn"]))], tmp_path / "in" / "broken")
    run = checked(bag)
    out = tmp_path / "out"
    run("info", bag)
    run("dataset", bag, "--output", out / "ds.npz", "--jobs", "1", "--json", out / "ds.json")
    run("evaluate", bag, "--output", out / "eval", "--json", out / "eval.json")


@pytest.mark.slow
@pytest.mark.parametrize("mutation", DEEP)
def test_broken_bags_deeper(mutation: str, base: dict[str, Path], tmp_path: Path, checked: Callable) -> None:
    """identify and diagnose (both need two manoeuvres: the broken one and a good one)."""
    rng = rng_for(mutation)
    bag = MUTATIONS[mutation](rng, base["zigzag"], tmp_path / "in" / "broken")
    run = checked(bag)
    out = tmp_path / "out"
    run("identify", bag, base["turn"], "--vessel", "jari_usv", "--prior", "fix", "--output", out / "id.pt",
        "--json", out / "id.json")
    run("diagnose", bag, base["turn"], "--hypotheses", "current", "actuator_delay", "--no-gain",
        "--json", out / "d.json")


# ------------------------------------------------------------------ broken measured data for `replay convert`


def _source_mutations() -> dict[str, Callable[[np.random.Generator, bytes], bytes]]:
    def garbage(rng: np.random.Generator, data: bytes) -> bytes:
        out = bytearray(data)
        for at in rng.integers(0, len(out), size=200):
            out[int(at)] = int(rng.integers(0, 256))
        return bytes(out)

    def replace_numbers(text: bytes, rng: np.random.Generator, by: bytes) -> bytes:
        lines = text.split(b"\n")
        for k in rng.integers(len(lines) // 4, len(lines) - 1, size=5):
            separator = b"," if b"," in lines[int(k)] else None  # CSV, or columns separated by blanks
            words = lines[int(k)].split(separator)
            if words:
                words[int(rng.integers(0, len(words)))] = by
                lines[int(k)] = (separator or b" ").join(words)
        return b"\n".join(lines)

    return {
        "empty": lambda rng, d: b"",
        "truncated": lambda rng, d: d[: int(len(d) * rng.uniform(0.01, 0.6))],
        "garbage_bytes": garbage,
        "nan_values": lambda rng, d: replace_numbers(d, rng, b"nan"),
        "inf_values": lambda rng, d: replace_numbers(d, rng, b"-inf"),
        "text_values": lambda rng, d: replace_numbers(d, rng, b"x"),
        "short_rows": lambda rng, d: b"\n".join(line[: len(line) // 2] if k % 7 == 3 else line
                                                for k, line in enumerate(d.split(b"\n"))),
        "header_only": lambda rng, d: b"\n".join(d.split(b"\n")[:5]),
    }


SOURCE_MUTATIONS = _source_mutations()
SOURCES = ("kvlcc2_hsva_simman2008/HSVA_CPMC_KVLCC2_Z_10_10_S.dat",
           "usv_alexandersson2022_fuzhou/zigzag_30_inter_xy.csv")


@pytest.mark.parametrize("mutation", sorted(SOURCE_MUTATIONS))
def test_broken_measured_data(mutation: str, raw_data_dir: Path, tmp_path: Path, checked: Callable) -> None:
    """`replay convert` on a broken copy of an HSVA model-test file and of the Fuzhou sea-trial file."""
    rng = rng_for(f"convert {mutation}")
    sources = []
    for name in SOURCES:
        target = tmp_path / "in" / Path(name).name
        target.parent.mkdir(exist_ok=True)
        target.write_bytes(SOURCE_MUTATIONS[mutation](rng, (raw_data_dir / name).read_bytes()))
        sources.append(target)
    run = checked(*sources)
    for k, source in enumerate(sources):
        run("convert", source, "--output", tmp_path / "out" / str(k), "--json", tmp_path / "out" / f"{k}.json")


# ------------------------------------------------------------------ numbers that are not numbers


VALUES = ("nan", "inf", "-inf", "-1", "0", "1e308", "1e-320", "abc", "")


def _numeric_options() -> list[tuple[str, str]]:
    parser = cli.build_parser([])
    subparsers = next(a for a in parser._actions if isinstance(a.choices, dict))
    return [(name, action.option_strings[0]) for name, sub in subparsers.choices.items() for action in sub._actions
            if action.type in NUMBER_TYPES]


def _base_argv(command: str, base: dict[str, Path], out: Path, option: str) -> list[object]:
    effect = next((name for name, params in EFFECTS.items() for p in params if p.flag == option), None)
    return {
        "simulate": ["--manoeuvre", "zigzag", "--duration", "5", "--output", out / "sim",
                     *(["--effect", effect] if effect else [])],
        "dataset": [base["bags"], "--output", out / "ds.npz", "--jobs", "1"],
        "train": [base["dataset"], "--output", out / "m.pt", "--epochs", "2"],
        "evaluate": [base["zigzag"], "--model", base["model"]],
        "report": [base["evaluation"], "--output", out / "report"],
        "identify": [base["bags"], "--vessel", "jari_usv", "--prior", "fix", "--output", out / "id.pt"],
        "diagnose": [base["bags"], "--hypotheses", "current", "--no-gain"],
        "vessel": ["init", "--name", "fuzz", "--layout", "twin_thrusters", "--lpp", "2", "--beam", "1",
                   "--mass", "80", "--draught", "0.2", "--thrust", "1:100", "--output", out / "v.yaml"],
    }[command]


@pytest.mark.parametrize(("command", "option"), _numeric_options())
def test_numbers_that_are_not_numbers(command: str, option: str, base: dict[str, Path], tmp_path: Path,
                                      checked: Callable) -> None:
    """Every numeric option of every command against nan, inf, negative, zero, huge, subnormal and non-numbers."""
    run = checked()
    for value in VALUES:
        out = tmp_path / f"out_{VALUES.index(value)}"
        code, err = run(command, *_base_argv(command, base, out, option), option, value)
        if value in ("nan", "inf", "-inf", "abc", ""):
            assert code == 2, err
            assert f"argument {option}" in err, err


# ------------------------------------------------------------------ outputs on top of inputs, or nowhere to go


OUTPUT_CASES = {  # command -> (its output option, "file" or "dir", its other arguments)
    "dataset": ("--output", "file", lambda b: [b["bags"], "--jobs", "1"]),
    "train": ("--output", "file", lambda b: [b["dataset"], "--epochs", "1"]),
    "evaluate": ("--output", "dir", lambda b: [b["zigzag"]]),
    "report": ("--output", "dir", lambda b: [b["evaluation"]]),
    "identify": ("--output", "file", lambda b: [b["bags"], "--vessel", "jari_usv", "--prior", "fix"]),
    "diagnose": ("--export", "file", lambda b: [b["bags"], "--hypotheses", "current", "--no-gain"]),
    "simulate": ("--output", "dir", lambda b: ["--manoeuvre", "zigzag", "--duration", "5"]),
    "info": ("--json", "file", lambda b: [b["zigzag"]]),
    "convert": ("--output", "dir", lambda b: [REPO / "bags" / "README.md"]),  # not measured data: refused anyway
}


def _targets(inputs: list[Path], kind: str, base: dict[str, Path], tmp_path: Path) -> dict[str, tuple[Path, str]]:
    """name -> (an output path, words the refusal must hold: alternatives split by |), from the command's inputs."""
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    (tmp_path / "a_directory").mkdir(exist_ok=True)
    targets = {"below_a_file": (blocker / "out", "is not a directory"),
               "inside_a_bag_not_read": (base["turn"] / "out", "inside the rosbag2 bag|inside the input"),
               "a_bag_not_read": (base["turn"], "is the rosbag2 bag|inside the input")}
    if kind == "file":
        targets["an_existing_directory"] = (tmp_path / "a_directory", "is a directory")
    special = tmp_path / "special"
    special.mkdir(exist_ok=True)
    if not (special / "a_link_to_dev_null").is_symlink():
        os.symlink("/dev/null", special / "a_link_to_dev_null")
        os.mkfifo(special / "a_fifo")
    targets["a_link_to_dev_null"] = (special / "a_link_to_dev_null", "is a symbolic link to /dev/null")  # never
    targets["a_fifo"] = (special / "a_fifo", "is a FIFO")                                      # replaced
    for k, source in enumerate(inputs):
        targets[f"input_{k}"] = (source, "is the input")
        targets[f"inside_input_{k}"] = (source / "metadata.yaml" if source.is_dir() else source / "x",
                                        "inside the input" if source.is_dir() else "is not a directory")
    return targets


@pytest.mark.parametrize("command", sorted(OUTPUT_CASES))
def test_outputs_on_top_of_inputs(command: str, base: dict[str, Path], tmp_path: Path, checked: Callable) -> None:
    """The command's output, then its --json, on its inputs, inside them, inside any bag, below a file, on a
    directory where a file belongs, on a special file (a link to /dev/null, a FIFO): refused before any work
    (exit 2, the reason); the inputs never change."""
    option, kind, args = OUTPUT_CASES[command]
    inputs = [a for a in args(base) if isinstance(a, Path)]
    run = checked()
    for flag in dict.fromkeys((option, "--json")):
        for name, (target, words) in _targets(inputs, kind if flag == option else "file", base, tmp_path).items():
            other = [option, tmp_path / f"elsewhere_{name}"] if flag != option else []
            code, err = run(command, *args(base), *other, flag, target)
            assert code == 2, f"{name} {flag}: {err}"
            assert any(w in err for w in words.split("|")), f"{name} {flag}: {err}"
            assert "reading" not in err and "wrote" not in err  # before any work


# ------------------------------------------------------------------ foreign and failing model files


def _models(tmp_path: Path) -> dict[str, Path]:
    shipped = load_artifact(SHIPPED_MODEL)  # its metadata and vessel description on modules of other code

    class Raises(torch.nn.Module):
        def forward(self, state: torch.Tensor, controls: torch.Tensor) -> torch.Tensor:
            if bool(state.sum() > -1e30):
                raise ValueError("the model's own bug")
            return state

    class WrongShape(torch.nn.Module):
        def forward(self, state: torch.Tensor, controls: torch.Tensor) -> torch.Tensor:
            return torch.zeros(2, 3)

    class NotFinite(torch.nn.Module):
        def forward(self, state: torch.Tensor, controls: torch.Tensor) -> torch.Tensor:
            return torch.full((1, state.shape[0], controls.shape[1], 6), float("nan"), dtype=torch.float64)

    class RaisesLater(torch.nn.Module):  # fine from rest, fails on real states
        def forward(self, state: torch.Tensor, controls: torch.Tensor) -> torch.Tensor:
            if bool(state[:, 0].max() > 2.0):
                raise RuntimeError("fails on a real state")
            return torch.zeros(1, state.shape[0], controls.shape[1], 6, dtype=torch.float64)

    tmp_path.mkdir(parents=True, exist_ok=True)
    out = {name: tmp_path / f"{name}.pt" for name in ("empty", "text", "zip", "plain_torchscript", "truncated")}
    out["empty"].write_bytes(b"")
    out["text"].write_text("not a model\n")
    shutil.make_archive(str(tmp_path / "zip"), "zip", REPO / "config")
    (tmp_path / "zip.zip").rename(out["zip"])
    torch.jit.save(torch.jit.script(WrongShape()), str(out["plain_torchscript"]))
    out["truncated"].write_bytes(SHIPPED_MODEL.read_bytes()[:20000])
    for name, module in (("raises", Raises()), ("wrong_shape", WrongShape()), ("not_finite", NotFinite()),
                         ("raises_later", RaisesLater())):
        out[name] = tmp_path / f"{name}.pt"
        export_like(out[name], module, shipped)
    out["other_dt"] = tmp_path / "other_dt.pt"
    export_like(out["other_dt"], RaisesLater(), shipped, dt=0.25)
    out["directory"] = tmp_path / "a_directory.pt"
    out["directory"].mkdir()
    return out


def test_foreign_and_failing_models(base: dict[str, Path], tmp_path: Path, checked: Callable) -> None:
    models = _models(tmp_path / "models")
    run = checked(tmp_path / "models")
    for name, model in models.items():
        code, err = run("evaluate", base["zigzag"], "--model", model)
        assert code == 2, f"{name}: {err}"
        if name in ("raises", "wrong_shape", "not_finite", "raises_later"):
            assert f"model {model} fails when run: " in err, err
        code, err = run("diagnose", base["bags"], "--model", model, "--hypotheses", "current", "--no-gain")
        assert code == 2, f"{name}: {err}"
    code, err = run("diagnose", base["bags"], "--model", base["model"], "--hypotheses", "current", "--no-gain")
    assert code == 2
    assert "diagnose needs a grey box" in err


# ------------------------------------------------------------------ broken datasets and evaluation files


def _datasets(base: dict[str, Path], tmp_path: Path) -> dict[str, Path]:
    rng = rng_for("datasets")
    tmp_path.mkdir(parents=True, exist_ok=True)
    with np.load(base["dataset"]) as npz:
        arrays = {k: npz[k] for k in npz.files}
    out: dict[str, Path] = {}

    def save(name: str, **changes: np.ndarray | None) -> None:
        data = {k: v for k, v in {**arrays, **changes}.items() if v is not None}
        out[name] = tmp_path / f"{name}.npz"
        np.savez_compressed(out[name], **data)

    for array in ("X", "Y", "seq_nu", "seq_controls", "seq_t_s"):
        for value in (np.nan, np.inf):
            changed = arrays[array].astype(float).copy()
            changed.reshape(-1)[int(rng.integers(0, changed.size))] = value
            save(f"{array}_{value}", **{array: changed})
    save("missing_array", Y=None)
    save("wrong_shape", X=arrays["X"][:, :2])
    save("metadata_not_json", metadata=np.array("{not json"))
    save("metadata_other_format", metadata=np.array(json.dumps({"format": "something/else"})))
    save("no_samples", X=arrays["X"][:0], Y=arrays["Y"][:0], sample_recording=arrays["sample_recording"][:0],
         sample_step=arrays["sample_step"][:0])
    data = base["dataset"].read_bytes()
    for name, content in (("truncated", data[: len(data) // 2]), ("empty", b""), ("text", b"hello")):
        out[name] = tmp_path / f"{name}.npz"
        out[name].write_bytes(content)
    return out


def test_broken_datasets(base: dict[str, Path], tmp_path: Path, checked: Callable) -> None:
    files = _datasets(base, tmp_path / "datasets")
    run = checked(tmp_path / "datasets")
    for name, path in files.items():
        code, err = run("train", path, "--output", tmp_path / "out" / f"{name}.pt", "--epochs", "2")
        assert code == 2, f"{name}: {err}"
        assert not (tmp_path / "out" / f"{name}.pt").exists()


def _json_nodes(value: object, path: tuple = ()) -> Iterator[tuple]:
    yield path
    if isinstance(value, dict):
        for key, item in value.items():
            yield from _json_nodes(item, (*path, key))
    elif isinstance(value, list):
        for k, item in enumerate(value):
            yield from _json_nodes(item, (*path, k))


EVALUATION_EDITS = 16  # nodes of the evaluation JSON replaced, drawn with the seed


def test_broken_evaluation_files(base: dict[str, Path], tmp_path: Path, checked: Callable) -> None:
    """Any node of an evaluation.json replaced by null, a string, a number, a list, an object, NaN or 1e999."""
    rng = rng_for("evaluation files")
    original = json.loads(base["evaluation"].read_text())
    nodes = [p for p in _json_nodes(original) if p]
    replacements = [None, "text", -1, [], {}, "NaN", "1e999"]
    folder = tmp_path / "evaluations"
    folder.mkdir()
    shutil.copy(base["evaluation"].parent / original["series_file"], folder / original["series_file"])
    edits = []
    for k in range(EVALUATION_EDITS):
        path = nodes[int(rng.integers(0, len(nodes)))]
        replacement = replacements[int(rng.integers(0, len(replacements)))]
        data = json.loads(json.dumps(original))
        target = data
        for key in path[:-1]:
            target = target[key]
        target[path[-1]] = "@@" if replacement in ("NaN", "1e999") else replacement
        text = json.dumps(data).replace('"@@"', str(replacement))
        edits.append(folder / f"evaluation_{k}.json")
        edits[-1].write_text(text)
    run = checked(folder)
    for k, edited in enumerate(edits):
        run("report", edited, "--output", tmp_path / "out" / f"report_{k}")


# ------------------------------------------------------------------ interrupted in the middle (in this process)


def _interrupted(argv: list[object], delay: float) -> int | str:
    """cli.main with a KeyboardInterrupt raised in it after `delay` s (what Ctrl-C does); 'finished' when it came
    too late (the command was done)."""
    lock, state = threading.Lock(), {"done": False}

    def fire() -> None:
        with lock:
            if not state["done"]:
                _thread.interrupt_main()

    timer = threading.Timer(delay, fire)
    try:
        timer.start()
        try:
            code = cli.main([str(a) for a in argv])
        finally:
            with lock:
                state["done"] = True
            timer.cancel()
        time.sleep(0.01)  # an interrupt already on its way lands here
        return code
    except KeyboardInterrupt:
        return "finished"


INTERRUPTS = {
    "dataset": lambda b, o: ["dataset", b["bags"], "--output", o / "ds.npz", "--jobs", "1"],
    "train": lambda b, o: ["train", b["dataset"], "--output", o / "m.pt", "--epochs", "300", "--patience", "0"],
    "evaluate": lambda b, o: ["evaluate", b["bags"], "--output", o / "eval"],
    "report": lambda b, o: ["report", b["evaluation"], "--output", o / "report"],
    "identify": lambda b, o: ["identify", b["bags"], "--vessel", "jari_usv", "--prior", "fix", "--output", o / "i.pt",
                              "--report", o / "id"],
    "simulate": lambda b, o: ["simulate", "--programme", "training", "--output", o / "sim"],
}


@pytest.fixture(scope="module")
def first_imports_done() -> None:
    """The modules `report` and `train` import on first use (matplotlib's figure, the sympy that torch's first
    optimiser step loads) imported before any interrupt. An interrupt inside a first import leaves the module half
    initialised in sys.modules; a real process then exits, but these runs share one process, and the next run would
    meet the half module. What is tested is the commands' handling of Ctrl-C, not Python's import machinery."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg  # noqa: F401
    from matplotlib.figure import Figure  # noqa: F401

    weight = torch.zeros(2, requires_grad=True)
    optimiser = torch.optim.Adam([weight])
    (weight ** 2).sum().backward()
    optimiser.step()


@pytest.mark.parametrize("command", sorted(INTERRUPTS))
@pytest.mark.usefixtures("first_imports_done")
def test_interrupted_in_the_middle(command: str, base: dict[str, Path], tmp_path: Path, checked: Callable,
                                   capsys: pytest.CaptureFixture[str]) -> None:
    rng = rng_for(f"interrupt {command}")
    run = checked()
    for k, delay in enumerate(rng.uniform(0.05, 1.5, size=3)):
        out = tmp_path / f"out_{k}"
        code = _interrupted(INTERRUPTS[command](base, out), float(delay))
        err = capsys.readouterr().err
        run.runs += 1
        TALLY[f"exit {code}"] += 1
        TALLY["group test_interrupted_in_the_middle"] += 1
        assert code in (0, cli.EXIT_INTERRUPTED, "finished"), err[-3000:]
        assert "Traceback" not in err
        if code == cli.EXIT_INTERRUPTED:
            assert err.strip().splitlines()[-1] == f"replay {command}: interrupted"
        assert leftovers(tmp_path) == []


# ------------------------------------------------------------------ a few real processes: signals, file-size limit


@pytest.mark.slow
@pytest.mark.parametrize("command", ["dataset", "train"])
def test_sigint_to_the_process_group(command: str, base: dict[str, Path], tmp_path: Path) -> None:
    """Ctrl-C in a terminal signals the whole process group (dataset's worker processes too)."""
    argv = {"dataset": ["dataset", str(REPO / "bags" / "sea_trial"), str(REPO / "bags" / "training"), "--include-calm",
                        "--jobs", "2", "--output",
                        str(tmp_path / "ds.npz")],
            "train": ["train", str(base["dataset"]), "--output", str(tmp_path / "m.pt"), "--epochs", "100000",
                      "--patience", "0"]}[command]
    delay = float(rng_for(f"sigint {command}").uniform(3.0, 4.5))  # torch's import alone takes ~2 s here
    process = subprocess.Popen([sys.executable, "-m", "usv_predictor.replay", *argv], start_new_session=True,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               env={**os.environ, "PYTHONPATH": str(REPO)})
    time.sleep(delay)
    os.killpg(process.pid, signal.SIGINT)
    _, err = process.communicate(timeout=120)
    TALLY[f"exit {process.returncode}"] += 1
    TALLY["group test_sigint_to_the_process_group"] += 1
    assert process.returncode in (0, cli.EXIT_INTERRUPTED), err[-3000:]
    assert "Traceback" not in err
    assert leftovers(tmp_path) == []


@pytest.mark.slow
@pytest.mark.parametrize("command", ["evaluate", "report", "dataset"])
def test_file_size_limit(command: str, base: dict[str, Path], tmp_path: Path) -> None:
    """ulimit -f: whichever file hits it, one line "cannot write ...: no space left", nothing half-written."""
    limit = int(rng_for(f"ulimit {command}").integers(2_000, 60_000))
    argv = {"evaluate": ["evaluate", str(base["bags"]), "--output", str(tmp_path / "eval")],
            "report": ["report", str(base["evaluation"]), "--output", str(tmp_path / "report")],
            "dataset": ["dataset", str(base["bags"]), "--jobs", "1", "--output", str(tmp_path / "ds.npz")]}[command]
    before = digest([base["bags"], base["evaluation"].parent])
    done = subprocess.run([sys.executable, "-m", "usv_predictor.replay", *argv], capture_output=True, text=True,
                          timeout=300, env={**os.environ, "PYTHONPATH": str(REPO)},
                          preexec_fn=lambda: resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit)))
    TALLY[f"exit {done.returncode}"] += 1
    TALLY["group test_file_size_limit"] += 1
    assert done.returncode == 2, done.stderr[-3000:]
    assert "Traceback" not in done.stderr
    assert "no space left" in done.stderr.strip().splitlines()[-1]
    assert leftovers(tmp_path) == []
    assert digest([base["bags"], base["evaluation"].parent]) == before


# ------------------------------------------------------------------ documents beyond bounds


def _documents() -> dict[str, Callable[[np.random.Generator, str], str | None]]:
    """name -> a YAML/JSON text (from the case's generator and the document's own text), or None where the file is
    made otherwise (_special_document). Each is past one bound of usv_predictor.bounded."""
    from usv_predictor.bounded import MAX_DEPTH

    def deep(rng: np.random.Generator, text: str) -> str:
        depth = int(rng.integers(MAX_DEPTH + 1, 200_000))
        opening, closing = ("[", "]") if rng.random() < 0.5 else ("{a: ", "}")
        return text.replace("\n", f"\ndeep_{depth}: {opening * depth}1{closing * depth}\n", 1)

    def alias_bomb(rng: np.random.Generator, text: str) -> str:
        width, levels = int(rng.integers(8, 20)), int(rng.integers(7, 12))
        lines = [f"b0: &b0 [{', '.join(['x'] * width)}]"]
        lines += [f"b{i}: &b{i} [{', '.join([f'*b{i - 1}'] * width)}]" for i in range(1, levels)]
        return "\n".join(lines) + "\n" + text

    def python_tag(rng: np.random.Generator, text: str) -> str:
        tag = str(rng.choice(["!!python/object/apply:os.system ['true']", "!!python/name:os.system",
                              "!!python/object/new:dict {}", "!!python/module:os"]))
        return f"tagged: {tag}\n" + text

    def cycle(rng: np.random.Generator, text: str) -> str:
        anchor = f"c{int(rng.integers(0, 1000))}"
        return f"cycle: &{anchor}\n  inner: [*{anchor}]\n" + text

    return {"deep": deep, "alias_bomb": alias_bomb, "python_tag": python_tag, "cycle": cycle,
            "fifo": lambda rng, text: None, "dev_zero": lambda rng, text: None, "link_loop": lambda rng, text: None,
            "sparse_200_MB": lambda rng, text: None}


DOCUMENTS = _documents()
DOCUMENT_WORDS = {"deep": "nested deeper than", "alias_bomb": "expands to more than", "python_tag": "for the tag",
                  "cycle": "refers to a node that holds it", "fifo": "FIFO", "dev_zero": "character device",
                  "link_loop": "loop of symbolic links", "sparse_200_MB": "more than the"}


def _special_document(case: str, path: Path) -> None:
    path.unlink(missing_ok=True)
    if case == "fifo":
        os.mkfifo(path)
    elif case == "dev_zero":
        os.symlink("/dev/zero", path)
    elif case == "link_loop":
        os.symlink(path.name, path)
    else:
        with path.open("wb") as out:
            out.truncate(200 << 20)  # sparse: no disk, refused by its size before a read


@pytest.mark.parametrize("reader", ["bag_metadata", "vessel_file", "predictor_config"])
@pytest.mark.parametrize("case", sorted(DOCUMENTS))
def test_documents_beyond_bounds(reader: str, case: str, base: dict[str, Path], tmp_path: Path,
                                 checked: Callable) -> None:
    """Every file read as YAML, past each bound (depth, alias expansion, tags, cycles, size, not a regular file): one
    line naming the file and the bound, exit 2, no hang and no traceback."""
    rng = rng_for(f"{reader} {case}")
    if reader == "bag_metadata":
        target_dir = _copy(base["zigzag"], tmp_path / "in" / "bag")
        target = target_dir / "metadata.yaml"
    else:
        target_dir = tmp_path / "in"
        target_dir.mkdir()
        target = target_dir / f"{reader}.yaml"
        shutil.copy(REPO / "config" / ("vessels/jari_usv.yaml" if reader == "vessel_file" else "predictor.yaml"),
                    target)
    text = DOCUMENTS[case](rng, "\n" + target.read_text())  # each goes in at the top level of the document
    if text is None:
        _special_document(case, target)
    else:
        target.write_text(text)
    run = checked()
    out = tmp_path / "out"
    if reader == "bag_metadata":
        code, err = run("info", target_dir, allowed=(2,))
    elif reader == "vessel_file":
        code, err = run("simulate", "--vessel", target, "--manoeuvre", "zigzag", "--duration", "5", "--output", out,
                        allowed=(2,))
    else:
        code, err = run("dataset", base["zigzag"], "--config", target, "--output", out / "ds.npz", allowed=(2,))
    assert DOCUMENT_WORDS[case] in err and str(target) in err, err
