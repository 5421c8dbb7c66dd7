"""Bags -> Recordings: the topics of config/predictor.yaml, cleaned, cut at gaps, optionally split into manoeuvres.

    load_recordings(["bags/training"], dt=0.5) -> [Recording, ...]

Bag arguments: a directory holding metadata.yaml (or a single bag file) is one bag; any other directory is
searched recursively for bags, in sorted order, skipping hidden sub-directories and those named `calm` (the
calm-water twins of `replay simulate --calm-twin`) unless include_calm=True. A calm directory named explicitly is
read in full.
Recording names are the shortest trailing part of the bag path that is unique among the bags read
(`zigzag_10_10_stbd_650rpm`, or `training/zigzag_...` next to `calm/zigzag_...`).

What happens to imperfect input (warnings go through `warn`, by default to stderr):
- topic names: a configured (relative) name matches the bag's fully qualified one, as ROS resolves names in the
  root namespace (`imu/data` reads `/imu/data`, written so by `ros2 bag record`; bagio.resolve_topic);
- missing or unreadable bag, unreadable metadata, a required topic missing or empty, a topic of another
  message type: BagError naming the bag, the topic and what is present;
- a missing optional topic (GNSS, ground truth): that role is left out, with a warning;
- samples with NaN in a field the Recording uses (USED_FIELDS): dropped, warning with topic/field/count; the
  same for values outside the plausible ranges (data.recording.PLAUSIBLE, the controls' plausible ranges), e.g.
  a corrupt 1e30 or a rudder angle in degrees read as radians;
- stamps: rows are sorted; a step backwards by more than the step dt in the given order is an error naming
  the time (bagio.read_bag sorts by header stamp, so this guards Signals from elsewhere); exact duplicates
  (same stamp, same values) are dropped and counted; same stamp with other values: the first is kept, counted;
- a gap longer than the step dt in a required topic: the recording is cut there (pieces NAME#1, NAME#2, ...,
  warning with topic, time and length); a gap does not end the manoeuvre, so the dataset keeps the pieces of
  one bag in one split (dataset.manoeuvre_of);
- a piece or segment shorter than min_duration_s, or with fewer than horizon_s / dt + 1 steps: skipped, warning.

segment="steady" splits each bag into manoeuvres (NAME@1, NAME@2, ... numbered through the bag, gap pieces
included; see steady_cuts for the rule); each is its own manoeuvre for the split.
Bags are only read, never modified. With jobs > 1 bags are read by worker processes; the result, warnings
included, is the same as with one.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
import hashlib
import math
import multiprocessing
import os
import signal
import sys
from collections.abc import Callable, Iterable, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from usv_predictor.bounded import load_yaml
from usv_predictor.config import FLOAT_RANGES, input_topics, load_predictor_config
from usv_predictor.data.recording import (
    Recording,
    RecordingError,
    froude_scaled,
    plausible_ranges,
    recording_from_signals,
    required_roles,
)
from usv_predictor.errors import BagError, ConfigError, DatasetError, one_line
from usv_predictor.physics.actuators import (
    DEFAULT_LAYOUT,
    ActuatorLayout,
    actuator_layout,
    check_layout_inputs,
    unused_roles,
)
from usv_predictor.physics.vessel import load_vessel
from usv_predictor.records import NS_PER_S, Signal, whole_steps
from usv_predictor.replay.bagio import TopicSpec, read_signals, resolve_topic

OPTIONAL_ROLES = ("gnss", "odometry")
# Fields of each role that recording_from_signals uses: a NaN there would poison a window mean.
# (imu heading is NaN by design when the IMU has no orientation, REP-145, and is not used.) The controls'
# roles and fields come from the actuator layout (used_fields).
MOTION_USED_FIELDS: Mapping[str, tuple[str, ...]] = {
    "imu": ("yaw_rate",),
    "velocity": ("u", "v"),
    "heading": ("psi",),
    "gnss": ("lat", "lon"),
    "odometry": ("x_n", "y_e", "psi", "u", "v", "r"),
}


def used_fields(layout: ActuatorLayout = DEFAULT_LAYOUT) -> dict[str, tuple[str, ...]]:
    """role -> the fields a Recording uses: the motion's, the position's and the layout's controls'."""
    return {**MOTION_USED_FIELDS, **{role: layout.fields_of(role) for role in layout.roles}}


USED_FIELDS: Mapping[str, tuple[str, ...]] = used_fields(DEFAULT_LAYOUT)
SEGMENTS = ("bag", "steady")
CALM_DIR = "calm"

Warn = Callable[[str], None]


@dataclass(frozen=True)
class Pieces:
    """Which bags load_recordings reads, how it cuts them into pieces and which pieces it keeps, at what scale."""

    segment: str = "bag"  # one of SEGMENTS: a bag's pieces between gaps, or "steady": one per steady manoeuvre
    min_duration_s: float = 10.0  # a shorter piece is skipped, with a warning (s, at the model's scale)
    horizon_s: float | None = None  # a piece too short for this open-loop horizon is skipped (s); None: no check
    include_calm: bool = False  # also read the calm/ twins under bag directories
    scale: float = 1.0  # Froude scale L_bags / L_model of the bags (data/recording.froude_scaled); 1: none


def warn_stderr(message: str) -> None:
    print(f"warning: {message}", file=sys.stderr)


# ------------------------------------------------------------------ finding bags and their topics


@dataclasses.dataclass(frozen=True)
class BagSource:
    path: Path
    name: str  # unique among the bags read together


def _is_bag(path: Path) -> bool:
    return path.is_file() or (path / "metadata.yaml").is_file()


def _bags_under(root: Path, include_calm: bool, seen: set[tuple[int, int]] | None = None) -> list[Path]:
    """The bags below `root`, each directory searched once (by device and inode): a link back to `.` or to a
    parent directory, which would make the search endless, is skipped. Hidden directories are not searched: a
    writer's work in progress (`.<bag>.<random>.partial`, write_bag) is never read as a bag."""
    seen = set() if seen is None else seen
    info = root.stat()
    if (info.st_dev, info.st_ino) in seen:
        return []
    seen.add((info.st_dev, info.st_ino))
    found: list[Path] = []
    for child in sorted(root.iterdir()):
        if not child.is_dir() or child.name.startswith(".") or (child.name == CALM_DIR and not include_calm):
            continue
        found += [child] if _is_bag(child) else _bags_under(child, include_calm, seen)
    return found


