#!/usr/bin/env python3
"""Checks scripts/plot_evaluation.py on small synthetic inputs.

The evaluation's CSV files and process_bag's map_server layers are written here by hand, the
script is run as a command (as a user runs it), and its PNG files are checked: present,
valid PNG of a plausible size, the methods' colours drawn; missing inputs skipped with a
note; malformed ones an error naming the file (exit status 1, no PNG written). Where a
property cannot be seen in a PNG (the layers' extent in metres), the module's plotting
function is called directly.

Plain unittest with /usr/bin/python3 (numpy, matplotlib, PyYAML):
    /usr/bin/python3 test/python/test_plot_evaluation.py [-v]
"""

import os
import shutil
import struct
import subprocess
import sys
import tempfile
import unittest

import numpy as np

SCRIPTS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "scripts")
SCRIPT = os.path.join(SCRIPTS, "plot_evaluation.py")
sys.path.insert(0, SCRIPTS)
import plot_evaluation  # noqa: E402  (after the path is set; chooses the Agg backend)
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.colors import to_rgb  # noqa: E402

ACCURACY_SCENARIOS = ("dynamic_5_5", "dynamic_25_25", "redraw_100", "redraw_300", "parking_lot")
METHODS = ("static", "static_unclamped", "online", "offline", "oracle")
PLANNING_METHODS = ("static", "online", "offline", "random", "optimal")
PLANNING_CLASSES = ("short", "long", "indirect_long", "unnecessary_indirect_long", "unnecessary_direct_long",
                    "effectiveness")
LAYERS = ("belief", "predicted", "stationary", "p_occ_given_free", "p_free_given_occ", "static_map")
ALL_FIGURES = tuple(f"accuracy_{s}.png" for s in ACCURACY_SCENARIOS) + (
    "fig4.png", "fig5.png", "parameter_error.png", "path_planning.png", "mrf_rmse.png", "mrf_maps.png")
MURPHY_FIGURES = ("murphy_corridor_fig2.png", "murphy_corridor_fig3.png", "murphy_corridor_fig4.png",
                  "murphy_corridor_tv.png")
ALL_FIGURES += MURPHY_FIGURES + ("murphy_doors.png",)
DOORS_HEADER = "run,x,y,cell,entropy_visits,entropy_p_occ,random_visits,random_p_occ"
MURPHY_ESTIMATORS = ("exact", "dead_reckoning", "online_em", "offline_em", "rbpf", "rbpf_optimal")
MRF_RMSE_HEADER = ("repetition,world_seed,run_seed,method,sparse_cells,sparse_p_occ_given_free_rmse,"
                   "sparse_p_free_given_occ_rmse,well_observed_cells,well_observed_p_occ_given_free_rmse,"
                   "well_observed_p_free_given_occ_rmse,em_iterations,newton_iterations,em_seconds")
MRF_MAPS_HEADER = ("x,y,observed_steps,truth_p_occ_given_free,truth_p_free_given_occ,plain_p_occ_given_free,"
                   "plain_p_free_given_occ,mrf_p_occ_given_free,mrf_p_free_given_occ")
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def write_accuracy(directory, scenario, steps=120):
    rng = np.random.default_rng(len(scenario))
    with open(os.path.join(directory, f"accuracy_{scenario}.csv"), "w") as file:
        file.write("step," + ",".join(f"{m}_mean,{m}_std" for m in METHODS) + "\n")
        for step in range(steps):
            values = []
            for index in range(len(METHODS)):
                values += [f"{80 + 3 * index + rng.normal(0, 0.5):.3f}", f"{1 + 0.3 * index:.3f}"]
            file.write(f"{step}," + ",".join(values) + "\n")


def write_parameter_error(directory):
    with open(os.path.join(directory, "parameter_error.csv"), "w") as file:
        file.write("scenario,method,dynamic_cells,dynamic_p_occ_given_free_mae,dynamic_p_free_given_occ_mae,"
                   "static_cells,static_p_occ_given_free_mae,static_p_free_given_occ_mae\n")
        for scenario in ACCURACY_SCENARIOS:
            # Two rows per scenario and method: repetitions, plotted as mean and spread.
            for repetition in range(2):
                file.write(f"{scenario},online,93,{0.02 + 0.001 * repetition},0.021,1800,0.0004,0.0005\n")
                file.write(f"{scenario},offline,93,{0.004 + 0.001 * repetition},0.005,1800,0.0001,0.0001\n")


