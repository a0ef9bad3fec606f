#!/usr/bin/env python3
"""Renders the map layers' values (the <layer>.npy files of ~export_layers and process_bag)
as colour PNGs with a colour bar and a scale bar.

    render_layers.py DIR_OR_NPY... [--out DIR] [--dpi N]
    render_layers.py NPY... --side-by-side PNG [--dpi N]

Every <layer>.npy given (or found in a directory given) becomes <layer>_values.png, next to
it or in --out (the _values suffix keeps plot_evaluation.py --layers' <layer>.png intact);
with --side-by-side, the layers given become panels of one PNG, in their order.
The .npy holds float32 values, row 0 the bottom row of the map (min y, as
nav_msgs/OccupancyGrid), NaN for cells never observed (drawn light grey). The map_server
<layer>.yaml next to it gives resolution and origin: the axes are then in metres of the fixed
frame, with a scale bar; without it they count cells.

Colour scales: the probabilities (belief, predicted, stationary, static_map, ltm, stm,
best_particle_belief, best_particle_predicted)
linear from 0 to 1; the transition layers (p_occ_given_free, p_free_given_occ: probability
of a change per time step) logarithmic, from the smallest positive value (at least 1e-6) to
the largest (at least ten times more); values below (0) are black, the bar's arrow.

Exit status 0 when every file was rendered; 1 when a file is unreadable or not a 2-D float
array (the message names it, no PNG written for it); 2 on bad arguments. Needs numpy and
matplotlib (Debian's python3-numpy, python3-matplotlib), no display (matplotlib's Agg).
"""

import argparse
import math
import os
import re
import sys

import numpy as np
import matplotlib

matplotlib.use("Agg")  # files only: no display needed
import matplotlib.pyplot as plt  # noqa: E402 (after the backend is chosen)
from matplotlib.colors import LogNorm, Normalize  # noqa: E402
from mpl_toolkits.axes_grid1.anchored_artists import AnchoredSizeBar  # noqa: E402

TRANSITION_LAYERS = {
    "p_occ_given_free": "p(free \u2192 occ) per time step",
    "p_free_given_occ": "p(occ \u2192 free) per time step",
}
PROBABILITY_LAYERS = {
    "belief": "p(occ) now",
    "predicted": "p(occ) at the prediction horizon",
    "stationary": "long-run p(occ)",
    "static_map": "p(occ), static occupancy grid",
    "ltm": "p(occ), long-term memory",
    "stm": "p(occ), short-term memory",
    "best_particle_belief": "p(occ) now, the pose filter's best particle",
    "best_particle_predicted": "p(occ) at the prediction horizon, the best particle",
}
UNKNOWN_COLOUR = "#d9d9d9"
MIN_LOG_VALUE = 1e-6


class InputError(Exception):
    """A file that cannot be rendered; the message names it."""


def read_values(path):
    """The layer in `path` as a 2-D float array (row 0 = bottom)."""
    try:
        values = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError) as error:
        raise InputError(f"{path}: not a readable .npy file: {error}") from None
    if values.ndim != 2 or values.dtype.kind != "f":
        raise InputError(f"{path}: expected a 2-D float array, found {values.ndim}-D {values.dtype}")
    return values.astype(np.float64)


def read_geometry(npy_path):
    """(resolution, origin x, origin y) from the map_server YAML next to the .npy, or None."""
    path = os.path.splitext(npy_path)[0] + ".yaml"
    if not os.path.isfile(path):
        return None
    with open(path) as file:
        text = file.read()
    resolution = re.search(r"^resolution:\s*([-+0-9.eE]+)\s*$", text, re.MULTILINE)
    origin = re.search(r"^origin:\s*\[\s*([-+0-9.eE]+)\s*,\s*([-+0-9.eE]+)", text, re.MULTILINE)
    if not resolution or not origin or not float(resolution.group(1)) > 0:
        raise InputError(f"{path}: no positive resolution and origin [x, y, yaw]")
    return float(resolution.group(1)), float(origin.group(1)), float(origin.group(2))


def colour_scale(name, values):
    """(norm, colormap, colour bar label) for the layer `name`."""
    if name in TRANSITION_LAYERS:
        positive = values[np.isfinite(values) & (values > 0)]
        low = max(float(positive.min()) if positive.size else MIN_LOG_VALUE, MIN_LOG_VALUE)
        high = max(float(positive.max()) if positive.size else 1.0, 10 * low)
        colormap = plt.get_cmap("viridis").copy()
        colormap.set_under("#000000")
        return LogNorm(vmin=low, vmax=high), colormap, TRANSITION_LAYERS[name] + " (log scale)"
    colormap = plt.get_cmap("magma_r").copy()
    return Normalize(vmin=0.0, vmax=1.0), colormap, PROBABILITY_LAYERS.get(name, name)


def nice_length(span):
    """A scale bar length of 1, 2 or 5 times a power of ten, about a fifth of `span`."""
    target = span / 5.0
    power = 10.0 ** math.floor(math.log10(target))
    for factor in (5.0, 2.0, 1.0):
        if factor * power <= target:
            return factor * power
    return power


