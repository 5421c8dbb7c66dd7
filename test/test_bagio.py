"""replay.bagio: write -> read round trips, bulk CDR == rosbags CDR, custom_data, atomic writes,
refusals and the errors for missing topics, wrong types and corrupt bags."""
from __future__ import annotations

import hashlib
import math
from pathlib import Path

import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import Writer

from msg_adapters import ROLE_FIELDS, columnar_factory, get_adapter, registered, rosbags_factory
from usv_predictor.errors import BagError
from usv_predictor.records import Signal
from usv_predictor.replay import bagio
from usv_predictor.replay.bagio import TopicSpec, bag_info, read_bag, read_custom_data, write_bag

T0 = 1_700_000_000_000_000_000  # ns
JOINT = {"joint": "rudder_joint"}


def _signal(role: str, hz: float, seconds: float, rng: np.random.Generator, offset_ns: int = 0) -> Signal:
    n = int(hz * seconds)
    t_ns = T0 + offset_ns + (np.arange(n) * (1e9 / hz)).astype(np.int64)
    k = len(ROLE_FIELDS[role])
    values = rng.normal(size=(n, k))
    if role == "gnss":
        values = values * 1e-4 + np.array([59.0, 10.0, 2.0])
        values[3] = np.nan  # one epoch without fix
    if role in ("heading", "imu", "odometry"):  # angles come back wrapped: give wrapped ones
        column = ROLE_FIELDS[role].index("heading" if role == "imu" else "psi")
        values[:, column] = rng.uniform(-math.pi, math.pi, n)
    if role == "imu":
        values[2, 4] = np.nan  # REP-145: no orientation in this message
    if role == "engine_rpm":
        values = 1000.0 + 50.0 * values
    return Signal(t_ns, values, ROLE_FIELDS[role])


ALL_SPECS = [
    TopicSpec("imu/data", "imu", "sensor_msgs/msg/Imu", frame_id="imu_link"),
    TopicSpec("velocity", "velocity", "geometry_msgs/msg/TwistStamped", frame_id="base_link"),
    TopicSpec("velocity_cov", "velocity", "geometry_msgs/msg/TwistWithCovarianceStamped"),
    TopicSpec("odom_velocity", "velocity", "nav_msgs/msg/Odometry", frame_id="odom"),
    TopicSpec("heading", "heading", "std_msgs/msg/Float64"),
    TopicSpec("heading_enu_rad", "heading", "std_msgs/msg/Float32", {"units": "rad", "convention": "enu"}),
    TopicSpec("heading_quat", "heading", "geometry_msgs/msg/QuaternionStamped"),
    TopicSpec("heading_imu", "heading", "sensor_msgs/msg/Imu"),
    TopicSpec("rudder_angle", "rudder_angle", "std_msgs/msg/Float64"),
    TopicSpec("rudder_deg", "rudder_angle", "std_msgs/msg/Float32", {"units": "deg", "sign": -1}),
    TopicSpec("joint_states/rudder", "rudder_angle", "sensor_msgs/msg/JointState", JOINT),
    TopicSpec("engine_rpm", "engine_rpm", "std_msgs/msg/Float64"),
    TopicSpec("engine_rpm32", "engine_rpm", "std_msgs/msg/Float32"),
    TopicSpec("joint_states/propeller", "engine_rpm", "sensor_msgs/msg/JointState", JOINT),
    TopicSpec("gps/fix", "gnss", "sensor_msgs/msg/NavSatFix", frame_id="gps"),
    TopicSpec("ground_truth/odometry", "odometry", "nav_msgs/msg/Odometry", {"child_frame_id": "hull"}, "odom"),
]


def _streams(seed: int = 0) -> list[tuple[TopicSpec, Signal]]:
    rng = np.random.default_rng(seed)
    rates = {"imu": 50.0, "gnss": 5.0}
    return [
        (spec, _signal(spec.role, rates.get(spec.role, 10.0), 2.0, rng, offset_ns=i * 1_000))
        for i, spec in enumerate(ALL_SPECS)
    ]


def _tree_digest(path: Path) -> str:
    digest = hashlib.sha256()
    for file in sorted(p for p in path.rglob("*") if p.is_file()):
        digest.update(str(file.relative_to(path)).encode())
        digest.update(file.read_bytes())
    return digest.hexdigest()


@pytest.fixture(scope="module")
def small_bag(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[tuple[TopicSpec, Signal]]]:
    streams = _streams()
    path = write_bag(tmp_path_factory.mktemp("bags") / "small", streams, metadata={"made_by": "test_bagio"})
    return path, streams


