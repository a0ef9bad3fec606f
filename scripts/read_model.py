#!/usr/bin/env python3
"""Reads dynamic_occupancy_grid model files (docs/model_format.md) with numpy only.

As a library:

    from read_model import load_model, dense_field
    model = load_model("map.dogm")
    model.config["resolution_m"], model.clock_origin_s, model.last_applied_step
    model.x, model.y, model.p_occ, model.em_stats        # one entry per observed cell
    grid, window = dense_field(model, "p_occ")            # 2D, row = y, NaN = unobserved

As a command:

    read_model.py MODEL        prints a summary (cells, bounds, time, mean transitions)

Errors in the file (wrong magic, other version, truncated, checksum mismatch, bad values)
raise ModelFormatError (a ValueError) with a message saying what is wrong; the command then
prints it and exits with status 1.
"""

import argparse
import struct
import sys
import zlib

import numpy as np

MAGIC = b"DOGMODEL"
FORMAT_VERSION = 2  # the version the C++ writes; version 1 is read too

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
    "<Bd"           # learn_prior, prior_population_weight
    "BddI"          # online_em: schedule (0 harmonic, 1 robbins_monro), step_size_exponent, step_size_offset, averaging_start
    "Bdd"           # learn_sensor_model, sensor_model_prior_weight, sensor_model_p_min
    "dddd"          # sensor model sums: trials occ, trials free, hits occ, hits free
)
CHECKSUM_SIZE = 4
HEADER_SIZES = {1: _HEADER_V1.size, 2: _HEADER_V1.size + _LEARNERS_V2.size}

# One observed cell (version 1: 62 bytes, packed; version 2 adds last_hits, last_misses).
CELL_DTYPE_V1 = np.dtype([
    ("x", "<i4"),
    ("y", "<i4"),
    ("p_occ", "<f4"),
    ("last_step", "<i4"),
    ("log_odds", "<f4"),
    ("p_occ_given_free", "<f4"),
    ("p_free_given_occ", "<f4"),
    ("em_stats", "<f4", (8,)),
    ("observed_steps", "<u2"),
])
CELL_DTYPE_V2 = np.dtype(CELL_DTYPE_V1.descr + [("last_hits", "u1"), ("last_misses", "u1")])
CELL_DTYPES = {1: CELL_DTYPE_V1, 2: CELL_DTYPE_V2}
CELL_FIELDS = CELL_DTYPE_V2.names

assert HEADER_SIZES == {1: 197, 2: 276} and CELL_DTYPE_V1.itemsize == 62 and CELL_DTYPE_V2.itemsize == 64, \
    "the layout of docs/model_format.md"


class ModelFormatError(ValueError):
    """The bytes are not an intact model file of version 1 or FORMAT_VERSION."""


class Model:
    """A model file's contents.

    config: dict with MapperConfig's fields and names (prior_transitions, online_em and
        static_clamp are nested dicts).
    clock_origin_s: sensor time of the start of step 0, or None (no scan seen).
    last_applied_step: the last step applied to the cells, or None.
    x, y (int32), p_occ, log_odds, p_occ_given_free, p_free_given_occ (float32),
    last_step (int32), em_stats (float32, N x 8, S(i, j, m) at (i * 2 + j) * 2 + m, 0 = occ),
    observed_steps (uint16), last_hits, last_misses (uint8, the evidence of the cell's last
    step; 0 in version 1 files): one entry per observed cell, by row (y) then column (x).
    sensor_model_stats: dict of the online sensor model's sums (trials_occ, trials_free,
        hits_occ, hits_free; zeros in version 1 files).
    """

    def __init__(self, config, clock_origin_s, last_applied_step, cells, sensor_model_stats):
        self.config = config
        self.sensor_model_stats = sensor_model_stats
        self.clock_origin_s = clock_origin_s
        self.last_applied_step = last_applied_step
        for name in CELL_FIELDS:
            if name in cells.dtype.names:
                setattr(self, name, np.ascontiguousarray(cells[name]))
            else:
                setattr(self, name, np.zeros(len(cells), dtype=CELL_DTYPE_V2[name]))

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
        "learn_prior": False,
        "prior_population_weight": 10.0,
        "learn_sensor_model": False,
        "sensor_model_prior_weight": 1000.0,
        "sensor_model_p_min": 0.01,
    }
    config["online_em"].update({"schedule": "harmonic", "step_size_exponent": 0.6, "step_size_offset": 2.0,
                                "averaging_start": 0})
    sensor_model_stats = {"trials_occ": 0.0, "trials_free": 0.0, "hits_occ": 0.0, "hits_free": 0.0}
    if version >= 2:
        (learn_prior, population_weight, schedule, exponent, offset, averaging_start, learn_sensor,
         sensor_weight, sensor_p_min, trials_occ, trials_free, hits_occ, hits_free) = _LEARNERS_V2.unpack_from(
             data, HEADER_SIZES[1] - 8)
        if schedule not in (0, 1):
            raise ModelFormatError(f"invalid model file: online_em.schedule is {schedule}, must be 0 (harmonic) or "
                                   "1 (robbins_monro)")
        config.update({"learn_prior": _flag(learn_prior, "learn_prior"), "prior_population_weight": population_weight,
                       "learn_sensor_model": _flag(learn_sensor, "learn_sensor_model"),
                       "sensor_model_prior_weight": sensor_weight, "sensor_model_p_min": sensor_p_min})
        config["online_em"].update({"schedule": "harmonic" if schedule == 0 else "robbins_monro",
                                    "step_size_exponent": exponent, "step_size_offset": offset,
                                    "averaging_start": averaging_start})
        sensor_model_stats = {"trials_occ": trials_occ, "trials_free": trials_free, "hits_occ": hits_occ,
                              "hits_free": hits_free}
    has_origin = _flag(has_origin, "clock origin present")
    has_last = _flag(has_last, "last applied step present")
    if not (resolution_m > 0.0 and time_step_s > 0.0):
        raise ModelFormatError("invalid configuration in model file: resolution and time step must be > 0")
    if (not has_origin and struct.pack("<d", origin_s) != bytes(8)) or (not has_last and last_step != 0):
        raise ModelFormatError("invalid model file: an absent time value is not stored as 0")
    if has_last and not has_origin:
        raise ModelFormatError("invalid time in model file: a last applied step needs a clock origin")
    cells = np.frombuffer(data, dtype=cell_dtype, count=count, offset=header_size)
    return Model(config, origin_s if has_origin else None, last_step if has_last else None, cells, sensor_model_stats)


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
    where no cell was observed. `field` is a cell field name; for "em_stats" give
    `component` (0..7). Returns (array, window) with window = dict(min_x, min_y, width,
    height, resolution_m, origin_x_m, origin_y_m) (world position of the array's
    lower-left corner); (empty 0 x 0 array, window with width = height = 0) for a model
    without cells."""
    if field not in CELL_FIELDS or field in ("x", "y"):
        raise KeyError(f"no cell field {field!r}; fields: {', '.join(CELL_FIELDS[2:])}")
    values = getattr(model, field)
    if field == "em_stats":
        if component is None or not 0 <= component < 8:
            raise ValueError("em_stats needs component 0..7")
        values = values[:, component]
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
    print(f"model file:         {args.model} (format version {FORMAT_VERSION})")
    print(summary(model))
    return 0


if __name__ == "__main__":
    sys.exit(main())
