#!/usr/bin/env python3
"""Checks the layers' .npy files and scripts/render_layers.py.

The test tool write_npy_cli (test/tools, built by test/core_standalone) writes two layers
through the core's export; numpy must read its .npy files exactly (dtype '<f4', shape rows x
cols, row 0 at the bottom, NaN kept), and the script run as a command must render them as
colour PNGs (log colour scale for the transition layer), skip nothing, and refuse damaged
files with a message naming them (exit status 1, no PNG for them).

Plain unittest with /usr/bin/python3 (numpy, matplotlib):
    /usr/bin/python3 test/python/test_render_layers.py WRITE_NPY_CLI [-v]
"""

import os
import shutil
import subprocess
import sys
import tempfile
import unittest

import numpy as np

SCRIPTS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "scripts")
SCRIPT = os.path.join(SCRIPTS, "render_layers.py")
sys.path.insert(0, SCRIPTS)
import render_layers  # noqa: E402  (after the path is set; chooses the Agg backend)
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.colors import LogNorm  # noqa: E402

CLI = None
ROWS, COLS = 5, 7
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def expected_layers():
    """write_npy_cli's formula (see test/tools/write_npy_cli.cpp)."""
    belief = np.empty((ROWS, COLS), dtype=np.float32)
    transitions = np.empty((ROWS, COLS), dtype=np.float32)
    for r in range(ROWS):
        for c in range(COLS):
            i = r * COLS + c
            unknown = (r + c) % 5 == 0
            belief[r, c] = np.nan if unknown else np.float32(i / 35.0)
            transitions[r, c] = np.nan if unknown else np.float32(2.0 ** -(1 + i % 16))
    return {"belief": belief, "p_occ_given_free": transitions}


def read_png(path):
    """(width, height, RGB pixels 0..255) of a PNG file."""
    with open(path, "rb") as file:
        assert file.read(8) == PNG_SIGNATURE, path
    image = np.round(plt.imread(path)[..., :3] * 255).astype(np.int32)
    return image.shape[1], image.shape[0], image


