"""Public measured manoeuvres -> plain numbers in the marine convention -> rosbag2 with the default topics.

Readers return one `Manoeuvre` per file: SI units, NED earth frame, body FRD, heading psi clockwise
from north (rad, wrapped), eta = [x_n, y_e, psi], nu = [u, v, r], rudder delta positive to starboard
(r > 0), propeller speed in rpm. Everything here is pure except `write_manoeuvre_bag` (one bagio.write_bag)
and `convert` (what `replay convert` does: every file read first, then one bag each).

One module per public format, each with its reader and its record (common.Format: how its files are named, the
licence, the nominal epoch and datum), gathered in formats.FORMATS_BY_NAME; common holds the Manoeuvre record and the
helpers they share, bags the conversion to rosbag2. The names below are the package's public ones.

Formats (see docs/data.md for the evidence behind each convention; every check raises DatasetError naming file, line
and column): hsva, marin (KVLCC2 tank data, SIMMAN 2008), fuzhou (a rudder-steered USV at sea), dalian (a
twin-thruster USV at sea): their modules' docstrings say what each reader reads and checks.
"""
from __future__ import annotations

from usv_predictor.replay.convert.bags import convert, custom_data, summarise, time_ns, to_signals, write_manoeuvre_bag
from usv_predictor.replay.convert.common import (
                                                 CONVERSION_VERSION,
                                                 GRAVITY,
                                                 KNOT,
                                                 KVLCC2_LPP_FULL_M,
                                                 KVLCC2_LPP_MODEL_M,
                                                 MANOEUVRE_KINDS,
                                                 MIN_ROWS,
                                                 Format,
                                                 Manoeuvre,
                                                 ScaleInfo,
                                                 centred_derivative,
)
from usv_predictor.replay.convert.dalian import read_dalian
from usv_predictor.replay.convert.formats import (
                                                 DATUM_DEG,
                                                 EPOCH_NS,
                                                 FORMATS,
                                                 FORMATS_BY_NAME,
                                                 LICENCE,
                                                 READERS,
                                                 UNSUPPORTED_FORMATS,
                                                 detect_format,
                                                 find_sources,
                                                 read_manoeuvres,
)
from usv_predictor.replay.convert.fuzhou import read_fuzhou
from usv_predictor.replay.convert.hsva import HSVA_DT_S, HSVA_LAMBDA, read_hsva
from usv_predictor.replay.convert.marin import MARIN_DT_S, read_marin

__all__ = ["CONVERSION_VERSION", "DATUM_DEG", "EPOCH_NS", "FORMATS", "FORMATS_BY_NAME", "GRAVITY", "HSVA_DT_S",
           "HSVA_LAMBDA", "KNOT", "KVLCC2_LPP_FULL_M", "KVLCC2_LPP_MODEL_M", "LICENCE", "MANOEUVRE_KINDS", "MARIN_DT_S",
           "MIN_ROWS", "READERS", "UNSUPPORTED_FORMATS", "Format", "Manoeuvre", "ScaleInfo", "centred_derivative",
           "convert", "custom_data", "detect_format", "find_sources", "read_dalian", "read_fuzhou", "read_hsva",
           "read_manoeuvres", "read_marin", "summarise", "time_ns", "to_signals", "write_manoeuvre_bag"]