def write_path_planning(directory):
    with open(os.path.join(directory, "path_planning.csv"), "w") as file:
        file.write("class," + ",".join(f"{m}_mean,{m}_std" for m in PLANNING_METHODS) + ","
                   + ",".join(f"paper_{m}" for m in PLANNING_METHODS) + "\n")
        for index, name in enumerate(PLANNING_CLASSES):
            # The paper leaves static's "unnecessary indirect long" empty: an empty cell.
            paper = ["" if name == "unnecessary_indirect_long" and m == "static" else f"{10 + index}"
                     for m in PLANNING_METHODS]
            file.write(f"{name}," + ",".join(f"{20 + index},{2 + index}" for _ in PLANNING_METHODS) + ","
                       + ",".join(paper) + "\n")


def write_mrf_rmse(directory):
    with open(os.path.join(directory, "mrf_rmse.csv"), "w") as file:
        file.write(MRF_RMSE_HEADER + "\n")
        for repetition in range(3):
            file.write(f"{repetition},11,12,plain,300,{0.024 + 0.001 * repetition},0.041,735,0.0096,0.055,300,0,0.1\n")
            file.write(f"{repetition},11,12,mrf,300,{0.016 + 0.001 * repetition},0.030,735,0.0090,0.054,170,1900,0.7\n")


def write_mrf_maps(directory, width=12, height=8):
    """A map with one dynamic square: truth 0.125 there, 0 elsewhere; the left column never
    observed (its learned values empty)."""
    with open(os.path.join(directory, "mrf_maps.csv"), "w") as file:
        file.write(MRF_MAPS_HEADER + "\n")
        for y in range(height):
            for x in range(width):
                truth = 0.125 if 6 <= x < 9 and 2 <= y < 5 else 0.0
                if x == 0:
                    file.write(f"{x},{y},0,{truth},{truth},,,,\n")
                    continue
                learned = max(truth, 1e-4) * (1.0 + 0.1 * ((x + y) % 3))
                file.write(f"{x},{y},{x + y},{truth},{truth},{learned},{learned},{learned},{learned}\n")


def corridor_value(t, cell, column):
    """A synthetic probability for step t, cell `cell` (1-based) of a corridor table."""
    if column in ("truth", "true_position"):
        return 1 if cell == min(t, 4) else 0
    if column == "true_label":
        return (cell + 1) % 2
    return round(0.1 + 0.8 * ((t * 7 + cell * 3 + len(column)) % 10) / 10.0, 4)


def write_murphy(directory, steps=5, cells=4):
    """Murphy's corridor tables as evaluate writes them (evaluation/murphy_corridor_report.cpp),
    1-based t and cells, on a small corridor."""
    columns = {
        "fig2_cells": ("truth", "exact", "online_em", "online_em_no_smoothing", "offline_em", "offline_em_smoothed",
                       "rbpf", "rbpf_optimal"),
        "fig3_position": ("truth", "exact", "dead_reckoning", "online_em", "online_em_no_smoothing", "offline_em",
                          "rbpf", "rbpf_optimal", "exact_smoothed", "offline_em_smoothed"),
        "fig4_rbpf": ("true_position", "exact_position", "rbpf_position", "rbpf_optimal_position", "true_label",
                      "exact_p_one", "rbpf_p_one", "rbpf_optimal_p_one"),
    }
    for name, names in columns.items():
        with open(os.path.join(directory, f"murphy_corridor_{name}.csv"), "w") as file:
            file.write("t,cell," + ",".join(names) + "\n")
            for t in range(1, steps + 1):
                for cell in range(1, cells + 1):
                    file.write(f"{t},{cell}," + ",".join(str(corridor_value(t, cell, c)) for c in names) + "\n")
    with open(os.path.join(directory, "murphy_corridor_fig2_maps.csv"), "w") as file:
        file.write("t,map,labels,probability\n")
        for t in range(1, steps + 1):
            for m in range(2 ** cells):
                labels = "".join(str((m >> i) & 1) for i in range(cells))
                file.write(f"{t},{m},{labels},{1.0 if m == t else 0.0}\n")
    with open(os.path.join(directory, "murphy_corridor_errors.csv"), "w") as file:
        file.write("variant,estimator,t,position_tv_mean,position_tv_std,truth_mass_mean,map_error_mean,"
                   "map_truth_error_mean,runs\n")
        for variant in ("paper", "simulated_static"):
            for index, estimator in enumerate(MURPHY_ESTIMATORS):
                for t in range(1, steps + 1):
                    tv = 0.0 if estimator == "exact" else 0.1 * index + 0.02 * t
                    map_error = "" if estimator == "dead_reckoning" else "0.05"
                    file.write(f"{variant},{estimator},{t},{tv},0.02,{0.9 - 0.1 * index},{map_error},0.2,3\n")


