"""The artifact embeds its vessel description: written with a digest, used where no vessel is given
(evaluate, diagnose --model, the fit check, the node), a given vessel that differs refused in one line naming the
fields, and artifacts of before (name only, as the shipped models/default.pt was before its rebuild) still
found by their name."""
from __future__ import annotations

import dataclasses
import io
import json
from pathlib import Path

import pytest
import torch
import yaml

from usv_predictor.analysis.diagnosis_run import calm_water_model
from usv_predictor.config import load_predictor_config, package_share_path
from usv_predictor.errors import ConfigError, ModelError
from usv_predictor.models import loading
from usv_predictor.models.artifact import (
    METADATA_FILE,
    VESSEL_DIGEST_KEY,
    VESSEL_FILE,
    export_like,
    export_module,
    load_artifact,
    read_metadata,
)
from usv_predictor.models.greybox import GreyBoxRollout, greybox_metadata
from usv_predictor.node import node as predictor_node
from usv_predictor.physics.vessel import (
    available_vessels,
    description_differences,
    description_sha256,
    load_vessel,
    vessel_from_dict,
    vessel_to_dict,
)
from usv_predictor.replay.cli import main

OTTER_BAGS = package_share_path("bags", "otter", "sea_trial")
DT = 0.25  # s, the otter's diagnosis step


def my_boat(tmp_path: Path, name: str = "my_otter", folder: str = "", **geometry: float) -> tuple[Path, object]:
    """A vessel file (in tmp_path/folder) of a boat that is no preset here (the otter preset under another name, its
    geometry changed as given), and its Vessel."""
    raw = vessel_to_dict(load_vessel("otter"))
    raw["name"] = name
    raw["geometry"].update(geometry)
    (tmp_path / folder).mkdir(exist_ok=True)
    path = tmp_path / folder / f"{name}.yaml"
    path.write_text(yaml.safe_dump(raw))
    return path, load_vessel(path)


def greybox_artifact(path: Path, vessel, *, embed: bool = True):
    """The calm-water grey box of `vessel` as an artifact, with its description embedded or (as before) named only."""
    rollout = GreyBoxRollout(vessel, dt=DT)
    meta = greybox_metadata(vessel, rollout, training_data_sha256="0" * 64)
    return export_module(path, rollout, meta, vessel=vessel if embed else None)


@pytest.mark.parametrize("name", available_vessels())
def test_every_preset_round_trips_through_its_description(name):
    vessel = load_vessel(name)
    description = vessel_to_dict(vessel)
    assert vessel_from_dict(json.loads(json.dumps(description))) == vessel
    assert description_differences(description, vessel_to_dict(load_vessel(name))) == []


def test_the_artifact_carries_the_whole_description_and_its_digest(tmp_path):
    path, vessel = my_boat(tmp_path)
    artifact = greybox_artifact(tmp_path / "m.pt", vessel)
    assert artifact.metadata["vessel"] == "my_otter"
    assert artifact.metadata[VESSEL_DIGEST_KEY] == description_sha256(vessel_to_dict(vessel))
    assert artifact.embedded_vessel == vessel
    extra = {VESSEL_FILE: ""}
    torch.jit.load(str(tmp_path / "m.pt"), _extra_files=extra)
    assert json.loads(extra[VESSEL_FILE]) == vessel_to_dict(vessel)  # in the extra files, readable without us
    # no preset of that name here: the model's vessel is the one it carries, with or without its name given
    assert "my_otter" not in available_vessels()
    assert loading.model_vessel(artifact) == vessel
    assert loading.model_vessel(artifact, "my_otter") == vessel
    assert loading.model_vessel(artifact, path) == vessel  # the same file: accepted


def test_a_given_vessel_that_differs_is_refused_naming_the_fields(tmp_path):
    _, vessel = my_boat(tmp_path)
    artifact = greybox_artifact(tmp_path / "m.pt", vessel)
    other, _ = my_boat(tmp_path, folder="o", L_pp=2.2, B=1.2)
    with pytest.raises(ModelError, match=r"was made for vessel 'my_otter' \(the description it embeds\), --vessel "
                                         r".*my_otter.yaml differs: geometry.B: model 1.08, --vessel 1.2; "
                                         r"geometry.L_pp: model 2, --vessel 2.2$"):
        loading.model_vessel(artifact, other)
    with pytest.raises(ModelError, match=r"--vessel otter differs: name: model my_otter, --vessel otter$"):
        loading.model_vessel(artifact, "otter")
    # the free text is not the boat
    renamed = vessel_to_dict(vessel) | {"description": "another text", "provenance": "elsewhere"}
    assert loading.model_vessel(artifact, vessel_from_dict(renamed)).name == "my_otter"


