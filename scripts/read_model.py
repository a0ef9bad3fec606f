#!/usr/bin/env python3
"""Reads dynamic_occupancy_grid model files (docs/model_format.md) with numpy only.

As a library:

    from read_model import load_model, dense_field
    model = load_model("map.dogm")
    model.config["resolution_m"], model.clock_origin_s, model.last_applied_step
    model.learner                                         # "kinds" or "cell_em"
    model.config["kinds"], model.kind_sums                # the kinds of cells: configuration, pair sums,
    model.kind_transitions                                # and the transitions they learned
    model.x, model.y, model.p_occ, model.learner_state    # one entry per observed cell
    model.kind_posterior    # learner "kinds": p(kind, state) per cell, N x 5 x 2 (else None)
    model.em_stats          # learner "cell_em": online EM statistics, N x 8 (else None)
    grid, window = dense_field(model, "p_occ")            # 2D, row = y, NaN = unobserved

As a command:

    read_model.py MODEL        prints a summary (cells, bounds, time, mean transitions)

Errors in the file (wrong magic, other version, truncated, checksum mismatch, bad values)
raise ModelFormatError (a ValueError) with a message saying what is wrong; the command then
prints it and exits with status 1.
"""

import argparse
import math
import struct
import sys
import zlib

import numpy as np

MAGIC = b"DOGMODEL"
FORMAT_VERSION = 3  # the version the C++ writes; versions 1 and 2 are read too
KIND_COUNT = 5  # core/cell/cell_kinds.h kKindCount
GAP_BINS = 124  # core/cell/cell_kinds.h kGapBins: distance bins of the kinds' pairs (gap_bin)
LEARNER_STATE_SIZE = 10  # core/grid/cell_grid.h kLearnerStateSize: floats of a cell's learner state
LEARNERS = ("cell_em", "kinds")  # the learner byte's values (TransitionLearner)
# The kinds' summaries and countings files may hold (choices removed after a9ed7d5: checked
# and ignored, as the core's reader does).
KIND_SUMMARIES = ("geometric_mean", "mean", "most_probable")
KIND_COUNTINGS = ("posterior", "most_probable")

# Version 1 header: magic, version, MapperConfig in its order, time, cell count (197 bytes).
_HEADER_V1 = struct.Struct(
    "<8sI"          # magic, format version
    "dddddd"        # resolution_m, time_step_s, p_hit_given_occ, p_hit_given_free, prior p_of, prior p_fo
    "B"             # learn_transitions
    "dddd"          # online_em: prior_weight, learning_rate_floor, p_min, p_max
    "BI"            # online_em: symmetric, min_observed_steps
    "d"             # initial_p_occ
    "dd"            # static_clamp: min_log_odds, max_log_odds
    "d"             # max_free_range_m
    "dd"            # origin_x_m, origin_y_m
    "B"             # fixed_bounds
    "ddd"           # width_m, height_m, max_map_size_m
    "Bd"            # clock origin present, clock origin (s)
    "Bq"            # last applied step present, last applied step
    "Q"             # cell count
)
# Version 2 inserts the learners' options and the sensor model's sums before the cell count.
_LEARNERS_V2 = struct.Struct(
    "<Bd"           # learn_prior, prior_population_weight (removed after a9ed7d5: checked and ignored)
    "BddI"          # online_em: schedule (0 harmonic, 1 robbins_monro), step_size_exponent, step_size_offset, averaging_start
                    # (options removed after a9ed7d5: checked and ignored)
    "Bdd"           # learn_sensor_model, sensor_model_prior_weight, sensor_model_p_min
    "dddd"          # sensor model sums: trials occ, trials free, hits occ, hits free
)
# Version 3 inserts the transition learner and the kinds of cells before the cell count: their
# configuration,
_KINDS_CONFIG_V3 = struct.Struct(
    "<BB"           # learner (0 cell_em, 1 kinds), kind count
    + "dd" * KIND_COUNT  # per kind: initial p_occ_given_free, p_free_given_occ
    + "d" * KIND_COUNT   # initial weights
    + "dddd"        # transition_prior_weight, weight_prior_cells, switch_probability, forgetting
    "BBB"           # summary, counting, learn_from_gaps (removed after a9ed7d5: checked and ignored)
    "H"             # number of distance bins (GAP_BINS)
)
# then the sums (float64): pairs [kind][bin][2 i + j] (i the state then, j now; 0 = occ,
# 1 = free), membership [kind], cells; then the kinds' learned transitions [kind] x
# (p_occ_given_free, p_free_given_occ).
_KIND_PAIRS = KIND_COUNT * GAP_BINS * 4
_KIND_DOUBLES = _KIND_PAIRS + KIND_COUNT + 1 + 2 * KIND_COUNT
_KINDS_V3_SIZE = _KINDS_CONFIG_V3.size + 8 * _KIND_DOUBLES
CHECKSUM_SIZE = 4
HEADER_SIZES = {1: _HEADER_V1.size, 2: _HEADER_V1.size + _LEARNERS_V2.size,
                3: _HEADER_V1.size + _LEARNERS_V2.size + _KINDS_V3_SIZE}

