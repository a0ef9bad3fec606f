#!/usr/bin/env python3
"""Plots the results of the evaluation (the CSV files `evaluate` writes) and the map layers
`process_bag` writes, as PNG files next to them.

    plot_evaluation.py OUT_DIR                  the evaluation's figures in OUT_DIR
    plot_evaluation.py --layers DIR             the map layers in DIR
    plot_evaluation.py OUT_DIR --layers DIR     both

From OUT_DIR:
    accuracy_<scenario>.csv  -> accuracy_<scenario>.png (Figs. 3-5 of Meyer-Delius et al.,
                                AAAI 2012), fig4.png and fig5.png (their two panels side by side)
    parameter_error.csv      -> parameter_error.png (error of the learned transitions)
    path_planning.csv        -> path_planning.png (Table 1, with the paper's values)
    mrf_maps.csv             -> mrf_maps.png (the learned transition maps without and with
                                the MRF next to the truth, as Fig. 5 of Li, Barão & Rato)
    mrf_rmse.csv             -> mrf_rmse.png (their error on sparsely and well observed
                                cells, and the EM's time)
    murphy_corridor_fig2_maps.csv, murphy_corridor_fig2_cells.csv
                             -> murphy_corridor_fig2.png (Murphy 1999, Fig. 2: the map posterior
                                over the 256 maps, its per-cell marginals, online and offline EM)
    murphy_corridor_fig3_position.csv
                             -> murphy_corridor_fig3.png (Fig. 3: the position, exact / dead
                                reckoning / online EM)
    murphy_corridor_fig4_rbpf.csv
                             -> murphy_corridor_fig4.png (Fig. 4(a-b): the RBPF's position and map)
    murphy_corridor_errors.csv
                             -> murphy_corridor_tv.png (each estimator's distance to exact Bayes)
    murphy_doors_maps.csv    -> murphy_doors.png (the 2D world with doors: where each robot
                                stood, the entropy-driven one and the random one, and the
                                maps they learned, in a typical run)
From --layers DIR: <layer>.pgm + <layer>.yaml (map_server files) -> <layer>.png and
layers.png (all of them, in metres).

A missing file is skipped with a note on stdout; a malformed one is an error naming the
file (exit status 1, nothing written). Needs numpy and matplotlib (Debian's python3-numpy,
python3-matplotlib) and, for --layers, PyYAML; no display (matplotlib's Agg backend).
"""

import argparse
import csv
import math
import os
import re
import sys

import numpy as np
import matplotlib

matplotlib.use("Agg")  # files only: no display needed
import matplotlib.pyplot as plt  # noqa: E402 (after the backend is chosen)
from matplotlib.colors import ListedColormap, LogNorm  # noqa: E402

# The evaluation's methods (evaluation/evaluation.h) and baselines, each with one colour in every plot.
ACCURACY_METHODS = (("static", "static"), ("static_unclamped", "static (unclamped)"), ("online", "online"),
                    ("offline", "offline"), ("oracle", "oracle"))
PLANNING_METHODS = (("static", "static"), ("online", "online"), ("offline", "offline"), ("random", "random"),
                    ("optimal", "optimal"))
# The MRF experiment's two offline EMs: plain EM is the offline method (its colour).
MRF_METHODS = (("plain", "plain EM"), ("mrf", "EM with the MRF"))
COLOURS = {"static": "#7f7f7f", "static_unclamped": "#8c564b", "online": "#1f77b4", "offline": "#d62728",
           "oracle": "#2ca02c", "random": "#9467bd", "optimal": "#ff7f0e", "plain": "#d62728", "mrf": "#17becf"}

# accuracy_<scenario>.csv: the scenarios and the figure of the paper each one reproduces.
ACCURACY_TITLES = {
    "dynamic_5_5": "Fig. 4 (left): 5 % dynamic cells, 5 % change probability",
    "dynamic_25_25": "Fig. 4 (right): 25 % dynamic cells, 25 % change probability",
    "redraw_100": "Fig. 5 (left): new dynamic cells after 100 steps",
    "redraw_300": "Fig. 5 (right): new dynamic cells after 300 steps",
    "parking_lot": "Fig. 3: parking lot",
}
# The side-by-side figures: file, title, (left, right) scenario.
PANEL_FIGURES = (
    ("fig4", "Fig. 4: accuracy for different configurations of dynamic cells", ("dynamic_5_5", "dynamic_25_25")),
    ("fig5", "Fig. 5: accuracy when the dynamics of the environment change", ("redraw_100", "redraw_300")),
)
PARKING_STEPS_PER_HOUR = 108  # the parking lot's cars change every 108 steps (evaluation/simulator.cpp)

ACCURACY_COLUMNS = ("step",) + tuple(f"{name}_{stat}" for name, _ in ACCURACY_METHODS for stat in ("mean", "std"))
PARAMETER_ERROR_TEXT = ("scenario", "method")
PARAMETER_ERROR_NUMBERS = ("dynamic_cells", "dynamic_p_occ_given_free_mae", "dynamic_p_free_given_occ_mae",
                           "static_cells", "static_p_occ_given_free_mae", "static_p_free_given_occ_mae")