def draw(figure, axes, npy_path):
    """Draws one layer into `axes` with its colour bar; returns (norm, label)."""
    name = os.path.splitext(os.path.basename(npy_path))[0]
    values = read_values(npy_path)
    geometry = read_geometry(npy_path)
    rows, cols = values.shape
    if geometry is None:
        resolution, x0, y0, unit = 1.0, 0.0, 0.0, "cells"
    else:
        resolution, x0, y0 = geometry
        unit = "m"
    width, height = max(cols, 1) * resolution, max(rows, 1) * resolution
    norm, colormap, label = colour_scale(name, values)
    colormap.set_bad(UNKNOWN_COLOUR)
    image = axes.imshow(np.ma.masked_invalid(values) if values.size else np.full((1, 1), np.nan),
                        origin="lower", extent=(x0, x0 + width, y0, y0 + height), cmap=colormap, norm=norm,
                        interpolation="nearest")
    below = isinstance(norm, LogNorm) and bool((values[np.isfinite(values)] < norm.vmin).any())
    bar = figure.colorbar(image, ax=axes, extend="min" if below else "neither")
    bar.set_label(label)
    axes.set_xlabel(f"x ({unit})")
    axes.set_ylabel(f"y ({unit})")
    observed = int(np.isfinite(values).sum())
    axes.set_title(f"{name}: {cols} \u00d7 {rows} cells, {observed} observed (grey: never observed)", fontsize=10)
    length = nice_length(width)
    text = f"{length:g} {unit}"
    axes.add_artist(AnchoredSizeBar(axes.transData, length, text, "lower right", pad=0.5, color="black",
                                    frameon=True, size_vertical=max(height / 150.0, 1e-9)))
    return norm, label


def save(figure, png_path, dpi):
    """Writes the figure atomically (a temporary file renamed)."""
    figure.tight_layout()
    temporary = png_path + ".tmp.png"
    figure.savefig(temporary, dpi=dpi)
    plt.close(figure)
    os.replace(temporary, png_path)


def figure_height(npy_path, width):
    """A height for a panel `width` inches wide showing the layer's map."""
    values = read_values(npy_path)
    geometry = read_geometry(npy_path)
    resolution = 1.0 if geometry is None else geometry[0]
    rows, cols = values.shape
    aspect = (max(rows, 1) * resolution) / (max(cols, 1) * resolution)
    return min(max(width * aspect * 0.85, 3.0), 12.0)


def render(npy_path, png_path, dpi=120):
    """Renders one layer; returns the figure's (norm, label) for the caller's report."""
    figure, axes = plt.subplots(figsize=(7.5, figure_height(npy_path, 7.5)))
    result = draw(figure, axes, npy_path)
    save(figure, png_path, dpi)
    return result


def render_side_by_side(npy_paths, png_path, dpi=120):
    """Renders the layers in one row of panels, in the order given, into one PNG."""
    figure, axes = plt.subplots(1, len(npy_paths), figsize=(6.5 * len(npy_paths), figure_height(npy_paths[0], 6.5)),
                                squeeze=False)
    for panel, path in zip(axes[0], npy_paths):
        draw(figure, panel, path)
    save(figure, png_path, dpi)


def npy_files(paths):
    """The .npy files among `paths`, directories expanded (sorted)."""
    found = []
    for path in paths:
        if os.path.isdir(path):
            found += sorted(os.path.join(path, f) for f in os.listdir(path) if f.endswith(".npy"))
        else:
            found.append(path)
    return found


def main(argv=None):
    parser = argparse.ArgumentParser(description="Renders <layer>.npy files as colour PNGs (<layer>_values.png).")
    parser.add_argument("paths", nargs="+", metavar="DIR_OR_NPY", help=".npy files or directories holding them")
    parser.add_argument("--out", metavar="DIR", help="write the PNGs here (default: next to each .npy)")
    parser.add_argument("--dpi", type=int, default=120, help="resolution of the PNGs (default 120)")
    parser.add_argument("--side-by-side", metavar="PNG",
                        help="instead, one PNG with the .npy files given side by side, in their order")
    args = parser.parse_args(argv)
    if args.dpi <= 0:
        parser.error("--dpi must be positive")
    files = npy_files(args.paths)
    if not files:
        print("no .npy files in " + " ".join(args.paths), file=sys.stderr)
        return 1
    if args.side_by_side:
        try:
            render_side_by_side(files, args.side_by_side, args.dpi)
        except InputError as error:
            print(f"error: {error}", file=sys.stderr)
            return 1
        print(f"{args.side_by_side} ({len(files)} layers side by side)")
        return 0
    if args.out:
        os.makedirs(args.out, exist_ok=True)
    failed = False
    for path in files:
        directory = args.out or os.path.dirname(path) or "."
        png = os.path.join(directory, os.path.splitext(os.path.basename(path))[0] + "_values.png")
        try:
            norm, _ = render(path, png, args.dpi)
        except InputError as error:
            print(f"error: {error}", file=sys.stderr)
            failed = True
            continue
        scale = "log" if isinstance(norm, LogNorm) else "linear"
        print(f"{png} ({scale} colour scale {norm.vmin:.3g} .. {norm.vmax:.3g})")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