# One observed cell (version 1: 62 bytes, packed, 8 learner floats; version 2 adds last_hits,
# last_misses; version 3 holds LEARNER_STATE_SIZE learner floats).
_CELL_BEFORE_LEARNER = [
    ("x", "<i4"),
    ("y", "<i4"),
    ("p_occ", "<f4"),
    ("last_step", "<i4"),
    ("log_odds", "<f4"),
    ("p_occ_given_free", "<f4"),
    ("p_free_given_occ", "<f4"),
]
CELL_DTYPE_V1 = np.dtype(_CELL_BEFORE_LEARNER + [("learner_state", "<f4", (8,)), ("observed_steps", "<u2")])
CELL_DTYPE_V2 = np.dtype(CELL_DTYPE_V1.descr + [("last_hits", "u1"), ("last_misses", "u1")])
CELL_DTYPE_V3 = np.dtype(_CELL_BEFORE_LEARNER + [("learner_state", "<f4", (LEARNER_STATE_SIZE,)),
                                                 ("observed_steps", "<u2"), ("last_hits", "u1"),
                                                 ("last_misses", "u1")])
CELL_DTYPES = {1: CELL_DTYPE_V1, 2: CELL_DTYPE_V2, 3: CELL_DTYPE_V3}
CELL_FIELDS = CELL_DTYPE_V3.names
# The learner's state read as what it is: arrays of each cell (None when the model's learner
# is the other one), with the shape per cell.
LEARNER_VIEWS = {"em_stats": (8,), "kind_posterior": (KIND_COUNT, 2)}

assert (HEADER_SIZES == {1: 197, 2: 276, 3: 20403} and _KINDS_CONFIG_V3.size == 159 and _KINDS_V3_SIZE == 20127
        and CELL_DTYPE_V1.itemsize == 62
        and CELL_DTYPE_V2.itemsize == 64 and CELL_DTYPE_V3.itemsize == 72), "the layout of docs/model_format.md"


_exp2 = getattr(math, "exp2", lambda x: 2.0 ** x)  # math.exp2: Python 3.11


class ModelFormatError(ValueError):
    """The bytes are not an intact model file of a version from 1 to FORMAT_VERSION."""


def default_kinds():
    """KindsConfig's defaults (core/cell/cell_kinds.h), which version 1 and 2 files get."""
    return {
        "initial_transitions": [{"p_occ_given_free": rate, "p_free_given_occ": rate}
                                for rate in (1e-4, 2e-3, 0.01, 0.05, 0.25)],
        "initial_weights": [0.8, 0.05, 0.05, 0.05, 0.05],
        "transition_prior_weight": 100.0,
        "weight_prior_cells": 100.0,
        "switch_probability": 1e-4,
        "forgetting": 1e-3,
    }


def gap_bin(steps):
    """The distance bin (0 .. GAP_BINS - 1) of a pair `steps` >= 1 steps apart, as
    core/cell/cell_kinds.cpp gapBin: 1 to 16 steps one bin each, then four bins per octave."""
    if steps <= 16:
        return max(int(steps), 1) - 1
    return min(16 + math.floor(4.0 * math.log2(float(steps) / 16.0)), GAP_BINS - 1)