PLANNING_PAPER = tuple(f"paper_{name}" for name, _ in PLANNING_METHODS)
PLANNING_NUMBERS = tuple(f"{name}_{stat}" for name, _ in PLANNING_METHODS for stat in ("mean", "std")) + PLANNING_PAPER
MRF_PARAMETERS = (("p_occ_given_free", "p(occ | free)"), ("p_free_given_occ", "p(free | occ)"))
MRF_CELLS = (("sparse", "sparse"), ("well_observed", "well observed"))
MRF_RMSE_NUMBERS = tuple(f"{cells}_{parameter}_rmse" for cells, _ in MRF_CELLS for parameter, _ in MRF_PARAMETERS) + (
    "repetition", "sparse_cells", "well_observed_cells", "em_seconds")
MRF_MAP_SOURCES = (("truth", "truth"), ("plain", "plain EM"), ("mrf", "EM with the MRF"))
MRF_MAP_LEARNED = tuple(f"{source}_{parameter}" for source in ("plain", "mrf") for parameter, _ in MRF_PARAMETERS)
MRF_MAP_NUMBERS = ("x", "y", "observed_steps") + tuple(f"truth_{parameter}" for parameter, _ in MRF_PARAMETERS) + \
    MRF_MAP_LEARNED
# The maps' colour scale: the EM's bounds on the learned probabilities (evaluationOfflineEmConfig:
# p_min, p_max); a true 0 (a static cell) is drawn at the lower bound.
MRF_MAP_RANGE = (1e-4, 0.5)

# Murphy's corridor (evaluation/murphy_corridor.h): 1-based steps and cells.
MURPHY_CELL_COLUMNS = ("truth", "exact", "online_em", "offline_em", "rbpf")
MURPHY_POSITION_COLUMNS = ("truth", "exact", "dead_reckoning", "online_em", "offline_em", "rbpf")
MURPHY_RBPF_COLUMNS = ("true_position", "exact_position", "rbpf_position", "true_label", "exact_p_one", "rbpf_p_one")
MURPHY_ERROR_NUMBERS = ("t", "position_tv_mean", "position_tv_std", "truth_mass_mean", "runs")
# The estimators drawn in murphy_corridor_tv.png, with their colours.
MURPHY_TV_ESTIMATORS = (("dead_reckoning", "dead reckoning", "#7f7f7f"), ("online_em", "online EM", "#1f77b4"),
                        ("offline_em", "offline EM (per prefix)", "#d62728"), ("rbpf", "RBPF", "#2ca02c"),
                        ("rbpf_optimal", "RBPF, optimal proposal", "#ff7f0e"))
MURPHY_RETURN_T = 10  # the robot turns back at t = 10 (kMurphyReturnStep + 1)

# The layers process_bag writes (core/layers/layers.cpp, layerName), in its order.
LAYERS = (("belief", "belief: p(occ) now"), ("predicted", "predicted p(occ)"),
          ("stationary", "stationary p(occ)"), ("p_occ_given_free", "p(occ | free) per step"),
          ("p_free_given_occ", "p(free | occ) per step"), ("static_map", "static map"))

DPI = 120


class InputError(Exception):
    """A malformed or unusable input; the message names the file."""


# ------------------------------------------------------------------------- reading

def read_table(path, text_columns=(), number_columns=(), may_be_empty=()):
    """The CSV file at `path` as {column: values}: a list of str for each text column, a
    float array for each number column (an empty cell is NaN where the column is in
    `may_be_empty`). Other columns are ignored. Raises InputError naming the file, line and
    column for a missing column, a short or long row, a value that is not a number, no rows."""
    try:
        with open(path, newline="") as file:
            rows = list(csv.reader(file))
    except (OSError, UnicodeDecodeError, csv.Error) as error:
        raise InputError(f"{path}: cannot read: {error}") from None
    if not rows:
        raise InputError(f"{path}: empty file (expected a header line)")
    header = [name.strip() for name in rows[0]]
    missing = [name for name in text_columns + number_columns if name not in header]
    if missing:
        raise InputError(f"{path}: header lacks the column(s) {', '.join(missing)} (header: {','.join(header)})")
    body = [(number, row) for number, row in enumerate(rows[1:], start=2) if any(field.strip() for field in row)]
    if not body:
        raise InputError(f"{path}: no data rows after the header")
    table = {name: [] for name in text_columns + number_columns}
    for line, row in body:
        if len(row) != len(header):
            raise InputError(f"{path}: line {line} has {len(row)} fields, the header {len(header)}")
        fields = dict(zip(header, (field.strip() for field in row)))
        for name in text_columns:
            if not fields[name]:
                raise InputError(f"{path}: line {line}: empty {name}")
            table[name].append(fields[name])
        for name in number_columns:
            text = fields[name]
            if not text and name in may_be_empty:
                table[name].append(math.nan)
                continue
            try:
                table[name].append(float(text))
            except ValueError:
                raise InputError(f"{path}: line {line}: {name} is '{text}', not a number") from None
    for name in number_columns:
        table[name] = np.array(table[name])
    return table


def read_accuracy(path):
    table = read_table(path, number_columns=ACCURACY_COLUMNS)
    steps = table["step"]
    if not (np.all(steps == np.round(steps)) and np.all(np.diff(steps) > 0)):
        raise InputError(f"{path}: the steps must be whole numbers in increasing order")
    return table


def read_mrf_rmse(path):
    table = read_table(path, ("method",), MRF_RMSE_NUMBERS)
    methods = set(table["method"])
    if methods != {name for name, _ in MRF_METHODS}:
        raise InputError(f"{path}: the methods must be {' and '.join(name for name, _ in MRF_METHODS)}, "
                         f"got {', '.join(sorted(methods))}")
    return table


