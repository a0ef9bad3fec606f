#!/usr/bin/env python3
"""Checks scripts/read_model.py against the C++ core, value for value.

Usage:
    test_read_model.py WRITE_MODEL_CLI [unittest options]

WRITE_MODEL_CLI is the test tool (or the environment variable DOG_WRITE_MODEL_CLI, e.g. under
pytest; without either the tests are skipped there) test/tools/write_model_cli.cpp: it maps a scripted run,
saves the model with core::saveModel and writes the mapper's configuration, time, sums and
cells as exact text (%a). The reader's config, time, kinds' pair sums and learned transitions
and arrays must equal those exactly (bit for bit for the floats), for either learner, and
version 1 and 2 files built from those bytes must read as the same map; its distance bins
must be the C++ ones; its dense grids must put every cell where it belongs, and damaged files
(truncated, flipped bytes, other magic or version, trailing bytes, bad flags and choices, a
bin count other than 124, bad kinds' sums, learned transitions outside the bounds) must
raise ModelFormatError. Runs with /usr/bin/python3
and numpy; registered as a ctest by test/core_standalone/CMakeLists.txt.
"""

import os
import struct
import subprocess
import sys
import tempfile
import unittest
import zlib

import numpy as np

SCRIPTS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "scripts")
sys.path.insert(0, SCRIPTS)
import read_model  # noqa: E402  (after the path is set)

CLI = os.environ.get("DOG_WRITE_MODEL_CLI")

FLOAT_FIELDS = ("p_occ", "log_odds", "p_occ_given_free", "p_free_given_occ")

# docs/model_format.md, version 3: the kinds' block and the cells.
LEARN_FROM_GAPS_OFFSET = 424
BIN_COUNT_OFFSET = 425
PAIRS_OFFSET = 427
MEMBERSHIP_OFFSET = PAIRS_OFFSET + 8 * 4 * read_model.KIND_COUNT * read_model.GAP_BINS
CELLS_SUM_OFFSET = MEMBERSHIP_OFFSET + 8 * read_model.KIND_COUNT
LEARNED_OFFSET = CELLS_SUM_OFFSET + 8
COUNT_OFFSET = LEARNED_OFFSET + 16 * read_model.KIND_COUNT
CELLS_OFFSET = COUNT_OFFSET + 8
assert (MEMBERSHIP_OFFSET, CELLS_SUM_OFFSET, LEARNED_OFFSET, COUNT_OFFSET, CELLS_OFFSET) == (
    20267, 20307, 20315, 20395, 20403)


def parse_values(path):
    """The CLI's text: (config dict with dotted names, origin, last step, cell columns); the
    sensor model's and the kinds' sums, the kinds' learned transitions and the distance bins
    are in the config as "sensor_model_stats", "kind_sums", "kind_transitions",
    "gap_bin_steps" and "gap_bin"."""
    config = {}
    origin = last = None
    count = None
    rows = []
    header = None
    with open(path) as file:
        for line in file:
            line = line.strip()
            if line.startswith("# config "):
                _, _, name, value = line.split(" ")
                config[name] = value
            elif line.startswith("# clock_origin_s "):
                value = line.split(" ")[2]
                origin = None if value == "none" else float.fromhex(value)
            elif line.startswith("# last_applied_step "):
                value = line.split(" ")[2]
                last = None if value == "none" else int(value)
            elif line.startswith("# sensor_model_stats "):
                values = [float.fromhex(v) for v in line.split(" ")[2:]]
                config["sensor_model_stats"] = dict(zip(("trials_occ", "trials_free", "hits_occ", "hits_free"), values))
            elif line.startswith("# kind_sums "):
                values = [float.fromhex(v) for v in line.split(" ")[2:]]
                assert len(values) == 4 * read_model.KIND_COUNT * read_model.GAP_BINS + read_model.KIND_COUNT + 1, len(
                    values)
                config["kind_sums"] = values
            elif line.startswith("# kind_transitions "):
                values = [float.fromhex(v) for v in line.split(" ")[2:]]
                assert len(values) == 2 * read_model.KIND_COUNT, len(values)
                config["kind_transitions"] = values
            elif line.startswith("# gap_bin_steps "):
                config["gap_bin_steps"] = [float.fromhex(v) for v in line.split(" ")[2:]]
            elif line.startswith("# gap_bin "):
                config["gap_bin"] = [tuple(int(part) for part in v.split(":")) for v in line.split(" ")[2:]]
            elif line.startswith("# cells "):
                count = int(line.split(" ")[2])
            elif header is None:
                header = line.split(",")
            else:
                rows.append(line.split(","))
    assert count == len(rows), (count, len(rows))
    columns = {name: [row[i] for row in rows] for i, name in enumerate(header)}
    cells = {
        "x": np.array([int(v) for v in columns["x"]], dtype=np.int32),
        "y": np.array([int(v) for v in columns["y"]], dtype=np.int32),
        "last_step": np.array([int(v) for v in columns["last_step"]], dtype=np.int32),
        "observed_steps": np.array([int(v) for v in columns["observed_steps"]], dtype=np.uint16),
        "last_hits": np.array([int(v) for v in columns["last_hits"]], dtype=np.uint8),
        "last_misses": np.array([int(v) for v in columns["last_misses"]], dtype=np.uint8),
    }
    for name in FLOAT_FIELDS:
        cells[name] = np.array([float.fromhex(v) for v in columns[name]], dtype=np.float32)
    size = read_model.LEARNER_STATE_SIZE
    cells["learner_state"] = np.array(
        [[float.fromhex(row[header.index(f"learner_state_{k}")]) for k in range(size)] for row in rows],
        dtype=np.float32).reshape(len(rows), size)
    return config, origin, last, cells