def gap_bin_steps(bin_index):
    """The distance in steps that bin `bin_index` stands for (cell_kinds.cpp gapBinSteps):
    its own for the first 16, else the geometric middle of the bin's distances."""
    if bin_index < 16:
        return bin_index + 1.0
    return 16.0 * _exp2((bin_index - 16 + 0.5) / 4.0)


class Model:
    """A model file's contents.

    format_version: the file's format version (1 to FORMAT_VERSION).
    config: dict with MapperConfig's fields and names (prior_transitions, online_em,
        static_clamp and kinds are nested dicts; kinds' initial_transitions and
        initial_weights are lists, one entry per kind); config["learner"] is learner.
    learner: how the cells learn their transitions, "kinds" (kinds of cells, the default)
        or "cell_em" (each cell's own online EM; every version 1 and 2 file).
    kind_sums: what the kinds are learned from (CellKinds::Sums): "pairs" (float64,
        KIND_COUNT x GAP_BINS x 2 x 2, [kind][bin][then][now]: expected pairs of a cell's
        states at two consecutive observations, then and now (0 = occ, 1 = free), in the
        distance bin of the steps between them (gap_bin, gap_bin_steps)), "membership"
        (float64, KIND_COUNT, sum over cells of p(kind)), "cells" (float); zeros in version
        1 and 2 files.
    kind_transitions: the transitions each kind learned from those sums, a list of
        KIND_COUNT dicts (p_occ_given_free, p_free_given_occ), per step; version 1 and 2
        files: the initial ones within the bounds [max(online_em.p_min, 1e-6),
        min(online_em.p_max, 0.5)], as the C++ starts them.
    clock_origin_s: sensor time of the start of step 0, or None (no scan seen).
    last_applied_step: the last step applied to the cells, or None.
    One entry per observed cell, by row (y) then column (x):
    x, y (int32), p_occ, log_odds, p_occ_given_free, p_free_given_occ (float32),
    last_step (int32), observed_steps (uint16), last_hits, last_misses (uint8, the evidence
    of the cell's last step; 0 in version 1 files), and the learner's state:
    learner_state (float32, N x LEARNER_STATE_SIZE, as stored; the last two 0 in version 1
        and 2 files), read as what it is by the learner:
    em_stats (learner "cell_em"; else None): float32, N x 8, online EM statistics S(i, j, m)
        at (i * 2 + j) * 2 + m, 0 = occ, 1 = free;
    kind_posterior (learner "kinds"; else None): float32, N x KIND_COUNT x 2, the cell's
        posterior p(kind = k, state = s), s 0 = occ, 1 = free (kind_posterior.sum(axis=2) is
        p(kind)).
    sensor_model_stats: dict of the online sensor model's sums (trials_occ, trials_free,
        hits_occ, hits_free; zeros in version 1 files).
    """

    def __init__(self, format_version, config, clock_origin_s, last_applied_step, cells, sensor_model_stats,
                 kind_sums, kind_transitions):
        self.format_version = format_version
        self.config = config
        self.learner = config["learner"]
        self.kind_sums = kind_sums
        self.kind_transitions = kind_transitions
        self.sensor_model_stats = sensor_model_stats
        self.clock_origin_s = clock_origin_s
        self.last_applied_step = last_applied_step
        for name in CELL_FIELDS:
            if name == "learner_state":
                stored = cells[name]
                state = np.zeros((len(cells), LEARNER_STATE_SIZE), dtype=np.float32)
                state[:, :stored.shape[1]] = stored
                self.learner_state = state
            elif name in cells.dtype.names:
                setattr(self, name, np.ascontiguousarray(cells[name]))
            else:
                setattr(self, name, np.zeros(len(cells), dtype=CELL_DTYPE_V3[name]))
        self.em_stats = np.ascontiguousarray(self.learner_state[:, :8]) if self.learner == "cell_em" else None
        self.kind_posterior = (self.learner_state.reshape(len(cells), KIND_COUNT, 2) if self.learner == "kinds"
                               else None)

    @property
    def cell_count(self):
        return int(self.x.size)

    def __getitem__(self, name):
        """model["p_occ"] etc. as well as model.p_occ."""
        return getattr(self, name)

    def bounds(self):
        """(min_x, min_y, max_x, max_y) of the observed cells, inclusive; None if none."""
        if self.cell_count == 0:
            return None
        return (int(self.x.min()), int(self.y.min()), int(self.x.max()), int(self.y.max()))