def grid_cells(path, table):
    """(width, height, flat index per row) of a table with one row per cell of a grid
    (columns x and y); raises InputError unless x, y are whole numbers >= 0 and every cell
    appears once."""
    x, y = table["x"], table["y"]
    if not (np.all(x == np.round(x)) and np.all(y == np.round(y)) and x.min() >= 0 and y.min() >= 0):
        raise InputError(f"{path}: x and y must be cell indices (whole numbers >= 0)")
    width, height = int(x.max()) + 1, int(y.max()) + 1
    index = y.astype(int) * width + x.astype(int)
    if index.size != width * height or np.unique(index).size != index.size:
        raise InputError(f"{path}: expected one row per cell of a {width} x {height} grid, got {index.size} rows")
    return width, height, index


def read_mrf_maps(path):
    """mrf_maps.csv as {column: 2D array indexed [y, x]}; learned values NaN where empty."""
    table = read_table(path, number_columns=MRF_MAP_NUMBERS, may_be_empty=MRF_MAP_LEARNED)
    width, height, index = grid_cells(path, table)
    grids = {}
    for name in MRF_MAP_NUMBERS[2:]:
        grid = np.full(width * height, math.nan)
        grid[index] = table[name]
        grids[name] = grid.reshape(height, width)
    return grids


def read_step_grid(path, columns, key="cell"):
    """A Murphy corridor table with one row per (t, key) as {column: 2D array [key - 1, t - 1]}
    (1-based t and cells, as in the paper); every (t, key) once, values in [0, 1]."""
    table = read_table(path, number_columns=("t", key) + columns)
    t, k = table["t"], table[key]
    if not (np.all(t == np.round(t)) and np.all(k == np.round(k)) and t.min() >= 1 and k.min() >= 0):
        raise InputError(f"{path}: t and {key} must be whole numbers (t >= 1)")
    offset = 1 if key == "cell" else 0  # cells are 1-based, maps 0-based
    if k.min() < offset:
        raise InputError(f"{path}: {key} must be >= {offset}")
    steps, size = int(t.max()), int(k.max()) + 1 - offset
    index = (k.astype(int) - offset) * steps + (t.astype(int) - 1)
    if index.size != steps * size or np.unique(index).size != index.size:
        raise InputError(f"{path}: expected one row per step and {key} ({steps} x {size}), got {index.size} rows")
    grids = {}
    for name in columns:
        values = table[name]
        if np.any(values < -1e-9) or np.any(values > 1.0 + 1e-9):
            raise InputError(f"{path}: {name} must be probabilities in [0, 1]")
        grid = np.full(steps * size, math.nan)
        grid[index] = values
        grids[name] = grid.reshape(size, steps)
    return grids


def read_murphy(out_dir):
    """Murphy's corridor tables of `out_dir`: {name: grids or table}, a note per missing one."""
    readers = {
        "fig2_maps": lambda path: read_step_grid(path, ("probability",), key="map"),
        "fig2_cells": lambda path: read_step_grid(path, MURPHY_CELL_COLUMNS),
        "fig3_position": lambda path: read_step_grid(path, MURPHY_POSITION_COLUMNS),
        "fig4_rbpf": lambda path: read_step_grid(path, MURPHY_RBPF_COLUMNS),
        "errors": lambda path: read_table(path, ("variant", "estimator"), MURPHY_ERROR_NUMBERS),
    }
    figures = {"fig2_maps": "fig2", "fig2_cells": "fig2", "fig3_position": "fig3", "fig4_rbpf": "fig4",
               "errors": "tv"}
    murphy = {}
    for name, reader in readers.items():
        path = os.path.join(out_dir, f"murphy_corridor_{name}.csv")
        if os.path.exists(path):
            murphy[name] = reader(path)
        else:
            print(f"note: murphy_corridor_{figures[name]}.png skipped: no {path}")
    return murphy


def read_pgm(path):
    """A binary PGM (P5) as a 2D array (row 0 at the top) and its maxval."""
    try:
        with open(path, "rb") as file:
            data = file.read()
    except OSError as error:
        raise InputError(f"{path}: cannot read: {error}") from None
    # Header: magic, width, height, maxval, separated by whitespace; '#' starts a comment
    # that runs to the end of its line; one whitespace character before the pixels.
    tokens, pos = [], 0
    while len(tokens) < 4:
        while pos < len(data) and data[pos:pos + 1].isspace():
            pos += 1
        if data[pos:pos + 1] == b"#":
            end = data.find(b"\n", pos)
            pos = len(data) if end < 0 else end + 1
            continue
        start = pos
        while pos < len(data) and not data[pos:pos + 1].isspace():
            pos += 1
        if start == pos:
            raise InputError(f"{path}: truncated PGM header")
        tokens.append(data[start:pos])
    if tokens[0] != b"P5":
        raise InputError(f"{path}: not a binary PGM (magic {tokens[0][:8]!r}, expected P5)")
    try:
        width, height, maxval = (int(token) for token in tokens[1:])
    except ValueError:
        raise InputError(f"{path}: bad PGM header {b' '.join(tokens[1:])[:40]!r}") from None
    if width <= 0 or height <= 0 or not 0 < maxval < 65536:
        raise InputError(f"{path}: bad PGM size {width} x {height} or maxval {maxval}")
    dtype = np.dtype(">u2") if maxval > 255 else np.dtype("u1")
    pixels = data[pos + 1:pos + 1 + width * height * dtype.itemsize]
    if len(pixels) < width * height * dtype.itemsize:
        raise InputError(f"{path}: truncated PGM: {len(pixels)} bytes of pixels, {width} x {height} expected")
    return np.frombuffer(pixels, dtype=dtype).reshape(height, width), maxval