def unique_names(paths: Sequence[Path]) -> list[str]:
    """The shortest trailing parts of each path that tell it apart from the others."""
    parts = [p.resolve().parts for p in paths]
    names = []
    for mine in parts:
        for k in range(1, len(mine) + 1):
            tail = mine[-k:]
            if sum(1 for other in parts if other[-k:] == tail) == 1:
                break
        names.append("/".join(tail))
    return names


def find_bags(paths: Iterable[str | Path], *, include_calm: bool = False) -> list[BagSource]:
    """Bags named by `paths` (bags or directories searched recursively; see the module docstring)."""
    bags: list[Path] = []
    for arg in map(Path, paths):
        if not arg.exists():
            raise BagError(f"{arg}: no such bag or directory")
        found = [arg] if _is_bag(arg) else _bags_under(arg, include_calm)
        if not found:
            hint = "" if include_calm else (f" (sub-directories named {CALM_DIR!r} are skipped: name them or use "
                                            "--include-calm)")
            raise BagError(f"{arg}: no rosbag2 bag (directory with metadata.yaml) found under it{hint}")
        bags += [b for b in found if b.resolve() not in {x.resolve() for x in bags}]
    return [BagSource(path, name) for path, name in zip(bags, unique_names(bags))]


def bag_sha256(path: Path) -> str:
    """SHA-256 of a bag: its files (metadata.yaml and storage files) in name order, each name then bytes."""
    path = Path(path)
    files = [path] if path.is_file() else sorted(f for f in path.iterdir() if f.is_file())
    digest = hashlib.sha256()
    try:
        for file in files:
            digest.update(file.name.encode() + b"\0")
            with file.open("rb") as stream:
                for block in iter(lambda: stream.read(1 << 20), b""):
                    digest.update(block)
    except OSError as err:
        raise BagError(f"{path}: cannot read the bag to hash it: {err}") from err
    return digest.hexdigest()


