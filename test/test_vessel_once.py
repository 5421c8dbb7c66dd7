"""The vessel is resolved once at each boundary (models/loading.resolve_vessel) and its file read once per command:
each command's library path is run on the shipped bags with the resolver and the vessel-file reader counted (the
work after the vessel and the recordings, a training or a fit, is stopped: it reads no vessel; a simulation is run
whole)."""
from __future__ import annotations

from collections import Counter
from pathlib import Path

import pytest

from usv_predictor.models import loading
from usv_predictor.physics import vessel as vessel_module
from usv_predictor.replay import cli

ROOT = Path(__file__).resolve().parents[1]
TRAINING = ROOT / "bags" / "training"
SEA_TRIAL = ROOT / "bags" / "sea_trial"


class Stop(BaseException):
    """Raised in place of the work after the vessel and the recordings (not an Exception: the CLI lets it through)."""


@pytest.fixture
def counted(monkeypatch: pytest.MonkeyPatch) -> Counter:
    """Counter of resolve_vessel calls ("resolved") and vessel files read ("read")."""
    counts: Counter = Counter()
    resolve, read = loading.resolve_vessel, vessel_module.load_yaml

    def counting_resolve(*args, **kwargs):
        counts["resolved"] += 1
        return resolve(*args, **kwargs)

    def counting_read(path, what, *args, **kwargs):
        counts["read"] += what == "vessel description"
        return read(path, what, *args, **kwargs)

    monkeypatch.setattr(loading, "resolve_vessel", counting_resolve)
    monkeypatch.setattr(vessel_module, "load_yaml", counting_read)
    return counts


def stop(*args, **kwargs):
    raise Stop


def test_dataset_reads_the_vessel_once(counted, tmp_path):
    """Every shipped training bag names its vessel (custom_data vessel jari_usv): the bags read as that vessel are
    not checked against its file again, bag by bag."""
    assert cli.main(["dataset", str(TRAINING), "--output", str(tmp_path / "d.npz"), "--jobs", "1"]) == 0
    assert counted == {"resolved": 1, "read": 1}


def test_train_reads_the_vessel_once(counted, monkeypatch, tmp_path):
    assert cli.main(["dataset", str(TRAINING), "--output", str(tmp_path / "d.npz"), "--jobs", "1"]) == 0
    counted.clear()
    monkeypatch.setattr("usv_predictor.fitting.training.train_dnn", stop)
    with pytest.raises(Stop):
        cli.main(["train", str(tmp_path / "d.npz"), "--output", str(tmp_path / "m.pt"), "--epochs", "1"])
    assert counted == {"resolved": 1, "read": 1}


def test_identify_reads_the_vessel_once(counted, monkeypatch, tmp_path):
    monkeypatch.setattr("usv_predictor.fitting.hull_models.identify", stop)
    with pytest.raises(Stop):
        cli.main(["identify", str(TRAINING), "--vessel", "jari_usv", "--prior", "fix", "--output",
                  str(tmp_path / "m.pt")])
    assert counted == {"resolved": 1, "read": 1}


def test_diagnose_reads_the_vessel_once(counted, monkeypatch):
    monkeypatch.setattr("usv_predictor.analysis.diagnosis_run.run_diagnosis", stop)
    with pytest.raises(Stop):
        cli.main(["diagnose", str(SEA_TRIAL)])  # the config's vessel
    assert counted == {"resolved": 1, "read": 1}


def test_evaluate_reads_the_vessel_once(counted, monkeypatch):
    """The shipped model embeds its description: --vessel is read once and checked against it."""
    monkeypatch.setattr("usv_predictor.analysis.evaluation.evaluate", stop)
    with pytest.raises(Stop):
        cli.main(["evaluate", str(SEA_TRIAL), "--vessel", "jari_usv"])
    assert counted == {"resolved": 1, "read": 1}


def test_evaluate_takes_the_vessel_the_model_embeds_without_reading_a_file(counted, monkeypatch):
    monkeypatch.setattr("usv_predictor.analysis.evaluation.evaluate", stop)
    with pytest.raises(Stop):
        cli.main(["evaluate", str(SEA_TRIAL)])
    assert counted == {"resolved": 1}


def test_evaluate_and_report_read_a_vessel_file_once(counted, monkeypatch, tmp_path):
    from usv_predictor.physics.vessel import vessel_dir

    boat = tmp_path / "jari.yaml"
    boat.write_bytes((vessel_dir() / "jari_usv.yaml").read_bytes())
    monkeypatch.setattr("usv_predictor.analysis.evaluation.evaluate", stop)
    for command in (["evaluate", str(SEA_TRIAL)], ["report", str(SEA_TRIAL), "--output", str(tmp_path / "r")]):
        counted.clear()
        with pytest.raises(Stop):
            cli.main([*command, "--vessel", str(boat)])
        assert counted == {"resolved": 1, "read": 1}, command


@pytest.mark.parametrize("vessel", ["otter", "file"])
def test_simulate_reads_the_vessel_once(counted, tmp_path, vessel):
    """A whole simulation (a sea, a hidden effect, its calm twin): the command resolves the vessel, the scenario, the
    manoeuvre and the simulator take it."""
    from usv_predictor.physics.vessel import vessel_dir

    if vessel == "file":
        vessel = str(tmp_path / "boat.yaml")
        Path(vessel).write_bytes((vessel_dir() / "otter.yaml").read_bytes())
    assert cli.main(["simulate", "--vessel", vessel, "--manoeuvre", "turning-circle", "--duration", "12", "--dt",
                     "0.1", "--sea", "rizhao", "--effect", "thruster_imbalance", "--calm-twin", "--output",
                     str(tmp_path / "bags")]) == 0
    assert counted == {"resolved": 1, "read": 1}


def test_the_resolver_is_the_one_meaning_of_none(tmp_path):
    """None: the predictor config's vessel, or the model's; a Vessel is taken as it is."""
    from usv_predictor.config import load_predictor_config
    from usv_predictor.models.greybox import greybox_predictor

    configured = loading.resolve_vessel()
    assert configured.name == load_predictor_config().vessel
    assert loading.resolve_vessel(configured) is configured
    otter = vessel_module.load_vessel("otter")
    assert loading.resolve_vessel(model=greybox_predictor(otter, 0.25)) == otter  # the description it embeds