def read_map(directory, layer):
    """The map_server layer `layer` in `directory`: (image, maxval, resolution, origin x, y)."""
    import yaml  # only --layers needs it
    path = os.path.join(directory, f"{layer}.yaml")
    try:
        with open(path) as file:
            info = yaml.safe_load(file)
    except (OSError, yaml.YAMLError) as error:
        raise InputError(f"{path}: cannot read: {error}") from None
    try:
        image_path = os.path.join(directory, str(info["image"]))
        resolution = float(info["resolution"])
        origin_x, origin_y = float(info["origin"][0]), float(info["origin"][1])
        negate = int(info.get("negate", 0))
    except (TypeError, KeyError, IndexError, ValueError) as error:
        raise InputError(f"{path}: not a map_server map file (image, resolution, origin): {error!r}") from None
    if not resolution > 0.0:
        raise InputError(f"{path}: resolution must be > 0, got {resolution}")
    image, maxval = read_pgm(image_path)
    if negate:
        image = maxval - image
    return image, maxval, resolution, origin_x, origin_y


# ------------------------------------------------------------------------- plotting

def save(figure, path):
    figure.savefig(path, dpi=DPI)
    plt.close(figure)
    print(f"wrote {path}")


def mark_events(axes, scenario, last_step):
    """The scenario's scripted changes: the re-draw of the dynamic cells (its step is in the
    name), the parking lot's hours."""
    redraw = re.fullmatch(r"redraw_(\d+)", scenario)
    if redraw:
        axes.axvline(int(redraw.group(1)), color="black", linestyle="--", linewidth=1.0, label="new dynamic cells")
    if scenario == "parking_lot":
        for index, step in enumerate(range(PARKING_STEPS_PER_HOUR, int(last_step) + 1, PARKING_STEPS_PER_HOUR)):
            axes.axvline(step, color="black", linestyle=":", linewidth=0.8, label=None if index else "new hour")


def plot_accuracy_panel(axes, scenario, table):
    steps = table["step"]
    lowest = 100.0
    for name, label in ACCURACY_METHODS:
        mean, std = table[f"{name}_mean"], table[f"{name}_std"]
        axes.fill_between(steps, mean - std, mean + std, color=COLOURS[name], alpha=0.2, linewidth=0)
        axes.plot(steps, mean, color=COLOURS[name], linewidth=1.2, label=label)
        if np.isfinite(mean - std).any():
            lowest = min(lowest, float(np.nanmin(mean - std)))
    mark_events(axes, scenario, steps[-1])
    if steps.size > 1:  # one step has no extent
        axes.set_xlim(steps[0], steps[-1])
    axes.set_ylim(max(0.0, math.floor(lowest / 5.0) * 5.0), 100.0)
    axes.set_xlabel("time step")
    axes.set_ylabel("accuracy [%]")
    axes.set_title(ACCURACY_TITLES[scenario], fontsize=10)
    axes.grid(True, alpha=0.3)
    axes.legend(loc="lower right", fontsize=8)


def plot_accuracy(out_dir, accuracy):
    for scenario, table in accuracy.items():
        figure, axes = plt.subplots(figsize=(7.0, 4.5), layout="constrained")
        plot_accuracy_panel(axes, scenario, table)
        save(figure, os.path.join(out_dir, f"accuracy_{scenario}.png"))
    for name, title, scenarios in PANEL_FIGURES:
        absent = [scenario for scenario in scenarios if scenario not in accuracy]
        if absent:
            print(f"note: {name}.png skipped: no {', '.join(f'accuracy_{scenario}.csv' for scenario in absent)}")
            continue
        figure, panels = plt.subplots(1, 2, figsize=(13.0, 4.5), layout="constrained", sharey=True)
        for axes, scenario in zip(panels, scenarios):
            plot_accuracy_panel(axes, scenario, accuracy[scenario])
        figure.suptitle(title)
        save(figure, os.path.join(out_dir, f"{name}.png"))


def grouped_bars(axes, groups, series, values, errors):
    """Bars of `values[s][g]` with error bars `errors[s][g]` for each series s (in `series`:
    name, label) side by side over each group g; returns the bars' x by series."""
    width = 0.8 / len(series)
    centres = {}
    for index, (name, label) in enumerate(series):
        x = np.arange(len(groups)) + (index - (len(series) - 1) / 2.0) * width
        axes.bar(x, values[name], width, color=COLOURS.get(name), label=label,
                 yerr=errors[name], capsize=3, error_kw={"linewidth": 0.8})
        centres[name] = x
    axes.set_xticks(np.arange(len(groups)))
    return centres


def use_log_scale_if_spread(axes, values):
    """A log axis when the positive values span more than a factor of 10: the small errors
    would be invisible next to the large ones otherwise."""
    positive = np.concatenate([np.asarray(v, dtype=float).ravel() for v in values])
    positive = positive[np.isfinite(positive) & (positive > 0)]
    if positive.size and positive.max() / positive.min() > 10.0:
        axes.set_yscale("log")