def bag_metadata(path: Path) -> tuple[dict[str, tuple[str, int]], dict[str, str]] | None:
    """(topic -> (type, message count), custom_data) of a rosbag2 metadata.yaml; None for a bag without one."""
    metadata = Path(path) / "metadata.yaml"
    if not metadata.is_file():
        return None
    try:
        info = load_yaml(metadata, "rosbag2 metadata", BagError)["rosbag2_bagfile_information"]
        topics = {t["topic_metadata"]["name"]: (t["topic_metadata"]["type"], int(t.get("message_count", 0)))
                  for t in info.get("topics_with_message_count") or []}
        custom = {str(k): str(v) for k, v in (info.get("custom_data") or {}).items()}
    except BagError as err:
        raise BagError(f"{path}: {err}") from err
    except (KeyError, TypeError, ValueError, AttributeError) as err:
        raise BagError(f"{path}: cannot read rosbag2 metadata {metadata} ({type(err).__name__}: "
                       f"{one_line(err)})") from err
    return topics, custom


def parse_datum(text: str) -> tuple[float, float] | None:
    """The position datum `replay simulate` records in custom_data ("lat,lon" deg), so pieces share a plane."""
    try:
        lat, lon = (float(x) for x in text.split(","))
    except ValueError:
        return None
    return (lat, lon) if -90.0 < lat < 90.0 and -180.0 <= lon <= 180.0 else None


def topic_specs(config_path: str | Path | None = None, topics: Mapping[str, str] | None = None,
                layout: ActuatorLayout | None = None) -> list[TopicSpec]:
    """TopicSpecs of the configured inputs and ground truth that a vessel of `layout` uses (None: the configured
    vessel's layout; the config lists the controls of every layout); `topics` overrides role -> topic name."""
    cfg = load_predictor_config(config_path)
    entries = input_topics(cfg, include_ground_truth=True)
    roles = {e.role for e in entries}
    unknown = sorted(set(topics or {}) - roles)
    if unknown:
        raise ConfigError(f"topic override for unknown role(s) {unknown}; roles of {cfg.source}: {sorted(roles)}")
    overrides = dict(topics or {})
    layout = layout or load_vessel(cfg.vessel).actuator_layout
    check_layout_inputs(layout, {e.role: overrides.get(e.role, e.topic) for e in entries}, cfg.source)
    unused = unused_roles(layout)
    return [TopicSpec(overrides.get(e.role, e.topic), e.role, e.ros_type, e.options, e.frame_id) for e in entries
            if e.role not in unused]