def _flag(value, field):
    if value not in (0, 1):
        raise ModelFormatError(f"invalid model file: {field} is {value}, must be 0 or 1")
    return value == 1


def parse_model(data):
    """Model of the bytes `data` (bytes, bytearray or memoryview)."""
    data = memoryview(data).cast("B")
    size = len(data)
    if bytes(data[:len(MAGIC)]) != MAGIC[:min(size, len(MAGIC))]:
        raise ModelFormatError("not a dynamic_occupancy_grid model file (no DOGMODEL magic at its start)")
    minimum = HEADER_SIZES[1] + CHECKSUM_SIZE
    if size < len(MAGIC) + 4:
        raise ModelFormatError(f"truncated model file: expected at least {minimum} bytes, {size} available")
    (version,) = struct.unpack_from("<I", data, len(MAGIC))
    if version not in HEADER_SIZES:
        raise ModelFormatError(f"model format version {version}, this reader reads versions 1 to {FORMAT_VERSION}")
    header_size = HEADER_SIZES[version]
    cell_dtype = CELL_DTYPES[version]
    minimum = header_size + CHECKSUM_SIZE
    if size < minimum:
        raise ModelFormatError(f"truncated model file: expected at least {minimum} bytes, {size} available")
    fields = _HEADER_V1.unpack_from(data, 0)[:-1]  # without version 1's cell count
    (count,) = struct.unpack_from("<Q", data, header_size - 8)
    expected = minimum + count * cell_dtype.itemsize  # Python integers: no overflow
    if expected > size:
        raise ModelFormatError(
            f"truncated model file: expected {expected} bytes for {count} cells, {size} available")
    if expected < size:
        raise ModelFormatError(
            f"invalid model file: {size - expected} trailing bytes after the checksum "
            f"({expected} bytes expected for {count} cells)")
    (stored,) = struct.unpack_from("<I", data, size - CHECKSUM_SIZE)
    computed = zlib.crc32(data[:size - CHECKSUM_SIZE]) & 0xFFFFFFFF
    if stored != computed:
        raise ModelFormatError(
            f"corrupt model file: checksum mismatch (stored {stored:08x}, computed {computed:08x})")

    (_, _, resolution_m, time_step_s, p_hit_given_occ, p_hit_given_free, prior_of, prior_fo, learn,
     prior_weight, learning_rate_floor, p_min, p_max, symmetric, min_observed_steps, initial_p_occ,
     min_log_odds, max_log_odds, max_free_range_m, origin_x_m, origin_y_m, fixed, width_m, height_m,
     max_map_size_m, has_origin, origin_s, has_last, last_step) = fields
    config = {
        "resolution_m": resolution_m,
        "time_step_s": time_step_s,
        "p_hit_given_occ": p_hit_given_occ,
        "p_hit_given_free": p_hit_given_free,
        "prior_transitions": {"p_occ_given_free": prior_of, "p_free_given_occ": prior_fo},
        "learn_transitions": _flag(learn, "learn_transitions"),
        "online_em": {
            "prior_weight": prior_weight,
            "learning_rate_floor": learning_rate_floor,
            "p_min": p_min,
            "p_max": p_max,
            "symmetric": _flag(symmetric, "online_em.symmetric"),
            "min_observed_steps": min_observed_steps,
        },
        "initial_p_occ": initial_p_occ,
        "static_clamp": {"min_log_odds": min_log_odds, "max_log_odds": max_log_odds},
        "max_free_range_m": max_free_range_m,
        "origin_x_m": origin_x_m,
        "origin_y_m": origin_y_m,
        "fixed_bounds": _flag(fixed, "fixed_bounds"),
        "width_m": width_m,
        "height_m": height_m,
        "max_map_size_m": max_map_size_m,
        # Version 1 files: MapperConfig's defaults.
        "learn_sensor_model": False,
        "sensor_model_prior_weight": 1000.0,
        "sensor_model_p_min": 0.01,
    }
    sensor_model_stats = {"trials_occ": 0.0, "trials_free": 0.0, "hits_occ": 0.0, "hits_free": 0.0}
    if version >= 2:
        # The empirical-Bayes prior and the online EM's schedule, exponent, offset and averaging
        # start (options removed after a9ed7d5) are checked and ignored, as the core's reader does.
        (learn_prior, _population_weight, schedule, _exponent, _offset, _averaging_start, learn_sensor,
         sensor_weight, sensor_p_min, trials_occ, trials_free, hits_occ, hits_free) = _LEARNERS_V2.unpack_from(
             data, HEADER_SIZES[1] - 8)
        if schedule not in (0, 1):
            raise ModelFormatError(f"invalid model file: online_em.schedule is {schedule}, must be 0 (harmonic) or "
                                   "1 (robbins_monro)")
        _flag(learn_prior, "learn_prior")
        config.update({"learn_sensor_model": _flag(learn_sensor, "learn_sensor_model"),
                       "sensor_model_prior_weight": sensor_weight, "sensor_model_p_min": sensor_p_min})
        sensor_model_stats = {"trials_occ": trials_occ, "trials_free": trials_free, "hits_occ": hits_occ,
                              "hits_free": hits_free}
    # Versions 1 and 2 were written by each cell's online EM; their cells hold its statistics.
    config["learner"] = "cell_em"
    config["kinds"] = default_kinds()
    kind_sums = {"pairs": np.zeros((KIND_COUNT, GAP_BINS, 2, 2)), "membership": np.zeros(KIND_COUNT), "cells": 0.0}
    # The bounds of the kinds' transitions (core/grid/mapper.cpp builds CellKinds with these).
    low = max(p_min, 1e-6)
    high = min(p_max, 0.5)
    kind_transitions = [{name: min(max(rate, low), high) for name, rate in start.items()}
                        for start in config["kinds"]["initial_transitions"]]
    if version >= 3:
        offset = HEADER_SIZES[2] - 8
        kinds = _KINDS_CONFIG_V3.unpack_from(data, offset)
        learner, kind_count = kinds[:2]
        if learner >= len(LEARNERS):
            raise ModelFormatError(f"invalid model file: learner is {learner}, must be 0 (cell_em) or 1 (kinds)")
        if kind_count != KIND_COUNT:
            raise ModelFormatError(f"model file with {kind_count} kinds of cells, this reader has {KIND_COUNT}")
        rest = list(kinds[2:])
        starts, rest = rest[:2 * KIND_COUNT], rest[2 * KIND_COUNT:]
        weights, rest = rest[:KIND_COUNT], rest[KIND_COUNT:]
        (transition_prior_weight, weight_prior_cells, switch_probability, forgetting, summary_index,
         counting_index, learn_from_gaps, bins) = rest
        if summary_index >= len(KIND_SUMMARIES):
            raise ModelFormatError(f"invalid model file: kinds.summary is {summary_index}, must be 0 (geometric_mean), "
                                   "1 (mean) or 2 (most_probable)")
        if counting_index >= len(KIND_COUNTINGS):
            raise ModelFormatError(f"invalid model file: kinds.counting is {counting_index}, must be 0 (posterior) or "
                                   "1 (most_probable)")
        _flag(learn_from_gaps, "kinds.learn_from_gaps")
        if bins != GAP_BINS:
            raise ModelFormatError(f"model file with {bins} distance bins of the kinds' pairs, this reader has "
                                   f"{GAP_BINS}")
        values = np.frombuffer(data, dtype="<f8", count=_KIND_DOUBLES,
                               offset=offset + _KINDS_CONFIG_V3.size).astype(np.float64)
        sums, learned = values[:_KIND_PAIRS + KIND_COUNT + 1], values[_KIND_PAIRS + KIND_COUNT + 1:]
        # As CellKinds::restore: sums finite and >= 0, learned transitions within the bounds.
        if not (np.all(np.isfinite(sums)) and np.all(sums >= 0.0) and np.all(learned >= low)
                and np.all(learned <= high)):
            raise ModelFormatError("invalid kinds of cells in model file: kinds: saved sums must be finite and >= 0, "
                                   "transitions within the bounds")
        config["learner"] = LEARNERS[learner]
        config["kinds"] = {
            "initial_transitions": [{"p_occ_given_free": starts[2 * k], "p_free_given_occ": starts[2 * k + 1]}
                                    for k in range(KIND_COUNT)],
            "initial_weights": weights,
            "transition_prior_weight": transition_prior_weight,
            "weight_prior_cells": weight_prior_cells,
            "switch_probability": switch_probability,
            "forgetting": forgetting,
        }
        kind_sums = {"pairs": sums[:_KIND_PAIRS].reshape(KIND_COUNT, GAP_BINS, 2, 2),
                     "membership": sums[_KIND_PAIRS:_KIND_PAIRS + KIND_COUNT], "cells": float(sums[-1])}
        kind_transitions = [{"p_occ_given_free": float(learned[2 * k]), "p_free_given_occ": float(learned[2 * k + 1])}
                            for k in range(KIND_COUNT)]
    has_origin = _flag(has_origin, "clock origin present")
    has_last = _flag(has_last, "last applied step present")
    if not (resolution_m > 0.0 and time_step_s > 0.0):
        raise ModelFormatError("invalid configuration in model file: resolution and time step must be > 0")
    if (not has_origin and struct.pack("<d", origin_s) != bytes(8)) or (not has_last and last_step != 0):
        raise ModelFormatError("invalid model file: an absent time value is not stored as 0")
    if has_last and not has_origin:
        raise ModelFormatError("invalid time in model file: a last applied step needs a clock origin")
    cells = np.frombuffer(data, dtype=cell_dtype, count=count, offset=header_size)
    return Model(version, config, origin_s if has_origin else None, last_step if has_last else None, cells,
                 sensor_model_stats, kind_sums, kind_transitions)