def plot_parameter_error(out_dir, table):
    scenarios = list(dict.fromkeys(table["scenario"]))
    methods = [(name, name) for name in dict.fromkeys(table["method"])]
    row_scenarios, row_methods = np.array(table["scenario"]), np.array(table["method"])
    # Several rows of one scenario and method (repetitions) give a mean and a spread.
    figure, panels = plt.subplots(2, 2, figsize=(12.0, 7.5), layout="constrained", sharex=True)
    for row, cells in enumerate(("dynamic", "static")):
        for column, parameter in enumerate(("p_occ_given_free", "p_free_given_occ")):
            axes = panels[row][column]
            values = table[f"{cells}_{parameter}_mae"]
            means = {name: [] for name, _ in methods}
            spreads = {name: [] for name, _ in methods}
            for name, _ in methods:
                for scenario in scenarios:
                    chosen = values[(row_scenarios == scenario) & (row_methods == name)]
                    means[name].append(chosen.mean() if chosen.size else math.nan)
                    spreads[name].append(chosen.std() if chosen.size > 1 else 0.0)
            grouped_bars(axes, scenarios, methods, means, spreads)
            use_log_scale_if_spread(axes, means.values())
            axes.set_xticklabels(scenarios, rotation=20, ha="right")
            axes.set_ylabel("mean absolute error per step")
            axes.set_title(f"{cells} cells: {parameter}", fontsize=10)
            axes.grid(True, axis="y", alpha=0.3)
            axes.legend(fontsize=8)
    figure.suptitle("Error of the learned transition probabilities against the truth")
    save(figure, os.path.join(out_dir, "parameter_error.png"))


def plot_path_planning(out_dir, table):
    classes = table["class"]
    figure, axes = plt.subplots(figsize=(12.0, 5.0), layout="constrained")
    means = {name: table[f"{name}_mean"] for name, _ in PLANNING_METHODS}
    errors = {name: table[f"{name}_std"] for name, _ in PLANNING_METHODS}
    centres = grouped_bars(axes, classes, PLANNING_METHODS, means, errors)
    paper_label = "paper (Table 1)"
    for name, _ in PLANNING_METHODS:
        paper = table[f"paper_{name}"]
        shown = np.isfinite(paper)  # the paper leaves some cells empty
        axes.plot(centres[name][shown], paper[shown], linestyle="none", marker="D", markersize=5,
                  markerfacecolor="white", markeredgecolor="black", label=paper_label)
        paper_label = None
    axes.set_xticklabels([name.replace("_", " ") for name in classes], rotation=15, ha="right")
    axes.set_ylabel("runs [%]")
    axes.set_title("Table 1: planned paths in the door scenario (mean ± std over repetitions)")
    axes.grid(True, axis="y", alpha=0.3)
    axes.legend(fontsize=8, ncol=2)
    save(figure, os.path.join(out_dir, "path_planning.png"))


def sample_std(values):
    """The standard deviation over seeds as summary.md gives it (n - 1; 0 for one value)."""
    return float(np.std(values, ddof=1)) if values.size > 1 else 0.0


def plot_mrf_maps(out_dir, grids):
    """Fig. 5 of Li, Barão & Rato: each learned parameter (a row) without and with the MRF, next
    to the truth, on one logarithmic colour scale; grey: never observed."""
    low, high = MRF_MAP_RANGE
    norm = LogNorm(vmin=low, vmax=high)
    colour_map = plt.get_cmap("viridis").copy()
    colour_map.set_bad("#bfbfbf")
    height, width = grids["observed_steps"].shape
    figure, panels = plt.subplots(2, 3, figsize=(13.0, 6.4), layout="constrained", squeeze=False)
    for row, (parameter, parameter_label) in enumerate(MRF_PARAMETERS):
        for column, (source, source_label) in enumerate(MRF_MAP_SOURCES):
            axes = panels[row][column]
            values = np.clip(grids[f"{source}_{parameter}"], low, high)  # NaN stays NaN
            image = axes.imshow(np.ma.masked_invalid(values), cmap=colour_map, norm=norm, origin="lower",
                                interpolation="nearest", extent=(0, width, 0, height))
            axes.set_title(f"{parameter_label}: {source_label}", fontsize=10)
            axes.set_xlabel("x [cells]")
            axes.set_ylabel("y [cells]")
        figure.colorbar(image, ax=list(panels[row]), shrink=0.9, label="per step (true 0 drawn at 1e-4)")
    figure.suptitle("Learned transition probabilities of one run (cf. Li, Barão & Rato, Fig. 5); "
                    "grey: never observed")
    save(figure, os.path.join(out_dir, "mrf_maps.png"))


def plot_mrf_rmse(out_dir, table):
    """RMSE per cell class and parameter, plain EM against EM with the MRF (mean and std over
    the seeds), and the EMs' wall time."""
    methods = np.array(table["method"])
    groups = [f"{cells_label}\n{parameter_label}" for _, cells_label in MRF_CELLS
              for _, parameter_label in MRF_PARAMETERS]
    columns = [f"{cells}_{parameter}_rmse" for cells, _ in MRF_CELLS for parameter, _ in MRF_PARAMETERS]
    means = {name: [table[column][methods == name].mean() for column in columns] for name, _ in MRF_METHODS}
    spreads = {name: [sample_std(table[column][methods == name]) for column in columns] for name, _ in MRF_METHODS}
    figure, (rmse_axes, time_axes) = plt.subplots(1, 2, figsize=(12.0, 4.8), layout="constrained",
                                                  gridspec_kw={"width_ratios": (3, 1)})
    grouped_bars(rmse_axes, groups, MRF_METHODS, means, spreads)
    use_log_scale_if_spread(rmse_axes, means.values())
    rmse_axes.set_xticklabels(groups)
    rmse_axes.set_ylabel("RMSE per step")
    rmse_axes.set_title("Error of the learned transitions against the truth", fontsize=10)
    rmse_axes.grid(True, axis="y", alpha=0.3)
    rmse_axes.legend(fontsize=8)
    seconds = {name: [table["em_seconds"][methods == name].mean()] for name, _ in MRF_METHODS}
    seconds_spread = {name: [sample_std(table["em_seconds"][methods == name])] for name, _ in MRF_METHODS}
    grouped_bars(time_axes, ["EM"], MRF_METHODS, seconds, seconds_spread)
    time_axes.set_xticklabels([""])
    time_axes.set_ylabel("wall time per run [s]")
    time_axes.set_title("Time of the EM", fontsize=10)
    time_axes.grid(True, axis="y", alpha=0.3)
    runs = len(set(table["repetition"]))
    figure.suptitle(f"MRF-smoothed transition maps (Li, Barão & Rato): mean and std over {runs} seeds")
    save(figure, os.path.join(out_dir, "mrf_rmse.png"))