def _present_specs(path: Path, present: Mapping[str, tuple[str, int]] | None, specs: Sequence[TopicSpec],
                   warn: Warn, layout: ActuatorLayout = DEFAULT_LAYOUT) -> list[TopicSpec]:
    """The specs to read: required topics must be there (BagError), absent optional ones are left out, and the
    controls of other actuator layouts (the config lists every layout's) are not read."""
    unused = unused_roles(layout)
    specs = [spec for spec in specs if spec.role not in unused]
    if present is None:  # not a rosbag2 directory: let read_bag name what is missing
        return list(specs)
    required = required_roles(layout)
    chosen = []
    for spec in specs:
        name = resolve_topic(spec.topic, present)  # `imu/data` of the config is `/imu/data` of `ros2 bag record`
        if name is not None and name != spec.topic:
            spec = dataclasses.replace(spec, topic=name)
        ros_type, count = present.get(spec.topic, (None, 0))
        if spec.role in required:
            if ros_type is None:
                raise BagError(f"{path}: no topic {spec.topic!r} (role {spec.role}); topics present: {sorted(present)}")
            if count == 0:
                raise BagError(f"{path}: topic {spec.topic!r} (role {spec.role}) has no messages")
        elif ros_type is None or count == 0:
            warn(f"{path}: optional topic {spec.topic!r} (role {spec.role}) is absent; recording without it")
            continue
        if ros_type != spec.ros_type:
            raise BagError(f"{path}: topic {spec.topic!r} has type {ros_type}, expected {spec.ros_type} "
                           f"(set the type of role {spec.role!r} in the config)")
        chosen.append(spec)
    return chosen


# ------------------------------------------------------------------ cleaning signals


def clean_signal(signal: Signal, *, where: str, role: str, dt: float, t_ref_ns: int, warn: Warn,
                 layout: ActuatorLayout = DEFAULT_LAYOUT) -> Signal:
    """Drop NaN samples in used fields, sort, drop duplicate stamps; see the module docstring for the rules."""
    t_ns, values = signal.t_ns, signal.values
    used = [f for f in used_fields(layout).get(role, ()) if f in signal.fields]
    if used:
        bad = np.zeros(len(t_ns), dtype=bool)
        counts = []
        for name in used:
            nan = ~np.isfinite(values[:, signal.fields.index(name)])
            bad |= nan
            if nan.any():
                counts.append(f"{name}: {int(nan.sum())}")
        if bad.any():
            warn(f"{where}: dropped {int(bad.sum())} of {len(t_ns)} samples with NaN/inf ({', '.join(counts)})")
            t_ns, values = t_ns[~bad], values[~bad]
        plausible = plausible_ranges(layout)
        outside = np.zeros(len(t_ns), dtype=bool)
        counts = []
        for name in used:
            if name not in plausible:
                continue
            low, high = plausible[name]
            column = values[:, signal.fields.index(name)]
            out = (column < low) | (column > high)
            outside |= out
            if out.any():
                worst = column[out][np.argmax(np.abs(column[out]))]
                counts.append(f"{name}: {int(out.sum())}, e.g. {worst:g} outside [{low:g}, {high:g}]")
        if outside.any():
            warn(f"{where}: dropped {int(outside.sum())} of {len(t_ns)} samples with implausible values "
                 f"({'; '.join(counts)}): corrupt samples, or wrong units in the config?")
            t_ns, values = t_ns[~outside], values[~outside]
    steps = np.diff(t_ns)
    if len(steps) and steps.min() < 0:
        k = int(np.argmin(steps))
        back = -int(steps[k])
        if back > dt * NS_PER_S:
            raise BagError(f"{where}: time goes back {back / NS_PER_S:.3f} s at "
                           f"t={(t_ns[k] - t_ref_ns) / NS_PER_S:.3f} s "
                           f"(stamp {int(t_ns[k + 1])} ns after {int(t_ns[k])} ns), more than the step {dt:g} s")
        warn(f"{where}: {int((steps < 0).sum())} samples out of order (at most {back / NS_PER_S:.3f} s); sorted")
    order = np.argsort(t_ns, kind="stable")
    t_ns, values = t_ns[order], values[order]
    repeat = np.concatenate([[False], np.diff(t_ns) == 0])
    if repeat.any():
        equal = (values[1:] == values[:-1]) | (np.isnan(values[1:]) & np.isnan(values[:-1]))  # NaN == NaN here
        same = repeat & np.concatenate([[False], np.all(equal, axis=1)])
        exact, differing = int(same.sum()), int((repeat & ~same).sum())
        detail = f"{exact} exact duplicates" + (f", {differing} with other values (kept the first)" if differing
                                                else "")
        warn(f"{where}: dropped {int(repeat.sum())} samples with a repeated stamp ({detail})")
        t_ns, values = t_ns[~repeat], values[~repeat]
    return Signal(t_ns, values, signal.fields)