class TestRenderLayers(unittest.TestCase):

    def setUp(self):
        self.tmp = tempfile.mkdtemp(prefix="dog_render_layers_")
        self.layers = os.path.join(self.tmp, "layers")
        os.mkdir(self.layers)
        done = subprocess.run([CLI, self.layers], capture_output=True, text=True)
        self.assertEqual(done.returncode, 0, done.stderr)

    def tearDown(self):
        shutil.rmtree(self.tmp, ignore_errors=True)

    def run_script(self, *args):
        return subprocess.run([sys.executable, SCRIPT, *args], capture_output=True, text=True)

    def test_numpy_reads_the_core_npy_exactly(self):
        for name, expected in expected_layers().items():
            values = np.load(os.path.join(self.layers, f"{name}.npy"), allow_pickle=False)
            self.assertEqual(values.dtype, np.dtype("<f4"), name)
            self.assertEqual(values.shape, (ROWS, COLS), name)
            self.assertFalse(np.isfortran(values), name)
            np.testing.assert_array_equal(np.isnan(values), np.isnan(expected), name)
            known = ~np.isnan(expected)
            np.testing.assert_array_equal(values[known], expected[known], name)
            # Row 0 is the bottom: the PGM (north up) is the same map upside down.
            with open(os.path.join(self.layers, f"{name}.pgm"), "rb") as file:
                pgm = file.read()
            upright = np.frombuffer(pgm[-ROWS * COLS:], dtype=np.uint8).reshape(ROWS, COLS)[::-1]
            self.assertTrue((upright[~known] == 205).all(), f"{name}: the PGM's unknown cells are elsewhere")
            free = 0.2 if name == "belief" else 0.02  # free: <= 25 of 100; the transitions at 0.1 = 100
            self.assertTrue((upright[known & (values < free)] == 254).all(), name)

    def test_renders_colour_pngs_with_the_right_scales(self):
        out = os.path.join(self.tmp, "png")
        done = self.run_script(self.layers, "--out", out)
        self.assertEqual(done.returncode, 0, done.stdout + done.stderr)
        self.assertEqual(sorted(os.listdir(out)), ["belief_values.png", "p_occ_given_free_values.png"])
        self.assertIn("log colour scale", done.stdout)
        self.assertIn("linear colour scale 0 .. 1", done.stdout)
        for name in ("belief", "p_occ_given_free"):
            width, height, pixels = read_png(os.path.join(out, f"{name}_values.png"))
            self.assertGreater(width, 400)
            self.assertGreater(height, 200)
            colours = {tuple(p) for p in pixels.reshape(-1, 3)[::7]}
            chromatic = [c for c in colours if max(c) - min(c) > 60]
            self.assertGreater(len(chromatic), 20, f"{name}: not a colour image")
            self.assertIn((0xd9, 0xd9, 0xd9), colours, f"{name}: no grey for the unknown cells")
        # The transition layer on a log scale over its values, metres from the YAML.
        norm, label = render_layers.render(os.path.join(self.layers, "p_occ_given_free.npy"),
                                           os.path.join(self.tmp, "t.png"))
        self.assertIsInstance(norm, LogNorm)
        self.assertEqual(norm.vmin, 2.0 ** -16)
        self.assertEqual(norm.vmax, 0.5)
        self.assertIn("log", label)
        # The pose filter's best particle's layers (process_bag --pose-correction) are named.
        for name in ("best_particle_belief", "best_particle_predicted"):
            norm, _, label = render_layers.colour_scale(name, np.array([[0.2, 0.9]]))
            self.assertEqual((norm.vmin, norm.vmax), (0.0, 1.0))
            self.assertIn("best particle", label)
        self.assertEqual(render_layers.read_geometry(os.path.join(self.layers, "belief.npy")),
                         (0.1, -0.3, 1.2))
        self.assertEqual(render_layers.nice_length(0.7), 0.1)
        self.assertEqual(render_layers.nice_length(60.0), 10.0)

    def test_side_by_side_is_one_png_with_a_panel_per_layer(self):
        both = os.path.join(self.tmp, "both.png")
        belief = os.path.join(self.layers, "belief.npy")
        transitions = os.path.join(self.layers, "p_occ_given_free.npy")
        done = self.run_script(belief, transitions, "--side-by-side", both)
        self.assertEqual(done.returncode, 0, done.stdout + done.stderr)
        self.assertIn("2 layers side by side", done.stdout)
        self.assertEqual(sorted(f for f in os.listdir(self.layers) if f.endswith(".png")), [])  # nothing else
        single = os.path.join(self.tmp, "single.png")
        render_layers.render_side_by_side([belief], single)
        width, height, pixels = read_png(both)
        single_width, single_height, _ = read_png(single)
        self.assertEqual(height, single_height)
        self.assertGreater(width, 1.8 * single_width)
        # The left panel is the belief's (magma), the right one the transitions' (viridis):
        # the greenish colours of viridis only on the right.
        green = (pixels[..., 1] > pixels[..., 0] + 40) & (pixels[..., 1] > pixels[..., 2])
        self.assertGreater(green[:, width // 2:].sum(), 100)
        self.assertEqual(green[:, :width // 2].sum(), 0)
        done = self.run_script(os.path.join(self.tmp, "missing.npy"), "--side-by-side", both)
        self.assertNotEqual(done.returncode, 0)

    def test_next_to_the_files_and_without_yaml(self):
        os.remove(os.path.join(self.layers, "belief.yaml"))
        done = self.run_script(os.path.join(self.layers, "belief.npy"))
        self.assertEqual(done.returncode, 0, done.stderr)
        self.assertTrue(os.path.isfile(os.path.join(self.layers, "belief_values.png")))
        self.assertIsNone(render_layers.read_geometry(os.path.join(self.layers, "belief.npy")))

    def test_damaged_files_are_refused(self):
        bad = os.path.join(self.tmp, "bad")
        os.mkdir(bad)
        with open(os.path.join(bad, "garbage.npy"), "wb") as file:
            file.write(b"not an npy file at all")
        with open(os.path.join(self.layers, "belief.npy"), "rb") as file:
            good = file.read()
        with open(os.path.join(bad, "truncated.npy"), "wb") as file:
            file.write(good[:len(good) - 9])
        np.save(os.path.join(bad, "one_d.npy"), np.zeros(4, dtype=np.float32))
        np.save(os.path.join(bad, "ints.npy"), np.zeros((2, 2), dtype=np.int32))
        shutil.copy(os.path.join(self.layers, "belief.npy"), os.path.join(bad, "fine.npy"))
        done = self.run_script(bad)
        self.assertEqual(done.returncode, 1, done.stdout + done.stderr)
        for name in ("garbage", "truncated", "one_d", "ints"):
            self.assertIn(f"{name}.npy", done.stderr)
            self.assertFalse(os.path.exists(os.path.join(bad, f"{name}_values.png")), name)
        self.assertTrue(os.path.isfile(os.path.join(bad, "fine_values.png")))
        self.assertEqual([f for f in os.listdir(bad) if ".tmp" in f], [])
        empty = os.path.join(self.tmp, "empty")
        os.mkdir(empty)
        self.assertEqual(self.run_script(empty).returncode, 1)
        self.assertEqual(self.run_script(self.layers, "--dpi", "0").returncode, 2)


if __name__ == "__main__":
    if len(sys.argv) > 1 and not sys.argv[1].startswith("-"):
        CLI = os.path.abspath(sys.argv.pop(1))
    if not CLI:
        print("usage: test_render_layers.py WRITE_NPY_CLI [unittest options]", file=sys.stderr)
        sys.exit(2)
    unittest.main()