def flat_config(config, prefix=""):
    """The reader's nested config with dotted names (a list's entries named by their index)."""
    flat = {}
    for name, value in config.items():
        if isinstance(value, list):
            value = {str(index): entry for index, entry in enumerate(value)}
        if isinstance(value, dict):
            flat.update(flat_config(value, prefix + name + "."))
        else:
            flat[prefix + name] = value
    return flat


def as_version_2(data):
    """A version 3 file as version 2 wrote it: without the learner and kinds block, and 8
    learner floats per cell (a file of learner cell_em is one version 2 could write)."""
    count = struct.unpack_from("<Q", data, COUNT_OFFSET)[0]
    cells = b"".join(data[CELLS_OFFSET + 72 * i:CELLS_OFFSET + 72 * i + 60]
                     + data[CELLS_OFFSET + 72 * i + 68:CELLS_OFFSET + 72 * (i + 1)] for i in range(count))
    v2 = bytearray(data[:268] + data[COUNT_OFFSET:CELLS_OFFSET] + cells + b"\0\0\0\0")
    v2[8:12] = struct.pack("<I", 2)
    return with_checksum(v2)


def as_version_1(v2):
    """A version 2 file as version 1 wrote it: without the learners' block and the cells'
    last evidence."""
    count = struct.unpack_from("<Q", v2, 268)[0]
    cells = b"".join(v2[276 + 64 * i:276 + 64 * i + 62] for i in range(count))
    v1 = bytearray(v2[:189] + v2[268:276] + cells + b"\0\0\0\0")
    v1[8:12] = struct.pack("<I", 1)
    return with_checksum(v1)


def with_checksum(data):
    data = bytearray(data)
    data[-4:] = struct.pack("<I", zlib.crc32(bytes(data[:-4])) & 0xFFFFFFFF)
    return bytes(data)


class ReadModelTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        if not CLI:
            raise unittest.SkipTest("no write_model_cli given (see the usage)")
        cls.directory = tempfile.TemporaryDirectory(prefix="dog_read_model_")
        cls.runs = {}
        for mode in ("growing", "cell-em", "fixed", "empty"):
            model = os.path.join(cls.directory.name, mode + ".dogm")
            values = os.path.join(cls.directory.name, mode + ".txt")
            command = [CLI] + ([] if mode == "growing" else ["--" + mode]) + [model, values]
            subprocess.run(command, check=True)
            cls.runs[mode] = (model, parse_values(values))

    @classmethod
    def tearDownClass(cls):
        cls.directory.cleanup()

    def bytes_of(self, mode):
        with open(self.runs[mode][0], "rb") as file:
            return file.read()

    def expect_error(self, data, *parts):
        with self.assertRaises(read_model.ModelFormatError) as caught:
            read_model.parse_model(data)
        for part in parts:
            self.assertIn(part, str(caught.exception))
        return str(caught.exception)

    # ---- the values are the C++ ones -------------------------------------------------------

    def check_matches_cpp(self, mode, min_cells):
        path, (config, origin, last, cells) = self.runs[mode]
        model = read_model.load_model(path)
        flat = flat_config(model.config)
        config = dict(config)
        stats = config.pop("sensor_model_stats")
        for name, value in stats.items():
            self.assertEqual(struct.pack("<d", model.sensor_model_stats[name]), struct.pack("<d", value), name)
        kind_sums = np.array(config.pop("kind_sums"), dtype=np.float64)
        sums = model.kind_sums
        self.assertEqual(sums["pairs"].shape, (read_model.KIND_COUNT, read_model.GAP_BINS, 2, 2))
        self.assertEqual(sums["pairs"].dtype, np.float64)
        self.assertEqual(sums["membership"].shape, (read_model.KIND_COUNT,))
        # [kind][bin][then][now] is the C++ [kind][bin][2 * then + now].
        mine = np.concatenate([sums["pairs"].ravel(), sums["membership"], [sums["cells"]]])
        self.assertTrue(np.array_equal(mine.view(np.uint64), kind_sums.view(np.uint64)))
        learned = np.array(config.pop("kind_transitions"), dtype=np.float64)
        self.assertEqual(len(model.kind_transitions), read_model.KIND_COUNT)
        mine = np.array([[t["p_occ_given_free"], t["p_free_given_occ"]] for t in model.kind_transitions])
        self.assertTrue(np.array_equal(mine.ravel().view(np.uint64), learned.view(np.uint64)))
        config.pop("gap_bin_steps")
        config.pop("gap_bin")
        self.assertEqual(model.format_version, read_model.FORMAT_VERSION)
        self.assertEqual(sorted(flat), sorted(config))
        for name, text in config.items():
            value = flat[name]
            if isinstance(value, str):
                self.assertEqual(value, text, name)
            elif isinstance(value, bool) or isinstance(value, int):
                self.assertEqual(int(value), int(text), name)
            else:
                self.assertEqual(struct.pack("<d", value), struct.pack("<d", float.fromhex(text)), name)
        if origin is None:
            self.assertIsNone(model.clock_origin_s)
        else:
            self.assertEqual(struct.pack("<d", model.clock_origin_s), struct.pack("<d", origin))
        self.assertEqual(model.last_applied_step, last)
        self.assertGreaterEqual(model.cell_count, min_cells)
        self.assertEqual(model.cell_count, len(cells["x"]))
        # Same cells in the same order (both by row, then column), every value bit for bit.
        for name in read_model.CELL_FIELDS:
            mine = getattr(model, name)
            theirs = cells[name]
            self.assertEqual((mine.dtype.kind, mine.dtype.itemsize), (theirs.dtype.kind, theirs.dtype.itemsize), name)
            self.assertEqual(mine.shape, theirs.shape, name)
            self.assertTrue(mine.flags["C_CONTIGUOUS"], name)
            self.assertTrue(np.array_equal(mine.view(np.uint8), theirs.view(np.uint8)), name)
        order = np.lexsort((model.x, model.y))
        self.assertTrue(np.array_equal(order, np.arange(model.cell_count)))
        self.assertEqual(model["p_occ"] is model.p_occ, True)
        return model

    def test_growing_learning_model_matches_cpp(self):
        model = self.check_matches_cpp("growing", 1000)
        self.assertTrue(model.config["learn_transitions"])
        # Kinds of cells, configured apart from the defaults, learned from the map.
        self.assertEqual(model.learner, "kinds")
        self.assertEqual(model.config["learner"], "kinds")
        self.assertNotEqual(model.config["kinds"], read_model.default_kinds())
        self.assertGreater(model.kind_sums["cells"], 1000.0)
        # Pairs across gaps: in more than one distance bin, changes of state among them.
        pairs = model.kind_sums["pairs"]
        self.assertGreaterEqual(int(np.count_nonzero(pairs.sum(axis=(0, 2, 3)))), 2)
        self.assertGreater(float(pairs[:, :, 0, 1].sum() + pairs[:, :, 1, 0].sum()), 0.0)
        # The kinds' transitions moved from where they started.
        starts = model.config["kinds"]["initial_transitions"]
        self.assertNotEqual(model.kind_transitions, starts)
        # Learning moved transitions away from the prior: the values are not all the same.
        self.assertGreater(len(np.unique(model.p_occ_given_free)), 10)
        # Each cell's learner state is its posterior p(kind, state): a distribution.
        self.assertIsNone(model.em_stats)
        self.assertEqual(model.kind_posterior.shape, (model.cell_count, read_model.KIND_COUNT, 2))
        self.assertTrue(np.array_equal(model.kind_posterior.reshape(model.cell_count, -1), model.learner_state))
        np.testing.assert_allclose(model.kind_posterior.sum(axis=(1, 2)), 1.0, atol=1e-5)
        self.assertEqual(model.kind_posterior[3, 2, 1], model.learner_state[3, 5])  # index 2 * kind + state

    def test_cell_em_model_matches_cpp(self):
        model = self.check_matches_cpp("cell-em", 1000)
        self.assertEqual(model.learner, "cell_em")
        self.assertEqual(model.config["kinds"], read_model.default_kinds())  # the C++ defaults
        self.assertEqual(model.kind_sums["cells"], 0.0)
        # Unused, the kinds keep their initial transitions within the bounds (p_min 1e-4 here).
        low = max(model.config["online_em"]["p_min"], 1e-6)
        self.assertEqual(model.kind_transitions,
                         [{name: max(rate, low) for name, rate in start.items()}
                          for start in read_model.default_kinds()["initial_transitions"]])
        # Each cell's own online EM: its statistics in the first 8 floats, the last two 0.
        self.assertIsNone(model.kind_posterior)
        self.assertEqual(model.em_stats.shape, (model.cell_count, 8))
        self.assertTrue(np.array_equal(model.em_stats, model.learner_state[:, :8]))
        self.assertFalse(np.any(model.learner_state[:, 8:]))
        self.assertGreater(float(model.em_stats.sum()), 0.0)

    def test_fixed_bounds_model_matches_cpp(self):
        model = self.check_matches_cpp("fixed", 500)
        self.assertTrue(model.config["fixed_bounds"])
        self.assertFalse(model.config["learn_transitions"])

    def test_empty_model_matches_cpp(self):
        model = self.check_matches_cpp("empty", 0)
        self.assertEqual(model.cell_count, 0)
        self.assertIsNone(model.clock_origin_s)
        self.assertIsNone(model.last_applied_step)
        self.assertIsNone(model.bounds())
        grid, window = read_model.dense_field(model, "p_occ")
        self.assertEqual(grid.shape, (0, 0))
        self.assertEqual(window["width"], 0)

    def test_version_2_files_are_read_as_each_cells_online_em(self):
        # Built from the file of a map of learner cell_em with the kinds' defaults: everything
        # version 2 holds and the defaults of what it lacks are that map's.
        data = self.bytes_of("cell-em")
        newer = read_model.parse_model(data)
        v2 = as_version_2(data)
        self.assertEqual(len(v2), 280 + 64 * newer.cell_count)
        self.assertEqual(len(data), 20407 + 72 * newer.cell_count)
        model = read_model.parse_model(v2)
        self.assertEqual(model.format_version, 2)
        self.assertEqual(model.learner, "cell_em")
        self.assertEqual(flat_config(model.config), flat_config(newer.config))
        self.assertEqual(model.sensor_model_stats, newer.sensor_model_stats)
        self.assertEqual(model.kind_sums["cells"], 0.0)
        self.assertEqual(model.kind_sums["pairs"].shape, (read_model.KIND_COUNT, read_model.GAP_BINS, 2, 2))
        self.assertFalse(np.any(model.kind_sums["pairs"]) or np.any(model.kind_sums["membership"]))
        # The C++ map of learner cell_em never learns kinds: its file holds the kinds'
        # starting transitions, which version 2 files get too.
        self.assertEqual(model.kind_transitions, newer.kind_transitions)
        self.assertEqual(model.clock_origin_s, newer.clock_origin_s)
        self.assertEqual(model.last_applied_step, newer.last_applied_step)
        for name in read_model.CELL_FIELDS + ("em_stats",):
            self.assertTrue(np.array_equal(getattr(model, name).view(np.uint8), getattr(newer, name).view(np.uint8)),
                            name)
        self.assertIsNone(model.kind_posterior)
        self.assertFalse(np.any(model.learner_state[:, 8:]))

    def test_version_1_files_are_read_with_defaults_for_what_they_lack(self):
        data = self.bytes_of("cell-em")
        v1 = as_version_1(as_version_2(data))
        model = read_model.parse_model(v1)
        newer = read_model.parse_model(data)
        self.assertEqual(model.format_version, 1)
        self.assertEqual(model.cell_count, newer.cell_count)
        self.assertEqual(len(v1), 201 + 62 * newer.cell_count)
        self.assertTrue(np.array_equal(model.p_occ, newer.p_occ))
        self.assertTrue(np.array_equal(model.em_stats, newer.em_stats))
        self.assertFalse(np.any(model.learner_state[:, 8:]))
        self.assertEqual(model.learner, "cell_em")
        self.assertEqual(model.config["kinds"], read_model.default_kinds())
        self.assertEqual(model.kind_transitions, newer.kind_transitions)
        self.assertFalse(model.config["learn_sensor_model"])
        self.assertEqual(model.sensor_model_stats["trials_occ"], 0.0)
        self.assertEqual(int(model.last_hits.sum()), 0)
        self.assertGreater(int(newer.last_hits.sum()), 0)

    def test_distance_bins_are_the_cpp_ones(self):
        config = self.runs["growing"][1][0]
        steps = config["gap_bin_steps"]
        self.assertEqual(len(steps), read_model.GAP_BINS)
        for index, value in enumerate(steps):
            self.assertEqual(read_model.gap_bin_steps(index), value, index)
        self.assertEqual(steps[:16], [float(n) for n in range(1, 17)])
        checked = config["gap_bin"]
        self.assertGreater(len(checked), 400)
        for distance, index in checked:
            self.assertEqual(read_model.gap_bin(distance), index, distance)
        # 1..16 one bin each, then four per octave, the last bin open-ended.
        self.assertEqual([read_model.gap_bin(n) for n in (1, 16, 17, 19, 20, 32, 64)], [0, 15, 16, 16, 17, 20, 24])
        self.assertEqual(read_model.gap_bin(2 ** 62), read_model.GAP_BINS - 1)

    # ---- dense grids ----------------------------------------------------------------------------

    def test_dense_field_puts_every_cell_in_its_place(self):
        model = read_model.load_model(self.runs["growing"][0])
        min_x, min_y, max_x, max_y = model.bounds()
        for field, component in (("p_occ", None), ("last_step", None), ("observed_steps", None),
                                 ("p_free_given_occ", None), ("learner_state", 9), ("kind_posterior", (4, 1))):
            grid, window = read_model.dense_field(model, field, component)
            self.assertEqual(grid.shape, (max_y - min_y + 1, max_x - min_x + 1))
            self.assertEqual((window["min_x"], window["min_y"]), (min_x, min_y))
            self.assertEqual((window["height"], window["width"]), grid.shape)
            values = getattr(model, field)
            if component is not None:
                values = values[(slice(None),) + (component if isinstance(component, tuple) else (component,))]
            self.assertTrue(np.array_equal(grid[model.y - min_y, model.x - min_x],
                                           values.astype(np.float64)), field)
            self.assertEqual(int(np.isnan(grid).sum()), grid.size - model.cell_count, field)
        # Row = y: the cell with the largest y is in the last row.
        grid, window = read_model.dense_field(model, "p_occ")
        top = int(np.argmax(model.y))
        self.assertEqual(grid[-1, model.x[top] - min_x], np.float64(model.p_occ[top]))
        resolution = model.config["resolution_m"]
        self.assertEqual(window["origin_x_m"], model.config["origin_x_m"] + min_x * resolution)
        self.assertEqual(window["origin_y_m"], model.config["origin_y_m"] + min_y * resolution)
        with self.assertRaises(KeyError):
            read_model.dense_field(model, "no_such_field")
        for field, component in (("learner_state", None), ("learner_state", 10), ("kind_posterior", 3),
                                 ("kind_posterior", (5, 0)), ("kind_posterior", (0, 2))):
            with self.assertRaises(ValueError):
                read_model.dense_field(model, field, component)
        # A map of kinds has no online EM statistics, and the other way round.
        with self.assertRaisesRegex(ValueError, "learner kinds has no em_stats"):
            read_model.dense_field(model, "em_stats", 0)
        cell_em = read_model.load_model(self.runs["cell-em"][0])
        grid, _ = read_model.dense_field(cell_em, "em_stats", 7)
        self.assertTrue(np.array_equal(grid[cell_em.y - cell_em.bounds()[1], cell_em.x - cell_em.bounds()[0]],
                                       cell_em.em_stats[:, 7].astype(np.float64)))
        with self.assertRaisesRegex(ValueError, "learner cell_em has no kind_posterior"):
            read_model.dense_field(cell_em, "kind_posterior", (0, 0))

    # ---- damaged files ----------------------------------------------------------------------------

    def test_every_truncation_raises(self):
        for mode in ("empty", "fixed"):
            data = self.bytes_of(mode)
            read_model.parse_model(data)
            lengths = range(len(data)) if mode == "empty" else list(range(0, 700)) + list(
                range(CELLS_OFFSET - 200, CELLS_OFFSET + 300)) + list(range(len(data) - 200, len(data)))
            for length in lengths:
                self.expect_error(data[:length], "truncated", f"{length} available")

    def test_flipped_bytes_raise(self):
        data = self.bytes_of("fixed")
        positions = (list(range(0, 700)) + list(range(700, MEMBERSHIP_OFFSET, 61)) + list(range(MEMBERSHIP_OFFSET,
                     CELLS_OFFSET + 80)) + list(range(len(data) - 80, len(data))) + [len(data) // 2])
        for position in positions:
            damaged = bytearray(data)
            damaged[position] ^= 0x40
            self.expect_error(bytes(damaged))
        damaged = bytearray(data)
        damaged[len(data) // 2] ^= 0x01
        self.expect_error(bytes(damaged), "corrupt", "checksum")

    def test_messages_say_what_is_wrong(self):
        data = self.bytes_of("growing")
        self.expect_error(b"P5\n# an image", "not a dynamic_occupancy_grid model file")
        self.expect_error(b"X" + data[1:], "not a dynamic_occupancy_grid model file")
        newer = bytearray(data)
        newer[8:12] = struct.pack("<I", 4)
        self.expect_error(with_checksum(newer), "model format version 4, this reader reads versions 1 to 3")
        self.expect_error(data + b"\0", "1 trailing bytes")
        flag = bytearray(data)
        flag[146] = 2  # fixed_bounds
        self.expect_error(with_checksum(flag), "fixed_bounds is 2, must be 0 or 1")
        absurd = bytearray(data)
        absurd[COUNT_OFFSET:CELLS_OFFSET] = struct.pack("<Q", 2 ** 64 - 1)  # the cell count of version 3
        self.expect_error(with_checksum(absurd), "truncated")

    def test_bad_kinds_block_raises(self):
        data = self.bytes_of("growing")

        def edited(offset, value):
            damaged = bytearray(data)
            damaged[offset:offset + len(value)] = value
            return with_checksum(damaged)

        self.expect_error(edited(268, b"\2"), "learner is 2, must be 0 (cell_em) or 1 (kinds)")
        for kinds in (0, 4, 6):
            self.expect_error(edited(269, bytes([kinds])), f"model file with {kinds} kinds of cells, this reader has 5")
        self.expect_error(edited(422, b"\3"), "kinds.summary is 3, must be 0 (geometric_mean), 1 (mean) or 2")
        self.expect_error(edited(423, b"\2"), "kinds.counting is 2, must be 0 (posterior) or 1 (most_probable)")
        for flag in (2, 255):
            self.expect_error(edited(LEARN_FROM_GAPS_OFFSET, bytes([flag])),
                              f"invalid model file: kinds.learn_from_gaps is {flag}, must be 0 or 1")
        for bins in (0, 123, 125, 124 << 8, 65535):  # 124 << 8: 124 in the wrong byte order
            self.expect_error(edited(BIN_COUNT_OFFSET, struct.pack("<H", bins)),
                              f"model file with {bins} distance bins of the kinds' pairs, this reader has 124")
        bad_kinds = ("invalid kinds of cells in model file: kinds: saved sums must be finite and >= 0, transitions "
                     "within the bounds")
        pair = PAIRS_OFFSET + 8 * ((2 * read_model.GAP_BINS + 17) * 4 + 3)  # kind 2, bin 17, free then and now
        for offset in (PAIRS_OFFSET, pair, MEMBERSHIP_OFFSET - 8, MEMBERSHIP_OFFSET, MEMBERSHIP_OFFSET + 8 * 4,
                       CELLS_SUM_OFFSET):  # pairs, membership, cells
            for bad in (-1.0, -1e-300, float("nan"), float("inf")):
                self.expect_error(edited(offset, struct.pack("<d", bad)), bad_kinds)
        # The learned transitions: within [max(p_min, 1e-6), min(p_max, 0.5)].
        online_em = read_model.parse_model(data).config["online_em"]
        low, high = max(online_em["p_min"], 1e-6), min(online_em["p_max"], 0.5)
        for index in range(2 * read_model.KIND_COUNT):
            offset = LEARNED_OFFSET + 8 * index
            for bad in (0.0, -0.1, np.nextafter(low, 0.0), np.nextafter(high, 1.0), 0.75, float("nan"), float("inf")):
                self.expect_error(edited(offset, struct.pack("<d", bad)), bad_kinds)
            for good in (low, high):
                model = read_model.parse_model(edited(offset, struct.pack("<d", good)))
                name = ("p_occ_given_free", "p_free_given_occ")[index % 2]
                self.assertEqual(model.kind_transitions[index // 2][name], good)
        # A pair sum is read at [kind][bin][then][now].
        model = read_model.parse_model(edited(pair, struct.pack("<d", 12345.5)))
        self.assertEqual(model.kind_sums["pairs"][2, 17, 1, 1], 12345.5)
        model = read_model.parse_model(edited(PAIRS_OFFSET + 8 * ((4 * read_model.GAP_BINS + 123) * 4 + 1),
                                              struct.pack("<d", 0.25)))
        self.assertEqual(model.kind_sums["pairs"][4, 123, 0, 1], 0.25)
        # The kinds' removed choices are read and ignored: the same model.
        base = read_model.parse_model(data)
        for offset, value in ((LEARN_FROM_GAPS_OFFSET, b"\0"), (422, b"\2"), (423, b"\0")):
            self.assertEqual(read_model.parse_model(edited(offset, value)).config, base.config)
        # The learner as documented.
        model = read_model.parse_model(edited(268, b"\0"))
        self.assertEqual(model.learner, "cell_em")
        self.assertIsNone(model.kind_posterior)

    def test_load_model_names_the_file(self):
        data = bytearray(self.bytes_of("growing"))
        data[300] ^= 0xFF
        path = os.path.join(self.directory.name, "corrupt.dogm")
        with open(path, "wb") as file:
            file.write(data)
        with self.assertRaises(read_model.ModelFormatError) as caught:
            read_model.load_model(path)
        self.assertIn(path, str(caught.exception))
        self.assertIn("corrupt", str(caught.exception))
        with self.assertRaises(OSError):
            read_model.load_model(os.path.join(self.directory.name, "missing.dogm"))

    # ---- the command ------------------------------------------------------------------------------

    def test_command_prints_a_summary(self):
        path = self.runs["growing"][0]
        model = read_model.load_model(path)
        script = os.path.join(SCRIPTS, "read_model.py")
        done = subprocess.run([sys.executable, script, path], capture_output=True, text=True)
        self.assertEqual(done.returncode, 0, done.stderr)
        self.assertIn(f"cells observed:     {model.cell_count}", done.stdout)
        self.assertIn("time step:          0.5 s", done.stdout)
        self.assertIn("mean p_occ_given_free:", done.stdout)
        self.assertIn("(format version 3)", done.stdout)
        self.assertIn("learner:            kinds", done.stdout)
        self.assertIn("kinds' transitions: ", done.stdout)
        # The file's own version and learner.
        old = os.path.join(self.directory.name, "version_1.dogm")
        with open(old, "wb") as file:
            file.write(as_version_1(as_version_2(self.bytes_of("cell-em"))))
        done = subprocess.run([sys.executable, script, old], capture_output=True, text=True)
        self.assertEqual(done.returncode, 0, done.stderr)
        self.assertIn("(format version 1)", done.stdout)
        self.assertIn("learner:            cell_em", done.stdout)
        corrupt = os.path.join(self.directory.name, "corrupt_for_command.dogm")
        with open(corrupt, "wb") as file:
            file.write(self.bytes_of("growing")[:-1])
        done = subprocess.run([sys.executable, script, corrupt], capture_output=True, text=True)
        self.assertEqual(done.returncode, 1)
        self.assertIn("truncated", done.stderr)
        self.assertIn(corrupt, done.stderr)


if __name__ == "__main__":
    if len(sys.argv) > 1 and not sys.argv[1].startswith("-"):
        CLI = os.path.abspath(sys.argv.pop(1))
    if not CLI:
        print("usage: test_read_model.py WRITE_MODEL_CLI [unittest options]", file=sys.stderr)
        sys.exit(2)
    unittest.main()