def gap_cuts(signals: Mapping[str, Signal], dt: float, *, where: str, topic_of: Mapping[str, str],
             t_ref_ns: int, warn: Warn, layout: ActuatorLayout = DEFAULT_LAYOUT) -> list[tuple[int, int]]:
    """Spans [start_ns, end_ns] of the required signals without a gap longer than dt (one warning per gap)."""
    required = required_roles(layout)
    start = max(int(signals[r].t_ns[0]) for r in required)
    end = min(int(signals[r].t_ns[-1]) for r in required)
    holes: list[tuple[int, int]] = []
    for role in required:
        t = signals[role].t_ns
        for k in np.flatnonzero(np.diff(t) > dt * NS_PER_S + 1):
            a, b = int(t[k]), int(t[k + 1])
            if b > start and a < end:
                warn(f"{where}: topic {topic_of[role]!r} has a {(b - a) / NS_PER_S:.2f} s gap at "
                     f"t={(a - t_ref_ns) / NS_PER_S:.2f} s "
                     f"(longer than the step {dt:g} s); cutting the recording there")
                holes.append((a, b))
    spans, cursor = [], start
    for a, b in sorted(holes):
        if a > cursor:
            spans.append((cursor, a))
        cursor = max(cursor, b)
    if cursor < end:
        spans.append((cursor, end))
    return spans


def _slice_signals(signals: Mapping[str, Signal], start_ns: int, end_ns: int) -> dict[str, Signal]:
    out = {}
    for role, s in signals.items():
        keep = (s.t_ns >= start_ns) & (s.t_ns <= end_ns)
        out[role] = Signal(s.t_ns[keep], s.values[keep], s.fields)
    return out


# ------------------------------------------------------------------ manoeuvres within a long recording


def steady_cuts(controls: np.ndarray, dt: float, *, settle_s: float = 30.0, lead_s: float = 10.0,
                rudder_tol_rad: float = math.radians(1.0), rpm_tol: float = 15.0) -> list[int]:
    """Step indices where a new manoeuvre starts, from the (T, 2) [delta rad, rpm] controls at step dt.

    The rule: controls are *held* while rudder and rpm stay within rudder_tol_rad / rpm_tol of their value
    when the hold began; any larger change starts a new hold. A change that ends a hold of at least settle_s
    (the vessel has settled, so whatever came before is over) starts a new manoeuvre; the cut is placed
    lead_s before that change, inside the hold, so every manoeuvre begins in a steady state. Zig-zags,
    random steps and spirals change more often than settle_s and stay whole; a turning circle held for
    minutes stays whole, and the return to straight running after it starts the next manoeuvre.
    """
    lead = int(round(lead_s / dt))
    settle = settle_s / dt
    cuts: list[int] = []
    anchor = 0
    for k in range(1, len(controls)):
        moved = (abs(controls[k, 0] - controls[anchor, 0]) > rudder_tol_rad
                 or abs(controls[k, 1] - controls[anchor, 1]) > rpm_tol)
        if not moved:
            continue
        cut = k - lead
        if k - anchor >= settle and cut > (cuts[-1] if cuts else 0):
            cuts.append(cut)
        anchor = k
    return cuts


def slice_recording(rec: Recording, start: int, stop: int, name: str) -> Recording:
    """Steps [start, stop) of a Recording as a Recording of its own (time re-based at its first step)."""
    dt_ns = int(round(rec.dt * NS_PER_S))
    n = stop - start
    return dataclasses.replace(
        rec, name=name, t0_ns=rec.t0_ns + start * dt_ns, t_s=(np.arange(n, dtype=np.int64) * dt_ns) / NS_PER_S,
        nu=rec.nu[start:stop], psi=rec.psi[start:stop], controls=rec.controls[start:stop],
        position=rec.position[start:stop], truth=None if rec.truth is None else rec.truth[start:stop],
    )


