#!/usr/bin/env python3
"""scripts/real_recordings_report.py: check_bag on every real recording, one Markdown row per
bag and variant (docs/real_recordings.md#the-report).

On the bundled Neato bag named on the command line (an empty data directory otherwise): the
two tables have their columns and one row per variant, the file --out writes is what stdout
shows, and the numbers are check_bag's own, run here with the same options and read from its
CSV (retention, walls learned as changing, the left cells', Brier and occ.acc, the static
map's in parentheses; stationary / predicted retention); a bag's options after a colon and
options after `--` reach check_bag; a failed run is a row saying why and exit status 1; a
missing data directory or no bag at all is a message (no traceback) and exit status 2. When
../shared/data/real is there: every bag of it, both variants, no run failing.
"""

import csv
import os
import shutil
import subprocess
import sys
import tempfile
import unittest

import rospkg
import rostest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from test_check_bag import NEATO_ARGS, NEATO_BAG, executable  # noqa: E402
import wall_scene  # noqa: E402

PKG = "dynamic_occupancy_grid"
PACKAGE_DIR = rospkg.RosPack().get_path(PKG)
SCRIPT = os.path.join(PACKAGE_DIR, "scripts", "real_recordings_report.py")
SHARED_DATA = os.path.normpath(os.path.join(os.path.realpath(PACKAGE_DIR), "..", "shared", "data", "real"))
TIMEOUT_S = 300
MAIN_COLUMNS = 14
LAYER_COLUMNS = 8


def report(args):
    """(return code, stdout, stderr) of the script."""
    result = subprocess.run([sys.executable, SCRIPT] + args, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            universal_newlines=True, timeout=TIMEOUT_S)
    return result.returncode, result.stdout, result.stderr


def tables(stdout):
    """The Markdown tables of the output: lists of rows (lists of cells), the header first,
    the |---| line dropped."""
    found, current = [], None
    for line in stdout.splitlines():
        if line.startswith("|"):
            if current is None:
                current = []
                found.append(current)
            if set(line) <= set("|-"):
                continue
            current.append([cell.strip() for cell in line.strip().strip("|").split("|")])
        else:
            current = None
    return found


def check_bag_csv(tmp, name, args):
    """check_bag's CSV rows ({horizon_s: row}) for one run with the report's horizons."""
    path = os.path.join(tmp, name + ".csv")
    subprocess.run([executable("check_bag")] + args + ["--horizon", "1", "--horizon", "5", "--horizon", "30",
                                                       "--csv", path],
                   check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, timeout=TIMEOUT_S)
    with open(path, newline="") as file:
        return {float(row["horizon_s"]): {key: float(value) for key, value in row.items()}
                for row in csv.DictReader(file)}


def percent(part, whole):
    return "-" if whole == 0 else "%.1f %%" % (100.0 * part / whole)