def show_corridor(axes, grid, title, light_is_one, truth=None):
    """A corridor quantity over time as the paper draws it: cells down, time across, grey
    levels (light = 1 or light = 0); red dots on the true cells where given."""
    cells, steps = grid.shape
    axes.imshow(grid, cmap="gray" if light_is_one else "gray_r", vmin=0.0, vmax=1.0, interpolation="nearest",
                origin="upper", aspect="auto", extent=(0.5, steps + 0.5, cells + 0.5, 0.5))
    if truth is not None:
        cell, t = np.nonzero(truth > 0.5)
        axes.plot(t + 1, cell + 1, "o", color="#d62728", markersize=3, label="truth")
    axes.set_xlabel("t")
    axes.set_ylabel("cell")
    axes.set_title(title, fontsize=10)


def read_doors(path):
    """murphy_doors_maps.csv as grids (rows = y, bottom row first): the layout (0 free,
    1 wall, 2 door) and per policy the visits and the final p(occ)."""
    table = read_table(path, ("cell",), ("run", "x", "y", "entropy_visits", "entropy_p_occ", "random_visits",
                                         "random_p_occ"))
    width, height, _ = grid_cells(path, table)
    grids = {name: np.full((height, width), np.nan) for name in
             ("layout", "entropy_visits", "entropy_p_occ", "random_visits", "random_p_occ")}
    kinds = {"free": 0.0, "wall": 1.0, "door": 2.0}
    for i, kind in enumerate(table["cell"]):
        if kind not in kinds:
            raise InputError(f"{path}: line {i + 2}: cell is '{kind}', not free, wall or door")
        x, y = int(table["x"][i]), int(table["y"][i])
        grids["layout"][y, x] = kinds[kind]
        for name in ("entropy_visits", "entropy_p_occ", "random_visits", "random_p_occ"):
            grids[name][y, x] = table[name][i]
    grids["run"] = int(table["run"][0])
    return grids


def plot_doors(out_dir, grids):
    """Murphy's 2D world with doors: the layout, where each robot stood (log scale) with the
    doors ringed, and the map each learned."""
    figure, axes = plt.subplots(2, 3, figsize=(13, 7))
    doors_y, doors_x = np.nonzero(grids["layout"] == 2.0)
    axes[0][0].imshow(grids["layout"], cmap=ListedColormap(["white", "black", "#ff7f0e"]),
                      vmin=-0.5, vmax=2.5, origin="lower", interpolation="nearest")
    axes[0][0].set_title("the world: walls, free space, doors (orange)", fontsize=10)
    axes[1][0].axis("off")
    for row, policy in enumerate(("entropy", "random")):
        visits = grids[policy + "_visits"]
        shown = axes[row][1].imshow(np.log10(1.0 + visits), cmap="viridis", origin="lower", interpolation="nearest")
        axes[row][1].plot(doors_x, doors_y, "o", markerfacecolor="none", markeredgecolor="#ff7f0e", markersize=12)
        axes[row][1].set_title(f"{policy}: where the robot stood (log10(1 + steps))", fontsize=10)
        figure.colorbar(shown, ax=axes[row][1], fraction=0.04)
        shown = axes[row][2].imshow(grids[policy + "_p_occ"], cmap="gray_r", vmin=0.0, vmax=1.0, origin="lower",
                                    interpolation="nearest")
        axes[row][2].set_title(f"{policy}: the learned map at the end, p(occ)", fontsize=10)
        figure.colorbar(shown, ax=axes[row][2], fraction=0.04)
    figure.suptitle(f"Murphy 1999: the 2D world with doors, run {grids['run']} (the entropy robot's median door "
                    "accuracy; evaluation/murphy_doors.h)")
    figure.tight_layout()
    save(figure, os.path.join(out_dir, "murphy_doors.png"))