# ------------------------------------------------------------------ the whole stage


def _first_fix(gnss: Signal | None) -> tuple[float, float] | None:
    """The bag's first GNSS fix as the position datum, so every piece of a bag shares one plane."""
    if gnss is None or len(gnss) == 0:
        return None
    return float(gnss.column("lat")[0]), float(gnss.column("lon")[0])


def _long_enough(rec: Recording, min_duration_s: float, horizon_s: float | None, warn: Warn) -> bool:
    if rec.duration_s + 1e-9 < min_duration_s:
        warn(f"{rec.source}: {rec.name} lasts {rec.duration_s:.1f} s, shorter than {min_duration_s:g} s; skipped")
        return False
    needed = None if horizon_s is None else whole_steps(horizon_s, rec.dt, "--horizon", minimum=0) + 1
    if needed is not None and len(rec) < needed:
        warn(f"{rec.source}: {rec.name} has {len(rec)} steps, too few for the {horizon_s:g} s horizon "
             f"({needed} steps); skipped")
        return False
    return True


def _check_recorded_layout(path: Path, vessel: str | None, layout: ActuatorLayout) -> None:
    """A bag that names its vessel (custom_data `vessel`, written by `replay simulate`) is read with that vessel's
    actuator layout: BagError naming both otherwise. A vessel that is no preset here is not checked."""
    if not vessel:
        return
    try:
        recorded = load_vessel(vessel).actuator_layout
    except ConfigError:
        return
    if recorded.name != layout.name:
        raise BagError(f"{path}: recorded on vessel {vessel} ({recorded.name} {list(recorded.control_names)}) but read "
                       f"as {layout.name} {list(layout.control_names)}: read it with the vessel of the bag")


def recordings_from_bag(source: BagSource, specs: Sequence[TopicSpec], dt: float, *, segment: str = "bag",
                        min_duration_s: float = 10.0, horizon_s: float | None = None,
                        warn: Warn = warn_stderr, layout: str = DEFAULT_LAYOUT.name,
                        vessel_name: str = "") -> list[Recording]:
    """The Recordings of one bag (several when it has gaps or, with segment="steady", several manoeuvres).

    layout: the actuator layout's name (physics/actuators.py): which roles carry the controls; vessel_name: the
    vessel it is read as (load_recordings: a bag that names it is not checked against its preset).
    """
    if segment not in SEGMENTS:
        raise DatasetError(f"unknown segment mode {segment!r}; use one of {list(SEGMENTS)}")
    actuators = actuator_layout(layout)
    required = required_roles(actuators)
    path = source.path
    metadata = bag_metadata(path)
    if metadata is not None:
        recorded = metadata[1].get("vessel")
        if not (vessel_name and recorded == vessel_name):  # recorded on the vessel it is read as
            _check_recorded_layout(path, recorded, actuators)
    chosen = _present_specs(path, None if metadata is None else metadata[0], specs, warn, actuators)
    raw = dict(zip((spec.role for spec in chosen), read_signals(path, chosen)))  # role -> Signal (topics may be shared)
    t_ref = min((int(s.t_ns[0]) for s in raw.values() if len(s)), default=0)
    topic_of = {spec.role: spec.topic for spec in chosen}
    signals = {}
    for spec in chosen:
        cleaned = clean_signal(raw[spec.role], where=f"{path}: topic {spec.topic!r}", role=spec.role, dt=dt,
                               t_ref_ns=t_ref, warn=warn, layout=actuators)
        if len(cleaned) == 0:
            if spec.role in required:
                raise BagError(f"{path}: topic {spec.topic!r} (role {spec.role}) has no usable samples")
            continue
        signals[spec.role] = cleaned
    spans = gap_cuts(signals, dt, where=str(path), topic_of=topic_of, t_ref_ns=t_ref, warn=warn, layout=actuators)
    datum = parse_datum(metadata[1].get("datum", "")) if metadata else None
    datum = datum or _first_fix(signals.get("gnss"))
    pieces: list[Recording] = []
    for k, (a, b) in enumerate(spans, start=1):
        name = source.name if len(spans) == 1 else f"{source.name}#{k}"
        if (b - a) / NS_PER_S < max(min_duration_s, dt):
            warn(f"{path}: piece {name} from t={(a - t_ref) / NS_PER_S:.2f} s lasts {(b - a) / NS_PER_S:.2f} s, "
                 f"shorter than {min_duration_s:g} s; skipped")
            continue
        try:
            pieces.append(recording_from_signals(_slice_signals(signals, a, b), dt, name=name, source=str(path),
                                                 datum=datum, layout=actuators))
        except RecordingError as err:
            warn(f"{path}: piece {name} skipped: {err}")
    if segment == "steady":
        pieces = _steady_segments(pieces, source.name)
    return [rec for rec in pieces if _long_enough(rec, min_duration_s, horizon_s, warn)]