class TestRealRecordingsReport(unittest.TestCase):

    @wall_scene.reported_set_up
    def setUpClass(cls):
        cls.tmp = tempfile.mkdtemp(prefix="test_real_report_")
        cls.empty = os.path.join(cls.tmp, "empty_data")
        os.mkdir(cls.empty)
        cls.out = os.path.join(cls.tmp, "report.md")
        cls.rc, cls.stdout, cls.stderr = report(["--data-dir", cls.empty, NEATO_BAG, "--out", cls.out])

    @classmethod
    def tearDownClass(cls):
        shutil.rmtree(cls.tmp, ignore_errors=True)

    def assert_row_matches(self, row, rows):
        """One row of the main table against check_bag's CSV of the same run."""
        end = rows[1.0]
        self.assertEqual(row[2], percent(end["end_kept_occupied"], end["end_static_occupied"]))
        self.assertEqual(row[3], percent(end["end_kept_free"], end["end_static_free"]))
        self.assertEqual(row[4], percent(end["end_occupied_changing"], end["end_static_occupied"]))
        self.assertEqual(row[5], percent(end["end_left_kept_occupied"], end["end_left_static_occupied"]))
        self.assertEqual(row[6], percent(end["end_left_kept_free"], end["end_left_static_free"]))
        self.assertEqual(row[7], percent(end["end_left_occupied_changing"], end["end_left_static_occupied"]))
        for k, horizon in enumerate((1.0, 5.0, 30.0)):
            self.assertEqual(row[8 + k], "%.4f (%.4f)" % (rows[horizon]["dynamic_brier"],
                                                          rows[horizon]["static_brier"]), horizon)
            self.assertEqual(row[11 + k], "%.4f (%.4f)" % (rows[horizon]["dynamic_occupied_accuracy"],
                                                           rows[horizon]["static_occupied_accuracy"]), horizon)

    def test_table_shape(self):
        self.assertEqual(self.rc, 0, self.stderr)
        main, layers = tables(self.stdout)
        self.assertEqual(len(main), 3)  # header, default, --no-learning
        self.assertEqual(len(layers), 3)
        for row in main:
            self.assertEqual(len(row), MAIN_COLUMNS, row)
        for row in layers:
            self.assertEqual(len(row), LAYER_COLUMNS, row)
        self.assertEqual(main[0][:3], ["bag", "variant", "belief keeps occupied"])
        self.assertEqual([row[:2] for row in main[1:]],
                         [["neato_person_follower.bag", "default"],
                          ["neato_person_follower.bag", "`--no-learning`"]])
        # Every cell a number: percentages, "Brier (static)".
        for row in main[1:]:
            for cell in row[2:8]:
                self.assertRegex(cell, r"^\d+\.\d %$")
            for cell in row[8:]:
                self.assertRegex(cell, r"^\d\.\d{4} \(\d\.\d{4}\)$")
        self.assertIn("neato_person_follower.bag (`--fixed-frame odom`): scans read: 196", self.stdout)
        with open(self.out) as file:
            self.assertEqual(file.read(), self.stdout)

    def test_values_are_check_bag_csv(self):
        main, layers = tables(self.stdout)
        default = check_bag_csv(self.tmp, "default", [NEATO_BAG] + NEATO_ARGS)
        no_learning = check_bag_csv(self.tmp, "no_learning", [NEATO_BAG] + NEATO_ARGS + ["--no-learning"])
        self.assert_row_matches(main[1], default)
        self.assert_row_matches(main[2], no_learning)
        end = default[1.0]
        self.assertEqual(layers[1][2:], [
            "%d / %d" % (end["end_static_occupied"], end["end_static_free"]),
            percent(end["end_stationary_kept_occupied"], end["end_static_occupied"]),
            percent(end["end_stationary_kept_free"], end["end_static_free"]),
            "60 s",
            percent(end["end_predicted_kept_occupied"], end["end_static_occupied"]),
            percent(end["end_predicted_kept_free"], end["end_static_free"])])
        # Learning off: no wall learned as changing.
        self.assertEqual(main[2][4], "0.0 %")
        # The labels the scores rest on.
        self.assertIn("scored labels 1 / 5 / 30 s: %s (occupied %s)" % (
            " / ".join("%d" % (default[h]["labels"] - default[h]["unseen"]) for h in (1.0, 5.0, 30.0)),
            " / ".join("%d" % default[h]["occupied_labels"] for h in (1.0, 5.0, 30.0))), self.stdout)

    def test_bag_options_and_options_for_every_run(self):
        rc, stdout, stderr = report(["--data-dir", self.empty,
                                     NEATO_BAG + ":--fixed-frame odom --no-learn-sensor-model", "--jobs", "1",
                                     "--", "--learner", "cell_em", "--retention-after", "5"])
        self.assertEqual(rc, 0, stderr)
        self.assertIn("with `--learner cell_em --retention-after 5` on every run", stdout)
        self.assertIn("(`--fixed-frame odom --no-learn-sensor-model --learner cell_em --retention-after 5`)", stdout)
        main, _ = tables(stdout)
        self.assertEqual(main[0][5], "left ≥ 5 s: keeps occupied")
        self.assertEqual(tables(self.stdout)[0][0][5], "left ≥ 10 s: keeps occupied")
        self.assert_row_matches(main[1], check_bag_csv(
            self.tmp, "cell_em", [NEATO_BAG] + NEATO_ARGS + ["--no-learn-sensor-model", "--learner", "cell_em",
                                                             "--retention-after", "5"]))

    def test_failed_run(self):
        rc, stdout, stderr = report(["--data-dir", self.empty, NEATO_BAG + ":--fixed-frame no_such_frame"])
        self.assertEqual(rc, 1, stdout + stderr)
        main, _ = tables(stdout)
        self.assertEqual(len(main), 3)
        for row in main[1:]:
            self.assertEqual(len(row), MAIN_COLUMNS, row)
            self.assertTrue(row[2].startswith("failed: check_bag exit 1"), row)
            self.assertIn("no_such_frame", row[2])
        self.assertIn("2 of 2 check_bag runs failed", stderr)
        self.assertNotIn("Traceback", stderr)

    def test_unwritable_out(self):
        out = os.path.join(self.tmp, "no_such_dir", "report.md")
        rc, stdout, stderr = report(["--data-dir", self.empty, NEATO_BAG, "--out", out])
        self.assertEqual(rc, 2, stdout + stderr)
        self.assertIn("cannot write " + out, stderr)
        self.assertEqual(stdout, "")

    def test_missing_data_dir_and_no_bags(self):
        missing = os.path.join(self.tmp, "no_such_dir")
        rc, stdout, stderr = report(["--data-dir", missing])
        self.assertEqual(rc, 2, stdout + stderr)
        self.assertIn("data directory " + missing + " not found", stderr)
        self.assertNotIn("Traceback", stderr)
        self.assertEqual(stdout, "")
        rc, stdout, stderr = report(["--data-dir", self.empty])
        self.assertEqual(rc, 2, stdout + stderr)
        self.assertIn("no bag in " + self.empty, stderr)
        self.assertNotIn("Traceback", stderr)

    def test_default_data_dir_is_next_to_the_package(self):
        """A copy of the script in CHECKOUT/scripts reads CHECKOUT/../shared/data/real (here
        with the Neato bag in it, known by its name); without that directory it says so and
        runs the bags named on its command line only."""
        root = os.path.join(self.tmp, "elsewhere")
        os.makedirs(os.path.join(root, "package", "scripts"))
        copy = os.path.join(root, "package", "scripts", "real_recordings_report.py")
        shutil.copy(SCRIPT, copy)
        run = (lambda args: subprocess.run([sys.executable, copy] + args, stdout=subprocess.PIPE,
                                           stderr=subprocess.PIPE, universal_newlines=True, timeout=TIMEOUT_S))
        result = run([NEATO_BAG])
        self.assertEqual(result.returncode, 0, result.stderr)
        self.assertIn("no data directory " + os.path.join(root, "shared", "data", "real"), result.stderr)
        self.assertEqual(len(tables(result.stdout)[0]), 3)
        data = os.path.join(root, "shared", "data", "real")
        os.makedirs(data)
        os.symlink(NEATO_BAG, os.path.join(data, "neato_person_follower.bag"))
        result = run([])
        self.assertEqual(result.returncode, 0, result.stderr)
        main = tables(result.stdout)[0]
        self.assertEqual([row[:2] for row in main[1:]], [["neato_person_follower.bag", "default"],
                                                         ["neato_person_follower.bag", "`--no-learning`"]])
        self.assertEqual(main[1:], tables(self.stdout)[0][1:])

    @unittest.skipUnless(os.path.isdir(SHARED_DATA), SHARED_DATA + " is not there")
    def test_shared_recordings(self):
        """The report itself: every bag of ../shared/data/real, both variants, none failing."""
        bags = sorted(name for name in os.listdir(SHARED_DATA) if name.endswith(".bag"))
        rc, stdout, stderr = report([])
        self.assertEqual(rc, 0, stdout + stderr)
        main, layers = tables(stdout)
        self.assertEqual([row[0] for row in main[1:]], [name for name in bags for _ in range(2)])
        self.assertEqual([row[0] for row in layers[1:]], [name for name in bags for _ in range(2)])
        for row in main[1:]:
            self.assertFalse(row[2].startswith("failed"), row)


if __name__ == "__main__":
    rostest.rosrun(PKG, "test_real_recordings_report", TestRealRecordingsReport)