@pytest.mark.parametrize(("role", "ros_type"), registered())
def test_bulk_cdr_equals_rosbags_serialize_cdr(role: str, ros_type: str) -> None:
    typestore = bagio.jazzy_typestore()
    options = JOINT if ros_type.endswith("JointState") else {"index": 2} if "MultiArray" in ros_type else {}
    adapter = get_adapter(role, ros_type, **options)
    signal = _signal(role, 10.0, 0.7, np.random.default_rng(1))
    columns = adapter.encode(signal.t_ns, list(signal.values.T), columnar_factory(), "some_frame")
    fast = bagio.serialize_columns(typestore, ros_type, columns, len(signal))
    make = rosbags_factory(typestore)
    reference = [
        bytes(typestore.serialize_cdr(adapter.encode(int(t), [float(x) for x in row], make, "some_frame"), ros_type))
        for t, row in zip(signal.t_ns, signal.values)
    ]
    assert [bytes(m) for m in fast] == reference


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
@pytest.mark.parametrize("compress", [True, False])
def test_round_trip_all_roles(tmp_path: Path, storage: str, compress: bool) -> None:
    streams = _streams(seed=2)
    path = write_bag(tmp_path / "bag", streams, storage=storage, compress=compress)
    signals = read_bag(path, [spec for spec, _ in streams])
    assert set(signals) == {spec.topic for spec, _ in streams}
    for spec, written in streams:
        read = signals[spec.topic]
        assert read.fields == written.fields
        np.testing.assert_array_equal(read.t_ns, written.t_ns)  # header stamp, or log time = stamp
        atol = 1e-4 if spec.ros_type.endswith("Float32") else 1e-9
        expected = written.values.copy()
        if spec.role == "gnss":
            expected[~np.isfinite(expected).all(axis=1)] = np.nan  # a NaN anywhere means "no fix"
        np.testing.assert_allclose(read.values, expected, rtol=1e-6 if atol > 1e-9 else 0, atol=atol,
                                   err_msg=spec.topic)


def test_anyreader_sees_types_counts_and_global_time_order(small_bag) -> None:
    path, streams = small_bag
    with AnyReader([path], default_typestore=bagio.jazzy_typestore()) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        counts = {c.topic: c.msgcount for c in reader.connections}
        log_times = [t for _, t, _ in reader.messages()]
    assert types == {spec.topic: spec.ros_type for spec, _ in streams}
    assert counts == {spec.topic: len(signal) for spec, signal in streams}
    assert log_times == sorted(log_times)
    assert sorted(log_times) == sorted(np.concatenate([s.t_ns for _, s in streams]).tolist())


def test_file_compression_is_used_for_sqlite(small_bag) -> None:
    path, _ = small_bag
    assert [p.name for p in path.iterdir() if p.name != "metadata.yaml"] == ["small.db3.zstd"]


def test_custom_data_and_bag_info(small_bag) -> None:
    path, streams = small_bag
    assert read_custom_data(path) == {"made_by": "test_bagio"}
    info = bag_info(path)
    assert info["custom_data"] == {"made_by": "test_bagio"}
    assert info["message_count"] == sum(len(s) for _, s in streams)
    imu = next(t for t in info["topics"] if t["topic"] == "imu/data")
    assert imu["type"] == "sensor_msgs/msg/Imu"
    assert imu["rate_hz"] == pytest.approx(50.0)
    assert info["duration_s"] == pytest.approx((info["end_ns"] - info["start_ns"]) * 1e-9)
    assert info["size_bytes"] == sum(p.stat().st_size for p in path.iterdir())


def test_reading_leaves_the_bag_unchanged(small_bag) -> None:
    path, streams = small_bag
    before = _tree_digest(path)
    read_bag(path, [spec for spec, _ in streams])
    bag_info(path)
    read_custom_data(path)
    assert _tree_digest(path) == before


def test_existing_output_is_refused_without_overwrite(tmp_path: Path) -> None:
    first, second = _streams(seed=3)[:1], _streams(seed=4)[:1]
    path = write_bag(tmp_path / "bag", first)
    before = _tree_digest(path)
    with pytest.raises(BagError, match=r"bag exists already; use --overwrite"):
        write_bag(path, second)
    assert _tree_digest(path) == before
    write_bag(path, second, overwrite=True)
    spec, signal = second[0]
    np.testing.assert_allclose(read_bag(path, [spec])[spec.topic].values, signal.values)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bag"]  # no temporary leftovers


def _fail_after(count: int):
    original = Writer.write
    calls = {"n": 0}

    def write(self, connection, timestamp, data):  # noqa: ANN001, ANN202 - same signature as Writer.write
        calls["n"] += 1
        if calls["n"] > count:
            raise RuntimeError("simulated crash while writing")
        return original(self, connection, timestamp, data)

    return write