def test_a_modified_description_is_refused_by_its_digest(tmp_path):
    _, vessel = my_boat(tmp_path)
    greybox_artifact(tmp_path / "m.pt", vessel)
    extra = {METADATA_FILE: "", VESSEL_FILE: ""}
    module = torch.jit.load(str(tmp_path / "m.pt"), _extra_files=extra)
    tampered = json.loads(extra[VESSEL_FILE])
    tampered["geometry"]["L_pp"] = 3.0
    buffer = io.BytesIO()
    torch.jit.save(module, buffer, _extra_files={METADATA_FILE: extra[METADATA_FILE],
                                                 VESSEL_FILE: json.dumps(tampered)})
    (tmp_path / "bad.pt").write_bytes(buffer.getvalue())
    with pytest.raises(ModelError, match=r"bad.pt: vessel.json does not match its digest vessel_sha256"):
        load_artifact(tmp_path / "bad.pt")
    buffer = io.BytesIO()
    torch.jit.save(module, buffer, _extra_files={METADATA_FILE: extra[METADATA_FILE]})
    (tmp_path / "lost.pt").write_bytes(buffer.getvalue())
    with pytest.raises(ModelError, match=r"lost.pt: its metadata has vessel_sha256 but the file has no vessel.json"):
        load_artifact(tmp_path / "lost.pt")


def test_a_copied_digest_without_its_description_is_not_written(tmp_path):
    """export_module with another model's metadata (its vessel_sha256) and no vessel: the file would carry a digest
    of a description it does not hold and not load (above), so it is refused before anything is written; given the
    other model's embedded vessel, it is written and carries it."""
    _, vessel = my_boat(tmp_path)
    source = greybox_artifact(tmp_path / "m.pt", vessel)
    with pytest.raises(ModelError, match=r"copy.pt: metadata has vessel_sha256 \(copied from another model\?\) but no "
                                         r"vessel is given"):
        export_module(tmp_path / "copy.pt", source.module, source.metadata)
    assert not (tmp_path / "copy.pt").exists()
    copy = export_module(tmp_path / "copy.pt", source.module, source.metadata, vessel=source.embedded_vessel)
    assert copy.metadata[VESSEL_DIGEST_KEY] == source.metadata[VESSEL_DIGEST_KEY]
    assert copy.embedded_vessel == vessel


def test_a_model_like_another_carries_its_metadata_with_the_changes_and_its_vessel(tmp_path):
    """export_like (the tests' failing models, the benchmark's larger ensemble): the other model's metadata with the
    named fields changed, its vessel description embedded, the fields export fills made anew."""
    _, vessel = my_boat(tmp_path)
    source = greybox_artifact(tmp_path / "m.pt", vessel)
    like = export_like(tmp_path / "like.pt", GreyBoxRollout(vessel, dt=DT), source, horizon_steps=7,
                       training_data_sha256="1" * 64)
    assert like.embedded_vessel == vessel
    assert like.metadata[VESSEL_DIGEST_KEY] == source.metadata[VESSEL_DIGEST_KEY]
    assert like.metadata["horizon_steps"] == 7
    assert source.metadata["horizon_steps"] != 7
    assert like.metadata["training_data_sha256"] == "1" * 64
    unchanged = set(source.metadata) - {"horizon_steps", "training_data_sha256", "model_id", "created_utc"}
    assert {k: like.metadata[k] for k in unchanged} == {k: source.metadata[k] for k in unchanged}
    assert like.model_id != source.model_id  # the changed fields are in the id


def as_written_before(source: Path, path: Path) -> Path:
    """`source` as artifacts were written before the description was embedded (the shipped model before its rebuild,
    81c5143c983762d4): its metadata without vessel_sha256, no vessel.json."""
    extra = {METADATA_FILE: "", VESSEL_FILE: ""}
    module = torch.jit.load(str(source), _extra_files=extra)
    meta = json.loads(extra[METADATA_FILE])
    assert meta.pop(VESSEL_DIGEST_KEY) and extra[VESSEL_FILE]  # the source embeds its description
    buffer = io.BytesIO()
    torch.jit.save(module, buffer, _extra_files={METADATA_FILE: json.dumps(meta)})
    path.write_bytes(buffer.getvalue())
    return path


def test_artifacts_of_before_are_found_by_their_vessel_name(tmp_path):
    shipped = loading.load_model("")  # models/default.pt, rebuilt by `replay train`: it embeds jari_usv
    assert shipped.embedded_vessel == load_vessel("jari_usv")
    before = loading.load_model(str(as_written_before(package_share_path("models", "default.pt"), tmp_path / "b.pt")))
    _, meta = read_metadata(tmp_path / "b.pt")
    assert VESSEL_DIGEST_KEY not in meta
    assert before.vessel_description is None
    assert before.embedded_vessel is None
    assert loading.model_vessel(before) == load_vessel("jari_usv")
    assert loading.model_vessel(before, "jari_usv") == load_vessel("jari_usv")
    _, vessel = my_boat(tmp_path)
    old = greybox_artifact(tmp_path / "old.pt", vessel, embed=False)
    with pytest.raises(ConfigError, match=r"names vessel 'my_otter' but embeds no description .* pass --vessel FILE"):
        loading.model_vessel(old)
    assert loading.model_vessel(old, tmp_path / "my_otter.yaml") == vessel