def plot_murphy(out_dir, murphy):
    """Murphy 1999, Figs. 2-4, and the distance of each estimator to exact Bayes."""
    if "fig2_maps" in murphy and "fig2_cells" in murphy:
        cells = murphy["fig2_cells"]
        figure, panels = plt.subplots(1, 4, figsize=(16.0, 4.2), layout="constrained",
                                      gridspec_kw={"width_ratios": (1.6, 1, 1, 1)})
        maps = murphy["fig2_maps"]["probability"]
        panels[0].imshow(maps, cmap="viridis", interpolation="nearest", origin="lower", aspect="auto",
                         extent=(0.5, maps.shape[1] + 0.5, -0.5, maps.shape[0] - 0.5))
        panels[0].set_xlabel("t")
        panels[0].set_ylabel("map (bit i = cell i + 1; the paper's number is map + 1)")
        panels[0].set_title("(a) exact p(M_t | y_1:t) over the maps", fontsize=10)
        for axes, (name, label) in zip(panels[1:], (("exact", "(b) exact marginals"), ("online_em", "(c) online EM"),
                                                     ("offline_em", "(d) offline EM"))):
            # The paper: light cells are more likely 0, so the truth 01010101 is light in the odd cells.
            show_corridor(axes, cells[name], label, light_is_one=False)
        figure.suptitle("Murphy 1999, Fig. 2: the map; light = more likely 0 (truth 01010101)")
        save(figure, os.path.join(out_dir, "murphy_corridor_fig2.png"))
    if "fig3_position" in murphy:
        position = murphy["fig3_position"]
        figure, panels = plt.subplots(1, 3, figsize=(13.0, 4.2), layout="constrained")
        for axes, (name, label) in zip(panels, (("exact", "(a) exact Bayes"), ("dead_reckoning", "(b) dead reckoning"),
                                                ("online_em", "(c) online EM, maximal window"))):
            show_corridor(axes, position[name], label, light_is_one=True, truth=position["truth"])
        panels[0].legend(fontsize=8, loc="lower left")
        figure.suptitle("Murphy 1999, Fig. 3: the position; light = more likely the robot's cell (red: the truth)")
        save(figure, os.path.join(out_dir, "murphy_corridor_fig3.png"))
    if "fig4_rbpf" in murphy:
        rbpf = murphy["fig4_rbpf"]
        figure, panels = plt.subplots(1, 4, figsize=(16.0, 4.2), layout="constrained")
        show_corridor(panels[0], rbpf["exact_position"], "exact position", True, truth=rbpf["true_position"])
        show_corridor(panels[1], rbpf["rbpf_position"], "(a) RBPF position", True, truth=rbpf["true_position"])
        show_corridor(panels[2], rbpf["exact_p_one"], "exact map", False)
        show_corridor(panels[3], rbpf["rbpf_p_one"], "(b) RBPF map", False)
        figure.suptitle("Murphy 1999, Fig. 4(a-b): the RBPF against exact Bayes (one seed)")
        save(figure, os.path.join(out_dir, "murphy_corridor_fig4.png"))
    if "errors" in murphy:
        table = murphy["errors"]
        variants = np.array(table["variant"])
        estimators = np.array(table["estimator"])
        figure, panels = plt.subplots(1, 2, figsize=(12.0, 4.4), layout="constrained")
        for name, label, colour in MURPHY_TV_ESTIMATORS:
            mine = (variants == "paper") & (estimators == name)
            if not mine.any():
                continue
            t = table["t"][mine]
            tv, spread = table["position_tv_mean"][mine], table["position_tv_std"][mine]
            panels[0].plot(t, tv, color=colour, label=label)
            panels[0].fill_between(t, tv - spread, tv + spread, color=colour, alpha=0.2, linewidth=0)
            panels[1].plot(t, table["truth_mass_mean"][mine], color=colour, label=label)
        exact = (variants == "paper") & (estimators == "exact")
        if exact.any():
            panels[1].plot(table["t"][exact], table["truth_mass_mean"][exact], color="black", label="exact")
        runs = int(table["runs"][0])
        panels[0].set_ylabel("total variation distance to exact p(L_t | y_1:t)")
        panels[0].set_title(f"Position error per step (mean and std over {runs} seeds)", fontsize=10)
        panels[1].set_ylabel("p(L_t = true cell)")
        panels[1].set_title("Mass on the robot's true cell", fontsize=10)
        for axes in panels:
            axes.axvline(MURPHY_RETURN_T, color="black", linestyle="--", linewidth=0.8)
            axes.set_xlabel("t (dashed: the robot turns back)")
            axes.set_ylim(0.0, 1.0)
            axes.grid(True, alpha=0.3)
        panels[1].legend(fontsize=8)
        figure.suptitle("Murphy's corridor, the paper's run: each estimator against exact Bayes")
        save(figure, os.path.join(out_dir, "murphy_corridor_tv.png"))