def test_failed_write_leaves_nothing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(Writer, "write", _fail_after(10))
    with pytest.raises(RuntimeError, match="simulated crash"):
        write_bag(tmp_path / "bag", _streams())
    assert list(tmp_path.iterdir()) == []


def test_failed_overwrite_keeps_the_old_bag(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = write_bag(tmp_path / "bag", _streams(seed=5))
    before = _tree_digest(path)
    monkeypatch.setattr(Writer, "write", _fail_after(10))
    with pytest.raises(RuntimeError):
        write_bag(path, _streams(seed=6), overwrite=True)
    assert _tree_digest(path) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bag"]


def test_missing_topic_names_bag_topic_and_topics_present(small_bag) -> None:
    path, _ = small_bag
    with pytest.raises(BagError, match=r"small: no topic 'sonar'; topics present: \[.*'imu/data'"):
        read_bag(path, [TopicSpec("sonar", "heading", "std_msgs/msg/Float64")])


def test_wrong_type_names_topic_expected_and_found(small_bag) -> None:
    path, _ = small_bag
    with pytest.raises(BagError, match=r"'heading' has type std_msgs/msg/Float64, expected geometry_msgs/msg/Quater"):
        read_bag(path, [TopicSpec("heading", "heading", "geometry_msgs/msg/QuaternionStamped")])


def test_adapter_problems_name_the_topic(small_bag) -> None:
    path, _ = small_bag
    with pytest.raises(BagError, match=r"'joint_states/rudder'.*no joint 'steer'.*\['rudder_joint'\]"):
        read_bag(path,
                 [TopicSpec("joint_states/rudder", "rudder_angle", "sensor_msgs/msg/JointState", {"joint": "steer"})])
    with pytest.raises(BagError, match=r"topic 'heading'.*unknown option"):
        read_bag(path, [TopicSpec("heading", "heading", "std_msgs/msg/Float64", {"unit": "deg"})])


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_corrupt_bag_is_reported_with_its_path(tmp_path: Path, storage: str) -> None:
    path = write_bag(tmp_path / "bag", _streams(), storage=storage, compress=False)
    data_file = next(p for p in path.iterdir() if p.name != "metadata.yaml")
    data_file.write_bytes(data_file.read_bytes()[: data_file.stat().st_size // 3])
    spec = ALL_SPECS[0]
    with pytest.raises(BagError, match=rf"{path}: cannot"):
        read_bag(path, [spec])


def test_not_a_bag_is_reported(tmp_path: Path) -> None:
    with pytest.raises(BagError, match="no such bag"):
        read_bag(tmp_path / "absent", [ALL_SPECS[0]])
    (tmp_path / "empty").mkdir()
    with pytest.raises(BagError, match=r"empty: cannot read bag"):
        bag_info(tmp_path / "empty")


def test_stream_problems_are_refused_before_writing(tmp_path: Path) -> None:
    spec, signal = _streams()[0]
    with pytest.raises(BagError, match="appears twice"):
        write_bag(tmp_path / "bag", [(spec, signal), (spec, signal)])
    wrong_fields = Signal(signal.t_ns, signal.values[:, :3], ("u", "v", "r"))
    with pytest.raises(BagError, match=r"'imu/data' \(imu\): signal fields \('u', 'v', 'r'\)"):
        write_bag(tmp_path / "bag", [(spec, wrong_fields)])
    with pytest.raises(BagError, match="unknown storage 'rosbag1'"):
        write_bag(tmp_path / "bag", [(spec, signal)], storage="rosbag1")
    assert list(tmp_path.iterdir()) == []


def test_unsorted_and_empty_streams(tmp_path: Path) -> None:
    spec = TopicSpec("velocity", "velocity", "geometry_msgs/msg/TwistStamped")
    t_ns = T0 + np.array([3, 1, 2], dtype=np.int64) * 10**8
    values = np.array([[3.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]])
    empty_spec = TopicSpec("engine_rpm", "engine_rpm", "std_msgs/msg/Float64")
    empty = Signal(np.zeros(0, np.int64), np.zeros((0, 1)), ("rpm",))
    path = write_bag(tmp_path / "bag", [(spec, Signal(t_ns, values, ROLE_FIELDS["velocity"])), (empty_spec, empty)])
    signals = read_bag(path, [spec, empty_spec])
    np.testing.assert_array_equal(signals["velocity"].t_ns, np.sort(t_ns))  # sorted by stamp on read
    np.testing.assert_array_equal(signals["velocity"].column("u"), [1.0, 2.0, 3.0])
    assert len(signals["engine_rpm"]) == 0


def test_bulk_read_equals_message_by_message_read(small_bag, monkeypatch: pytest.MonkeyPatch) -> None:
    path, streams = small_bag
    specs = [spec for spec, _ in streams]
    bulk = read_bag(path, specs)
    monkeypatch.setattr(bagio, "has_fast_layout", lambda *_: False)
    one_by_one = read_bag(path, specs)
    for spec in specs:
        np.testing.assert_array_equal(bulk[spec.topic].t_ns, one_by_one[spec.topic].t_ns)
        np.testing.assert_array_equal(bulk[spec.topic].values, one_by_one[spec.topic].values)  # NaN-aware


SHARED_TOPICS = {  # both thrusters on one topic: the common conventions
    "std_msgs/msg/Float64MultiArray": ({"index": 0, "units": "pwm"}, {"index": 1, "units": "pwm"}),
    "sensor_msgs/msg/JointState": ({"joint": "left", "units": "rpm", "full_scale": 2000.0},
                                   {"joint": "right", "units": "rpm", "full_scale": 2000.0}),
    "geometry_msgs/msg/WrenchStamped": ({"yaw_full_scale": 0.5}, {"yaw_full_scale": 0.5}),
}


def _thruster_streams(ros_type: str, rows: int = 40) -> list[tuple[TopicSpec, Signal]]:
    rng = np.random.default_rng(11)
    t_ns = T0 + np.arange(rows, dtype=np.int64) * 100_000_000
    port, starboard = SHARED_TOPICS[ros_type]
    commands = rng.uniform(-1.0, 1.0, size=(rows, 2)) * 0.5  # |port - starboard| / 2 stays within the yaw scale
    return [(TopicSpec("thrusters", "thruster_port", ros_type, port, "base_link"),
             Signal(t_ns, commands[:, :1], ROLE_FIELDS["thruster_port"])),
            (TopicSpec("thrusters", "thruster_starboard", ros_type, starboard, "base_link"),
             Signal(t_ns, commands[:, 1:], ROLE_FIELDS["thruster_starboard"]))]


@pytest.mark.parametrize("ros_type", sorted(SHARED_TOPICS))
def test_two_roles_on_one_topic_round_trip(tmp_path: Path, ros_type: str) -> None:
    streams = _thruster_streams(ros_type)
    path = write_bag(tmp_path / "bag", streams)
    assert [(t["topic"], t["type"], t["count"]) for t in bag_info(path)["topics"]] == [("thrusters", ros_type, 40)]
    signals = bagio.read_signals(path, [spec for spec, _ in streams])
    for (_, written), read in zip(streams, signals):
        np.testing.assert_array_equal(read.t_ns, written.t_ns)
        np.testing.assert_allclose(read.values, written.values, atol=1e-12)
    with pytest.raises(BagError, match=r"topic\(s\) \['thrusters'\] carry several roles: read them with read_signals"):
        read_bag(path, [spec for spec, _ in streams])


def test_shared_topic_refusals(tmp_path: Path) -> None:
    streams = _thruster_streams("std_msgs/msg/Float64MultiArray")
    (port, a), (starboard, b) = streams
    late = Signal(b.t_ns + 1, b.values, b.fields)
    with pytest.raises(BagError, match=r"share the topic but not their sample times"):
        write_bag(tmp_path / "bag", [(port, a), (starboard, late)])
    same = TopicSpec("thrusters", "thruster_starboard", port.ros_type, {"index": 0, "units": "pwm"})
    with pytest.raises(BagError, match=r"'thruster_port' and 'thruster_starboard' read the same part"):
        write_bag(tmp_path / "bag", [(port, a), (same, b)])
    path = write_bag(tmp_path / "bag", streams)
    with pytest.raises(BagError, match=r"bag: topic 'thrusters'.*read the same part"):
        bagio.read_signals(path, [port, same])
    assert not (tmp_path / "bag.partial").exists()


def test_pwm_outside_the_configured_range_names_bag_topic_and_field(tmp_path: Path) -> None:
    streams = _thruster_streams("std_msgs/msg/Float64MultiArray")
    path = write_bag(tmp_path / "bag", streams)
    wrong = TopicSpec("thrusters", "thruster_starboard", "std_msgs/msg/Float64MultiArray",
                      {"index": 1, "units": "newton", "full_scale": 120.0})  # a PWM read as thrust in N
    with pytest.raises(BagError, match=r"bag: topic 'thrusters' \(thruster_starboard\): thruster_starboard = 1[\d.]+ "
                                       r"\(data\[1\]\) with units newton.*PWM in microseconds configured as a thrust"):
        bagio.read_signals(path, [wrong])