def _steady_segments(pieces: Sequence[Recording], bag_name: str) -> list[Recording]:
    """Manoeuvres NAME@1, NAME@2, ... numbered through the bag (a bag of one manoeuvre keeps its name)."""
    bounds = [(rec, [0, *steady_cuts(rec.controls, rec.dt), len(rec)]) for rec in pieces]
    if len(pieces) == 1 and len(bounds[0][1]) == 2:
        return [dataclasses.replace(pieces[0], name=bag_name)]
    out: list[Recording] = []
    for rec, cuts in bounds:
        for start, stop in zip(cuts[:-1], cuts[1:]):
            out.append(slice_recording(rec, start, stop, f"{bag_name}@{len(out) + 1}"))
    return out


def _bag_job(source: BagSource, specs: Sequence[TopicSpec], dt: float,
             options: Mapping) -> tuple[list[Recording], list[str]]:
    """One bag in a worker process: its Recordings and its warnings (replayed in bag order by the parent)."""
    messages: list[str] = []
    return recordings_from_bag(source, specs, dt, warn=messages.append, **options), messages


def _ignore_interrupts() -> None:
    """In a worker: Ctrl-C reaches the whole process group, but only the parent answers it (one line, exit 130);
    a worker finishes its bag instead of printing a traceback of its own."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _map_bags(sources: Sequence[BagSource], specs: Sequence[TopicSpec], dt: float, options: Mapping, jobs: int):
    """(source, recordings, warnings) per bag, in order; bags are independent, so `jobs` processes read them.

    Decoding is CPU-bound Python (the GIL rules out threads); fork shares the imported modules, so a worker
    costs milliseconds. Results do not depend on `jobs`.
    """
    if jobs <= 1 or len(sources) <= 1:
        for source in sources:
            yield source, *_bag_job(source, specs, dt, options)
        return
    specs = [dataclasses.replace(s, options=dict(s.options)) for s in specs]  # a mappingproxy does not pickle
    methods = multiprocessing.get_all_start_methods()
    context = multiprocessing.get_context("fork" if "fork" in methods else "spawn")
    with ProcessPoolExecutor(max_workers=min(jobs, len(sources)), mp_context=context,
                             initializer=_ignore_interrupts) as pool:
        work = [pool.submit(_bag_job, source, specs, dt, options) for source in sources]
        try:
            for source, future in zip(sources, work):
                yield source, *future.result()
        finally:
            for future in work:
                future.cancel()


def default_jobs(bags: int) -> int:
    """Worker processes for `bags` bags: one per CPU this process may use, at most one per bag."""
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return max(1, min(cpus, bags))


def load_recordings(bag_paths: Iterable[str | Path], dt: float, *, config_path: str | Path | None = None,
                    topics: Mapping[str, str] | None = None, pieces: Pieces = Pieces(), jobs: int = 1,
                    warn: Warn = warn_stderr, progress: Callable[[str], None] | None = None,
                    layout: ActuatorLayout = DEFAULT_LAYOUT, vessel_name: str = "") -> list[Recording]:
    """Recordings of the bags (or directories of bags) in `bag_paths`, resampled to step dt, the pieces kept by
    `pieces` (Pieces: how a bag is cut, the shortest piece kept, the calm twins, the scale).

    vessel_name: the vessel the bags are read as (with its `layout`): a bag that names it (custom_data vessel) is
    read so, unchecked; a bag that names another vessel preset is checked against that preset's layout
    (BagError naming both when they differ); "": every bag that names a preset is checked.

    pieces.scale: Froude scaling (data/recording.froude_scaled) of bags recorded on a hull `scale` times as long as the
    model's (`--scale LAMBDA` of evaluate, identify, diagnose; 1: none): the bags are read at the step, horizon and
    minimum duration that become dt, horizon_s and min_duration_s at the model's scale, then scaled.

    topics: role -> topic name overrides of the config's input topics. jobs: processes reading bags in
    parallel (0: default_jobs). layout: the vessel's actuator layout (which roles carry the controls). May return []
    when every piece was skipped (each skip has its warning);
    errors in the input raise BagError naming the bag and topic.
    """
    if not dt > 0.0 or not math.isfinite(dt):
        raise DatasetError(f"step dt={dt} s must be a positive number")
    FLOAT_RANGES["dt"].check("dt", dt, "the resampling step")  # 1e-300 s would ask for an astronomical grid
    scale = pieces.scale
    if not (math.isfinite(scale) and scale > 0.0):
        raise DatasetError(f"--scale {scale!r}: expected a finite number > 0 (L_bags / L_model)")
    if scale != 1.0:  # the bags' own clock: every time in it is sqrt(scale) times the model's
        root = math.sqrt(scale)
        if progress is not None:
            progress(f"Froude scale {scale:g}: the bags' vessel is {scale:g} x the model's; read at {dt * root:.4g} s "
                     f"of their clock (= {dt:g} s at the model's scale), lengths / {scale:g}, speeds and times / "
                     f"{root:.4g}, yaw rates and rpm x {root:.4g}")
        at_their_scale = dataclasses.replace(pieces, min_duration_s=pieces.min_duration_s * root, scale=1.0,
                                             horizon_s=None if pieces.horizon_s is None else pieces.horizon_s * root)
        found = load_recordings(bag_paths, dt * root, config_path=config_path, topics=topics, pieces=at_their_scale,
                                jobs=jobs, warn=warn, progress=progress, layout=layout, vessel_name=vessel_name)
        return [dataclasses.replace(froude_scaled(rec, scale), dt=dt) for rec in found]
    if pieces.segment not in SEGMENTS:
        raise DatasetError(f"unknown segment mode {pieces.segment!r}; use one of {list(SEGMENTS)}")
    specs = topic_specs(config_path, topics, layout)
    sources = find_bags(bag_paths, include_calm=pieces.include_calm)
    options = {"segment": pieces.segment, "min_duration_s": pieces.min_duration_s, "horizon_s": pieces.horizon_s,
               "layout": layout.name, "vessel_name": vessel_name}
    recordings: list[Recording] = []
    jobs = default_jobs(len(sources)) if jobs == 0 else jobs
    for i, (source, found, messages) in enumerate(_map_bags(sources, specs, dt, options, jobs), start=1):
        for message in messages:
            warn(message)
        recordings += found
        if progress is not None:
            seconds = sum(r.duration_s for r in found)
            progress(f"[{i}/{len(sources)}] {source.path}: {len(found)} recording(s), {seconds:.0f} s")
    return recordings