def read_evaluation(out_dir):
    """The CSV files of `out_dir` that exist: (accuracy by scenario, parameter error table or
    None, path planning table or None, MRF RMSE table or None, MRF maps or None, Murphy's
    corridor tables by name, Murphy's doors grids or None); a note for each missing one."""
    if not os.path.isdir(out_dir):
        raise InputError(f"{out_dir}: no such directory")
    accuracy = {}
    for scenario in ACCURACY_TITLES:
        path = os.path.join(out_dir, f"accuracy_{scenario}.csv")
        if os.path.exists(path):
            accuracy[scenario] = read_accuracy(path)
        else:
            print(f"note: accuracy_{scenario}.png skipped: no {path}")
    parameter_error = path_planning = None
    path = os.path.join(out_dir, "parameter_error.csv")
    if os.path.exists(path):
        parameter_error = read_table(path, PARAMETER_ERROR_TEXT, PARAMETER_ERROR_NUMBERS)
    else:
        print(f"note: parameter_error.png skipped: no {path}")
    path = os.path.join(out_dir, "path_planning.csv")
    if os.path.exists(path):
        path_planning = read_table(path, ("class",), PLANNING_NUMBERS, may_be_empty=PLANNING_PAPER)
    else:
        print(f"note: path_planning.png skipped: no {path}")
    mrf_rmse = mrf_maps = None
    path = os.path.join(out_dir, "mrf_rmse.csv")
    if os.path.exists(path):
        mrf_rmse = read_mrf_rmse(path)
    else:
        print(f"note: mrf_rmse.png skipped: no {path}")
    path = os.path.join(out_dir, "mrf_maps.csv")
    if os.path.exists(path):
        mrf_maps = read_mrf_maps(path)
    else:
        print(f"note: mrf_maps.png skipped: no {path}")
    murphy = read_murphy(out_dir)
    doors = None
    path = os.path.join(out_dir, "murphy_doors_maps.csv")
    if os.path.exists(path):
        doors = read_doors(path)
    else:
        print(f"note: murphy_doors.png skipped: no {path}")
    if not accuracy and not murphy and all(table is None for table in (parameter_error, path_planning, mrf_rmse,
                                                                        mrf_maps, doors)):
        raise InputError(f"{out_dir}: none of the evaluation's CSV files (accuracy_<scenario>.csv, "
                         "parameter_error.csv, path_planning.csv, mrf_rmse.csv, mrf_maps.csv, murphy_corridor_*.csv, "
                         "murphy_doors_maps.csv)")
    return accuracy, parameter_error, path_planning, mrf_rmse, mrf_maps, murphy, doors


def plot_evaluation(out_dir, evaluation):
    accuracy, parameter_error, path_planning, mrf_rmse, mrf_maps, murphy, doors = evaluation
    plot_accuracy(out_dir, accuracy)
    if parameter_error is not None:
        plot_parameter_error(out_dir, parameter_error)
    if path_planning is not None:
        plot_path_planning(out_dir, path_planning)
    if mrf_rmse is not None:
        plot_mrf_rmse(out_dir, mrf_rmse)
    if mrf_maps is not None:
        plot_mrf_maps(out_dir, mrf_maps)
    plot_murphy(out_dir, murphy)
    if doors is not None:
        plot_doors(out_dir, doors)


def show_map(axes, layer, title):
    image, maxval, resolution, origin_x, origin_y = layer
    height, width = image.shape
    # Row 0 of the image is the top (north): 'upper' puts it at the top of the extent.
    axes.imshow(image, cmap="gray", vmin=0, vmax=maxval, interpolation="nearest", origin="upper",
                extent=(origin_x, origin_x + width * resolution, origin_y, origin_y + height * resolution))
    axes.set_xlabel("x [m]")
    axes.set_ylabel("y [m]")
    axes.set_title(title, fontsize=10)


def read_layers(directory):
    """The layers of `directory` that exist, by name; a note for each missing one."""
    if not os.path.isdir(directory):
        raise InputError(f"{directory}: no such directory")
    layers = {}
    for name, _ in LAYERS:
        if os.path.exists(os.path.join(directory, f"{name}.yaml")):
            layers[name] = read_map(directory, name)
        else:
            print(f"note: {name}.png skipped: no {os.path.join(directory, name + '.yaml')}")
    if not layers:
        raise InputError(f"{directory}: none of the layers ({', '.join(name for name, _ in LAYERS)}) as .yaml + .pgm")
    return layers


def plot_layers(directory, layers):
    """<layer>.png of every layer and the overview layers.png."""
    legend = "black: occupied, white: free, grey: unknown or in between (map_server's image)"
    titles = dict(LAYERS)
    for name, layer in layers.items():
        figure, axes = plt.subplots(figsize=(6.5, 6.0), layout="constrained")
        show_map(axes, layer, f"{titles[name]}\n{legend}")
        save(figure, os.path.join(directory, f"{name}.png"))
    columns = min(3, len(layers))
    rows = math.ceil(len(layers) / columns)
    figure, panels = plt.subplots(rows, columns, figsize=(4.8 * columns, 4.6 * rows), layout="constrained",
                                  squeeze=False)
    for axes, (name, layer) in zip(panels.ravel(), layers.items()):
        show_map(axes, layer, titles[name])
    for axes in panels.ravel()[len(layers):]:
        axes.set_visible(False)
    figure.suptitle(f"{os.path.abspath(directory)}\n{legend}", fontsize=10)
    save(figure, os.path.join(directory, "layers.png"))


def main(argv=None):
    parser = argparse.ArgumentParser(
        description="Plots the evaluation's CSV files and process_bag's map layers as PNG files next to them.")
    parser.add_argument("out_dir", nargs="?", metavar="OUT_DIR",
                        help="directory with the CSV files of the evaluation (accuracy_<scenario>.csv, "
                             "parameter_error.csv, path_planning.csv, mrf_rmse.csv, mrf_maps.csv, "
                             "murphy_corridor_*.csv)")
    parser.add_argument("--layers", metavar="DIR", help="directory with map_server layers (process_bag --out)")
    args = parser.parse_args(argv)
    if args.out_dir is None and args.layers is None:
        parser.error("give OUT_DIR, --layers DIR, or both")
    # Everything is read (and checked) before anything is written.
    try:
        evaluation = read_evaluation(args.out_dir) if args.out_dir is not None else None
        layers = read_layers(args.layers) if args.layers is not None else None
    except InputError as error:
        print(f"plot_evaluation.py: {error}", file=sys.stderr)
        return 1
    if evaluation is not None:
        plot_evaluation(args.out_dir, evaluation)
    if layers is not None:
        plot_layers(args.layers, layers)
    return 0


if __name__ == "__main__":
    sys.exit(main())