def test_evaluate_and_the_fit_check_take_the_vessel_from_the_model(tmp_path, capsys):
    _, vessel = my_boat(tmp_path)
    greybox_artifact(tmp_path / "m.pt", vessel)
    out = tmp_path / "e.json"
    assert main(["evaluate", str(OTTER_BAGS), "--model", str(tmp_path / "m.pt"), "--json", str(out)]) == 0
    check = json.loads(out.read_text())["fit_check"]
    assert check["verdict"] == "fits"
    assert check["actuator_layout"] == "twin_thrusters"
    assert check["length_m"] == 2.0 and check["top_speed_mps"] == pytest.approx(3.086, abs=0.01)  # the embedded boat's
    assert main(["evaluate", str(OTTER_BAGS), "--model", str(tmp_path / "m.pt"), "--vessel", "my_otter",
                 "--json", str(out)]) == 0  # its name: no preset here, the model's description
    assert json.loads(out.read_text())["fit_check"]["length_m"] == 2.0
    capsys.readouterr()
    other, _ = my_boat(tmp_path, folder="x", L_pp=2.5)
    assert main(["evaluate", str(OTTER_BAGS), "--model", str(tmp_path / "m.pt"), "--vessel", str(other)]) == 2
    errors = [line for line in capsys.readouterr().err.splitlines() if "error:" in line]
    assert len(errors) == 1
    assert errors[0].startswith("replay evaluate: error: model ")
    assert errors[0].endswith("differs: geometry.L_pp: model 2, --vessel 2.5")


def test_diagnose_takes_the_calm_water_vessel_from_the_model(tmp_path, capsys):
    path, vessel = my_boat(tmp_path)
    greybox_artifact(tmp_path / "m.pt", vessel)
    calm = calm_water_model(None, tmp_path / "m.pt")
    assert calm.description == vessel
    assert calm.vessel.small_craft == vessel.small_craft
    assert calm.source.startswith("identified (")
    assert calm_water_model(path, tmp_path / "m.pt").description == vessel
    other, _ = my_boat(tmp_path, folder="y", d=0.3)
    assert main(["diagnose", str(OTTER_BAGS), "--model", str(tmp_path / "m.pt"), "--vessel", str(other)]) == 2
    errors = [line for line in capsys.readouterr().err.splitlines() if "error:" in line]
    assert len(errors) == 1
    assert errors[0].endswith("differs: geometry.d: model 0.195122, --vessel 0.3")
    greybox_artifact(tmp_path / "old.pt", vessel, embed=False)
    assert main(["diagnose", str(OTTER_BAGS), "--model", str(tmp_path / "old.pt")]) == 2
    assert "pass --vessel FILE" in capsys.readouterr().err


def test_the_node_uses_the_embedded_vessel_when_its_file_is_not_installed(tmp_path):
    _, vessel = my_boat(tmp_path)
    greybox_artifact(tmp_path / "m.pt", vessel)
    config = dataclasses.replace(load_predictor_config(), vessel="my_otter", dt=DT, ensemble_size=1)
    rollout, chosen = predictor_node.load_model(str(tmp_path / "m.pt"), config)
    assert chosen == vessel
    assert chosen.actuator_layout.name == "twin_thrusters"
    assert rollout.artifact.embedded_vessel == vessel
    # a preset of that name that differs from what the model carries: refused, naming the fields
    _, changed = my_boat(tmp_path, folder="z", name="otter", L_pp=2.4)
    greybox_artifact(tmp_path / "o.pt", changed)
    with pytest.raises(ModelError, match=r"vessel otter differs: geometry.L_pp: model 2.4, vessel 2$"):
        predictor_node.load_model(str(tmp_path / "o.pt"), dataclasses.replace(config, vessel="otter"))
    # the shipped model (name only) still runs on its preset
    rollout, chosen = predictor_node.load_model("", load_predictor_config())
    assert chosen == load_vessel("jari_usv")


def test_a_node_runs_a_boat_whose_vessel_file_is_not_installed(ros_context, tmp_path):
    """The rclpy node itself: vessel my_otter (no preset) and its model: the twin-thruster inputs are subscribed."""
    from rclpy.parameter import Parameter

    _, vessel = my_boat(tmp_path)
    greybox_artifact(tmp_path / "m.pt", vessel)
    node = predictor_node.PredictorNode(context=ros_context, parameter_overrides=[
        Parameter("vessel", value="my_otter"), Parameter("model_path", value=str(tmp_path / "m.pt")),
        Parameter("dt", value=DT), Parameter("ensemble_size", value=1)])
    try:
        assert node.vessel == vessel
        assert node.layout.name == "twin_thrusters"
        assert {"thruster_port", "thruster_starboard"} <= set(node.inputs.tracks)
        assert node.inputs.missing == []
        assert "rudder_angle" in node.ignored
        assert "thruster_port" not in node.ignored
        assert node.sea.estimator is not None
        assert node.sea.estimator.layout.name == "twin_thrusters"
        assert node.sea.estimator.model.vessel.small_craft == vessel.small_craft  # the online estimator's boat
    finally:
        node.destroy_node()