def write_doors(directory, width=7, height=5):
    """murphy_doors_maps.csv: a walled box with one door in the middle."""
    with open(os.path.join(directory, "murphy_doors_maps.csv"), "w") as file:
        file.write(DOORS_HEADER + "\n")
        for y in range(height):
            for x in range(width):
                border = x in (0, width - 1) or y in (0, height - 1)
                cell = "door" if (x, y) == (width // 2, height // 2) else "wall" if border else "free"
                visits = 0 if cell == "wall" else x * y
                file.write(f"3,{x},{y},{cell},{visits},{1.0 if border else 0.1},{visits // 2},0.5\n")


def write_all(directory):
    for scenario in ACCURACY_SCENARIOS:
        # The parking lot long enough for a few of its 108-step hours.
        write_accuracy(directory, scenario, 400 if scenario == "parking_lot" else 120)
    write_parameter_error(directory)
    write_path_planning(directory)
    write_mrf_rmse(directory)
    write_mrf_maps(directory)
    write_murphy(directory)
    write_doors(directory)


def write_layer(directory, name, width=40, height=30, resolution=0.05, origin=(-1.0, 2.0)):
    """A trinary map_server layer as process_bag writes it (with a comment line)."""
    pixels = np.full((height, width), 205, dtype=np.uint8)
    pixels[5:25, 5:35] = 254
    pixels[5, 5:35] = 0
    with open(os.path.join(directory, f"{name}.pgm"), "wb") as file:
        file.write(f"P5\n# dynamic_occupancy_grid {name}\n{width} {height}\n255\n".encode() + pixels.tobytes())
    with open(os.path.join(directory, f"{name}.yaml"), "w") as file:
        file.write(f"image: {name}.pgm\nresolution: {resolution}\norigin: [{origin[0]}, {origin[1]}, 0.0]\n"
                   "negate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n")


def png_size(path):
    """(width, height) of a PNG file; AssertionError if it is not one."""
    with open(path, "rb") as file:
        head = file.read(24)
    assert head[:8] == PNG_SIGNATURE and head[12:16] == b"IHDR", f"{path} is not a PNG"
    return struct.unpack(">II", head[16:24])


def has_colour(path, colour, tolerance=0.02):
    """Whether some pixel of the PNG at `path` has the colour `colour`."""
    image = plt.imread(path)[..., :3]
    return bool((np.abs(image - np.array(to_rgb(colour))).max(axis=-1) < tolerance).any())


class TestPlotEvaluation(unittest.TestCase):
    def setUp(self):
        self.tmp = tempfile.mkdtemp(prefix="test_plot_evaluation_")

    def tearDown(self):
        shutil.rmtree(self.tmp, ignore_errors=True)

    def run_script(self, *args):
        result = subprocess.run([sys.executable, SCRIPT] + list(args), capture_output=True, text=True, timeout=300)
        return result.returncode, result.stdout, result.stderr

    def pngs(self, directory):
        return sorted(name for name in os.listdir(directory) if name.endswith(".png"))

    def assert_png(self, path, min_width=400, min_height=300):
        self.assertTrue(os.path.isfile(path), f"{path} missing")
        width, height = png_size(path)
        self.assertGreaterEqual(width, min_width, path)
        self.assertGreaterEqual(height, min_height, path)
        self.assertLess(width * height, 4000 * 4000, path)
        self.assertGreater(os.path.getsize(path), 5000, f"{path}: too small to hold a plot")
        return width, height

    # --- the evaluation's figures ------------------------------------------------------------

    def test_all_figures(self):
        write_all(self.tmp)
        rc, stdout, stderr = self.run_script(self.tmp)
        self.assertEqual(rc, 0, stderr)
        self.assertEqual(self.pngs(self.tmp), sorted(ALL_FIGURES))
        for name in ALL_FIGURES:
            width, height = self.assert_png(os.path.join(self.tmp, name))
            self.assertIn(f"wrote {os.path.join(self.tmp, name)}", stdout)
        for name in ("fig4.png", "fig5.png"):  # two panels side by side
            width, height = png_size(os.path.join(self.tmp, name))
            self.assertGreater(width, 2 * height, name)
        self.assertNotIn("note:", stdout)

    def test_methods_have_their_colours(self):
        write_accuracy(self.tmp, "dynamic_5_5")
        write_path_planning(self.tmp)
        write_mrf_rmse(self.tmp)
        rc, _, stderr = self.run_script(self.tmp)
        self.assertEqual(rc, 0, stderr)
        for method in ("plain", "mrf"):
            self.assertTrue(has_colour(os.path.join(self.tmp, "mrf_rmse.png"), plot_evaluation.COLOURS[method]), method)
        for method in METHODS:
            self.assertTrue(has_colour(os.path.join(self.tmp, "accuracy_dynamic_5_5.png"),
                                       plot_evaluation.COLOURS[method]), method)
        for method in PLANNING_METHODS:
            self.assertTrue(has_colour(os.path.join(self.tmp, "path_planning.png"),
                                       plot_evaluation.COLOURS[method]), method)

    def test_missing_files_are_skipped(self):
        write_accuracy(self.tmp, "dynamic_5_5")
        write_accuracy(self.tmp, "redraw_100")
        write_accuracy(self.tmp, "redraw_300")
        rc, stdout, stderr = self.run_script(self.tmp)
        self.assertEqual(rc, 0, stderr)
        self.assertEqual(self.pngs(self.tmp),
                         ["accuracy_dynamic_5_5.png", "accuracy_redraw_100.png", "accuracy_redraw_300.png", "fig5.png"])
        for skipped in ("accuracy_dynamic_25_25.png", "accuracy_parking_lot.png", "fig4.png", "parameter_error.png",
                        "path_planning.png", "mrf_rmse.png", "mrf_maps.png") + MURPHY_FIGURES:
            self.assertRegex(stdout, rf"note: {skipped} skipped")
        self.assertIn("accuracy_dynamic_25_25.csv", stdout)  # what fig4 lacks

    def test_nothing_to_plot_is_an_error(self):
        rc, _, stderr = self.run_script(self.tmp)
        self.assertEqual(rc, 1)
        self.assertIn(self.tmp, stderr)
        missing = os.path.join(self.tmp, "no_such_dir")
        rc, _, stderr = self.run_script(missing)
        self.assertEqual(rc, 1)
        self.assertIn(missing, stderr)

    def test_usage(self):
        rc, _, stderr = self.run_script()
        self.assertEqual(rc, 2)
        self.assertIn("usage:", stderr)

    def test_malformed_csv_is_an_error(self):
        header = "step," + ",".join(f"{m}_mean,{m}_std" for m in METHODS)
        row = ",".join(["1"] + ["90", "1"] * len(METHODS))
        cases = {
            "accuracy_dynamic_5_5.csv": [
                "",                                                     # empty file
                header + "\n",                                          # no rows
                header.replace("oracle_std", "oracle_sd") + "\n" + row,  # a column missing
                header + "\n" + row + ",7\n",                           # a row too long
                header + "\n" + row.replace("90", "ninety", 1) + "\n",  # not a number
                header + "\n" + row + "\n" + row + "\n",                # steps not increasing
            ],
            "parameter_error.csv": [
                "scenario,method,dynamic_cells\ndynamic_5_5,online,93\n",
            ],
            "path_planning.csv": [
                "class," + ",".join(f"{m}_mean,{m}_std" for m in PLANNING_METHODS) + ","
                + ",".join(f"paper_{m}" for m in PLANNING_METHODS)
                + "\nshort,," + ",".join(["1"] * 14) + "\n",  # an empty mean
            ],
            "mrf_rmse.csv": [
                MRF_RMSE_HEADER + "\n0,1,2,plain,3,0.1,0.1,4,0.1,0.1,5,0,0.1\n",       # no MRF rows
                MRF_RMSE_HEADER + "\n0,1,2,plain,3,0.1,,4,0.1,0.1,5,0,0.1\n"           # an empty RMSE
                "0,1,2,mrf,3,0.1,0.1,4,0.1,0.1,5,9,0.5\n",
            ],
            "murphy_corridor_fig3_position.csv": [
                "t,cell,truth,exact\n1,1,1,1\n",                                 # columns missing
                "t,cell," + ",".join(plot_evaluation.MURPHY_POSITION_COLUMNS) + "\n"
                "1,1,1,1,1,1,1,1\n1,1,1,1,1,1,1,1\n",                            # a (t, cell) twice
                "t,cell," + ",".join(plot_evaluation.MURPHY_POSITION_COLUMNS) + "\n"
                "1,1,1,1.5,1,1,1,1\n",                                            # not a probability
            ],
            "murphy_corridor_fig2_maps.csv": [
                "t,map,labels,probability\n1,0,00,0.5\n1,2,01,0.5\n",             # map 1 missing
            ],
            "murphy_doors_maps.csv": [
                DOORS_HEADER + "\n3,0,0,wall,0,1,0,1\n3,0,0,wall,0,1,0,1\n",           # a cell twice
                DOORS_HEADER + "\n3,0,0,wall,0,1,0,1\n3,1,1,wall,0,1,0,1\n",           # cells missing
                DOORS_HEADER + "\n3,0,0,lava,0,1,0,1\n",                               # not a kind of cell
                DOORS_HEADER + "\n3,0.5,0,wall,0,1,0,1\n",                             # not a cell
            ],
            "mrf_maps.csv": [
                MRF_MAPS_HEADER + "\n0,0,1,0,0,0.1,0.1,0.1,0.1\n0,0,1,0,0,0.1,0.1,0.1,0.1\n",  # a cell twice
                MRF_MAPS_HEADER + "\n0,0,1,0,0,0.1,0.1,0.1,0.1\n1,1,1,0,0,0.1,0.1,0.1,0.1\n",  # cells missing
                MRF_MAPS_HEADER + "\n0.5,0,1,0,0,0.1,0.1,0.1,0.1\n",                            # not a cell
                MRF_MAPS_HEADER + "\n0,0,1,,0,0.1,0.1,0.1,0.1\n",                               # no truth
            ],
        }
        for name, contents in cases.items():
            for content in contents:
                directory = tempfile.mkdtemp(dir=self.tmp)
                write_all(directory)
                path = os.path.join(directory, name)
                with open(path, "w") as file:
                    file.write(content)
                rc, stdout, stderr = self.run_script(directory)
                self.assertEqual(rc, 1, f"{name} {content[-60:]!r}: exit {rc}\n{stdout}\n{stderr}")
                self.assertIn(path, stderr)
                self.assertNotIn("Traceback", stderr)
                self.assertEqual(self.pngs(directory), [], "figures written despite the error")

    def test_mrf_maps_are_the_csv_cells(self):
        write_mrf_maps(self.tmp, width=12, height=8)
        grids = plot_evaluation.read_mrf_maps(os.path.join(self.tmp, "mrf_maps.csv"))
        self.assertEqual(grids["truth_p_occ_given_free"].shape, (8, 12))  # indexed [y, x]
        self.assertEqual(grids["truth_p_occ_given_free"][3, 7], 0.125)
        self.assertEqual(grids["truth_p_occ_given_free"][7, 7], 0.0)
        self.assertTrue(np.isnan(grids["mrf_p_free_given_occ"][:, 0]).all())  # never observed
        self.assertFalse(np.isnan(grids["mrf_p_free_given_occ"][:, 1:]).any())
        self.assertEqual(grids["observed_steps"][5, 4], 9)
        # Drawn as six panels (two parameters by truth, plain EM, MRF), wider than high.
        rc, _, stderr = self.run_script(self.tmp)
        self.assertEqual(rc, 0, stderr)
        width, height = self.assert_png(os.path.join(self.tmp, "mrf_maps.png"))
        self.assertGreater(width, height)

    def test_murphy_grids_are_the_csv_cells(self):
        write_murphy(self.tmp, steps=5, cells=4)
        grids = plot_evaluation.read_step_grid(os.path.join(self.tmp, "murphy_corridor_fig3_position.csv"),
                                               plot_evaluation.MURPHY_POSITION_COLUMNS)
        self.assertEqual(grids["exact"].shape, (4, 5))  # [cell - 1, t - 1]
        self.assertEqual(grids["exact"][2, 3], corridor_value(4, 3, "exact"))
        self.assertEqual(grids["truth"][3, 4], 1)
        maps = plot_evaluation.read_step_grid(os.path.join(self.tmp, "murphy_corridor_fig2_maps.csv"),
                                              ("probability",), key="map")
        self.assertEqual(maps["probability"].shape, (16, 5))  # maps 0-based
        self.assertEqual(maps["probability"][3, 2], 1.0)  # step 3's mass on map 3
        rc, stdout, stderr = self.run_script(self.tmp)
        self.assertEqual(rc, 0, stderr)
        self.assertEqual(self.pngs(self.tmp), sorted(MURPHY_FIGURES))
        for name in MURPHY_FIGURES:
            width, height = self.assert_png(os.path.join(self.tmp, name))
            self.assertGreater(width, height, name)
        for _, _, colour in plot_evaluation.MURPHY_TV_ESTIMATORS:
            self.assertTrue(has_colour(os.path.join(self.tmp, "murphy_corridor_tv.png"), colour), colour)

    # --- the map layers ------------------------------------------------------------------------

    def test_layers(self):
        for name in LAYERS:
            write_layer(self.tmp, name)
        rc, stdout, stderr = self.run_script("--layers", self.tmp)
        self.assertEqual(rc, 0, stderr)
        self.assertEqual(self.pngs(self.tmp), sorted(f"{name}.png" for name in LAYERS + ("layers",)))
        for name in LAYERS:
            self.assert_png(os.path.join(self.tmp, f"{name}.png"))
        width, height = self.assert_png(os.path.join(self.tmp, "layers.png"))
        self.assertGreater(width, height)  # three panels by two

    def test_layers_are_in_metres(self):
        write_layer(self.tmp, "belief", width=40, height=30, resolution=0.05, origin=(-1.0, 2.0))
        layer = plot_evaluation.read_map(self.tmp, "belief")
        figure, axes = plt.subplots()
        plot_evaluation.show_map(axes, layer, "belief")
        np.testing.assert_allclose(axes.get_xlim(), (-1.0, 1.0))
        np.testing.assert_allclose(axes.get_ylim(), (2.0, 3.5))
        # The image's first row (north) is drawn at the top.
        image = axes.get_images()[0]
        self.assertEqual(image.origin, "upper")
        plt.close(figure)

    def test_missing_layers_are_skipped(self):
        write_layer(self.tmp, "belief")
        rc, stdout, stderr = self.run_script("--layers", self.tmp)
        self.assertEqual(rc, 0, stderr)
        self.assertEqual(self.pngs(self.tmp), ["belief.png", "layers.png"])
        self.assertIn("note: static_map.png skipped", stdout)

    def test_malformed_layer_is_an_error(self):
        for name, damage in (("belief.pgm", lambda data: data[:-100]),      # truncated pixels
                             ("belief.pgm", lambda data: b"P2" + data[2:]),  # not binary
                             ("belief.yaml", lambda data: data.replace(b"resolution: 0.05", b"resolution: x"))):
            directory = tempfile.mkdtemp(dir=self.tmp)
            for layer in LAYERS:
                write_layer(directory, layer)
            path = os.path.join(directory, name)
            with open(path, "rb") as file:
                data = file.read()
            with open(path, "wb") as file:
                file.write(damage(data))
            rc, _, stderr = self.run_script("--layers", directory)
            self.assertEqual(rc, 1, f"{name}: exit {rc}\n{stderr}")
            self.assertIn(path, stderr)
            self.assertNotIn("Traceback", stderr)
            self.assertEqual(self.pngs(directory), [])

    def test_both_at_once(self):
        evaluation, layers = os.path.join(self.tmp, "evaluation"), os.path.join(self.tmp, "layers")
        os.mkdir(evaluation)
        os.mkdir(layers)
        write_accuracy(evaluation, "dynamic_5_5")
        write_layer(layers, "belief")
        rc, _, stderr = self.run_script(evaluation, "--layers", layers)
        self.assertEqual(rc, 0, stderr)
        self.assertEqual(self.pngs(evaluation), ["accuracy_dynamic_5_5.png"])
        self.assertEqual(self.pngs(layers), ["belief.png", "layers.png"])


if __name__ == "__main__":
    unittest.main()