def load_model(path):
    """Model of the file at `path`; OSError if it cannot be read, ModelFormatError (naming
    the file) if it is not an intact model file."""
    with open(path, "rb") as file:
        data = file.read()
    try:
        return parse_model(data)
    except ModelFormatError as error:
        raise ModelFormatError(f"{path}: {error}") from None


def dense_field(model, field, component=None):
    """A field over the bounding box of the observed cells as a 2D float64 array, row = y -
    min_y, column = x - min_x (row 0 is the bottom row, as in nav_msgs/OccupancyGrid), NaN
    where no cell was observed. `field` is a cell field name or a view of the learner's
    state; give `component` for those with several values per cell: "learner_state"
    0..9, "em_stats" 0..7, "kind_posterior" (kind, state). Returns (array, window) with
    window = dict(min_x, min_y, width, height, resolution_m, origin_x_m, origin_y_m) (world
    position of the array's lower-left corner); (empty 0 x 0 array, window with width =
    height = 0) for a model without cells."""
    fields = [name for name in CELL_FIELDS if name not in ("x", "y")] + list(LEARNER_VIEWS)
    if field not in fields:
        raise KeyError(f"no cell field {field!r}; fields: {', '.join(fields)}")
    values = getattr(model, field)
    if values is None:
        raise ValueError(f"a model of learner {model.learner} has no {field}")
    shape = values.shape[1:]
    if shape:
        index = component if isinstance(component, tuple) else (component,)
        valid = all(isinstance(i, (int, np.integer)) and 0 <= i < n for i, n in zip(index, shape))
        if len(index) != len(shape) or not valid:
            wanted = " x ".join(f"0..{n - 1}" for n in shape)
            raise ValueError(f"{field} needs component {wanted}")
        values = values[(slice(None),) + index]
    resolution = model.config["resolution_m"]
    bounds = model.bounds()
    if bounds is None:
        window = dict(min_x=0, min_y=0, width=0, height=0, resolution_m=resolution,
                      origin_x_m=model.config["origin_x_m"], origin_y_m=model.config["origin_y_m"])
        return np.full((0, 0), np.nan), window
    min_x, min_y, max_x, max_y = bounds
    width = max_x - min_x + 1
    height = max_y - min_y + 1
    grid = np.full((height, width), np.nan)
    grid[model.y.astype(np.int64) - min_y, model.x.astype(np.int64) - min_x] = values
    window = dict(min_x=min_x, min_y=min_y, width=width, height=height, resolution_m=resolution,
                  origin_x_m=model.config["origin_x_m"] + min_x * resolution,
                  origin_y_m=model.config["origin_y_m"] + min_y * resolution)
    return grid, window


def summary(model):
    """A few lines about the model, as the command prints them."""
    config = model.config
    lines = []
    prior = config["prior_transitions"]
    lines.append(f"cells observed:     {model.cell_count}")
    bounds = model.bounds()
    resolution = config["resolution_m"]
    if bounds is None:
        lines.append("bounds:             (no cells)")
    else:
        min_x, min_y, max_x, max_y = bounds
        x0 = config["origin_x_m"] + min_x * resolution
        y0 = config["origin_y_m"] + min_y * resolution
        x1 = config["origin_x_m"] + (max_x + 1) * resolution
        y1 = config["origin_y_m"] + (max_y + 1) * resolution
        lines.append(f"bounds (cells):     x {min_x}..{max_x}, y {min_y}..{max_y} "
                     f"({max_x - min_x + 1} x {max_y - min_y + 1})")
        lines.append(f"bounds (m):         x [{x0:.3f}, {x1:.3f}), y [{y0:.3f}, {y1:.3f})")
    lines.append(f"resolution:         {resolution} m")
    fixed = (f"fixed {config['width_m']} x {config['height_m']} m" if config["fixed_bounds"]
             else f"growing, up to {config['max_map_size_m']} m")
    lines.append(f"map:                {fixed}, origin ({config['origin_x_m']}, {config['origin_y_m']}) m")
    lines.append(f"time step:          {config['time_step_s']} s")
    origin = "none" if model.clock_origin_s is None else f"{model.clock_origin_s!r} s"
    last = "none" if model.last_applied_step is None else str(model.last_applied_step)
    lines.append(f"clock origin:       {origin}")
    lines.append(f"last applied step:  {last}")
    lines.append(f"learn transitions:  {'yes' if config['learn_transitions'] else 'no'} "
                 f"(prior p_occ_given_free {prior['p_occ_given_free']}, "
                 f"p_free_given_occ {prior['p_free_given_occ']})")
    lines.append(f"learner:            {model.learner}")
    if model.learner == "kinds":
        cells = model.kind_sums["cells"]
        shares = model.kind_sums["membership"] / cells if cells > 0 else np.zeros(KIND_COUNT)
        lines.append("kinds' shares:      " + " ".join(f"{share:.3g}" for share in shares) + f" (of {cells:.0f} cells)")
        lines.append("kinds' transitions: " + " ".join(f"{t['p_occ_given_free']:.3g}/{t['p_free_given_occ']:.3g}"
                                                     for t in model.kind_transitions)
                     + " (p_occ_given_free/p_free_given_occ per step)")
    if model.cell_count > 0:
        p_of = model.p_occ_given_free.astype(np.float64)
        p_fo = model.p_free_given_occ.astype(np.float64)
        lines.append(f"mean p_occ_given_free: {p_of.mean():.6g} per step")
        lines.append(f"mean p_free_given_occ: {p_fo.mean():.6g} per step")
        lines.append(f"mean p_occ:            {model.p_occ.astype(np.float64).mean():.6g}")
        lines.append(f"mean observed steps:   {model.observed_steps.astype(np.float64).mean():.6g}")
    return "\n".join(lines)


def main(argv=None):
    parser = argparse.ArgumentParser(description="Summary of a dynamic_occupancy_grid model file.")
    parser.add_argument("model", help="model file (saved by saveModel / the save_model service)")
    args = parser.parse_args(argv)
    try:
        model = load_model(args.model)
    except (OSError, ModelFormatError) as error:
        print(f"read_model.py: {error}", file=sys.stderr)
        return 1
    print(f"model file:         {args.model} (format version {model.format_version})")
    print(summary(model))
    return 0


if __name__ == "__main__":
    sys.exit(main())
