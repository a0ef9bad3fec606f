#!/usr/bin/env python3
"""check_bag (the self-supervised prediction check) on the two real recordings of the package.

* data/example/stationary_laser_people.bag: a stationary laser (no tf: --laser-pose 0,0,0)
  in a static room while people walk through it;
* test/data/neato_person_follower.bag: a Neato robot driving in its odom frame.

Checks that the table and the CSV agree and hold values in range, facts that follow from the
definitions (docs/self_check.md) and that a broken implementation gets wrong: at horizon 0
every label is scored and none is unseen, labels only get fewer with the horizon, a moving
robot meets cells it has not seen, the static map's Brier score is at least what its clamp
costs on free labels, labels and the static map do not depend on online learning; measured
facts with margins (tolerances are test parameters, test/ros/check_bag.test): both models
are accurate 1 s ahead, the dynamic model's Brier score is the lower one 1 s ahead on both
bags; and the error paths (missing bag, bag without tf, no usable scan, bad options,
unwritable CSV).

The end-of-run report (the learned sensor model, the static map's classes and how many the
belief, the stationary and the predicted layers keep, walls learned as changing and their
edge cells): stdout and CSV agree, counts are consistent (parts at most their wholes, edge
cells among occupied ones), the learned sensor model is a sensor model (in (0, 1), a hit more
likely in occupied cells), learning off learns no changing cell and leaves the stationary and
60 s predicted layers with no cell classified (the prior's pi = 0.5, lambda^60 < 0.3),
--prediction-horizon 0 makes the predicted layer the belief, and with the sensor model fixed
every count equals an independent computation with numpy on the layers process_bag writes
for the same bag (process_bag maps with the sensor model fixed; its predicted layer looks
60 s ahead, the node's default and check_bag's).
"""

import csv
import math
import os
import re
import shutil
import subprocess
import tempfile
import unittest

import numpy as np
import rospkg
import rospy
import rostest
from catkin.find_in_workspaces import find_in_workspaces

import wall_scene

PKG = "dynamic_occupancy_grid"
PACKAGE_DIR = rospkg.RosPack().get_path(PKG)
STATIONARY_BAG = os.path.join(PACKAGE_DIR, "data", "example", "stationary_laser_people.bag")
NEATO_BAG = os.path.join(PACKAGE_DIR, "test", "data", "neato_person_follower.bag")
STATIONARY_ARGS = ["--laser-pose", "0,0,0"]
NEATO_ARGS = ["--fixed-frame", "odom"]
# p(occ) of the static map's lowest log-odds (core::LogOddsClamp default, -2).
STATIC_FREE_FLOOR = 1.0 / (1.0 + math.exp(2.0))

# Test parameters (private, from check_bag.test) and their defaults.
PARAMS = {
    "min_accuracy_stationary": 0.99,
    "max_brier_ratio_stationary": 0.5,
    "min_accuracy_neato": 0.9,
    "max_brier_ratio_neato": 0.95,
    "timeout_s": 60.0,
}

TABLE_ROW = re.compile(r"^\s*(\S+)s\s+(\d+)\s+(\d+)\s+(\d+)\s+(\S+)\s+\|\s+(\S+)\s+(\S+)\s+(\S+)\s+\|"
                       r"\s+(\S+)\s+(\S+)\s+(\S+)\s*$")


def executable(name):
    found = find_in_workspaces(["libexec"], project=PKG, path=name, first_match_only=True)
    if not found:
        raise RuntimeError(f"{name} not found in the catkin workspaces (built?)")
    return found[0]


def check_bag(args):
    """(return code, stdout, stderr) of a check_bag run."""
    result = subprocess.run([executable("check_bag")] + [str(a) for a in args], capture_output=True, text=True,
                            errors="replace", timeout=PARAMS["timeout_s"])
    return result.returncode, result.stdout, result.stderr


def parse_table(stdout):
    """Rows of the table as dicts (None for '-')."""
    rows = []
    for line in stdout.splitlines():
        match = TABLE_ROW.match(line)
        if not match:
            continue
        values = match.groups()
        number = (lambda text: None if text == "-" else float(text.rstrip("%")))
        rows.append({"horizon_s": float(values[0]), "horizon_steps": int(values[1]), "labels": int(values[2]),
                     "unseen": int(values[3]), "occupied_percent": number(values[4]),
                     "dynamic_accuracy": number(values[5]), "dynamic_occupied_accuracy": number(values[6]),
                     "dynamic_brier": number(values[7]), "static_accuracy": number(values[8]),
                     "static_occupied_accuracy": number(values[9]), "static_brier": number(values[10])})
    return rows


def read_csv(path):
    with open(path, newline="") as file:
        rows = list(csv.DictReader(file))
    for row in rows:
        for key, value in row.items():
            integer = key in ("horizon_steps", "labels", "unseen", "occupied_labels", "dynamic_unclassified",
                              "static_unclassified") or (key.startswith("end_") and not key.startswith("end_p_")
                                                         and key not in ("end_retention_after_s",
                                                                         "end_prediction_horizon_s"))
            row[key] = int(value) if integer else float(value)
    return rows


END_LINES = {
    "sensor": re.compile(r"^  sensor model: p_hit_given_occ ([0-9.]+), p_hit_given_free ([0-9.]+) \((learned|fixed)"),
    "static": re.compile(r"^  static map \(clamped log-odds, occupied > 0.65, free < 0.196\): (\d+) free, "
                         r"(\d+) occupied of (\d+) observed cells$"),
    "kept": re.compile(r"^  retention \(belief at the last step, same thresholds\): free (\d+) of (\d+) \(\S+\), "
                       r"occupied (\d+) of (\d+) \(\S+\)$"),
    "left": re.compile(r"^  retention of the cells last observed >= (\S+)s before the end: "
                       r"free (\d+) of (\d+) \(\S+\), occupied (\d+) of (\d+) \(\S+\)$"),
    "stationary": re.compile(r"^  retention by the stationary layer \(long-run p\(occ\), same thresholds\): "
                             r"free (\d+) of (\d+) \(\S+\), occupied (\d+) of (\d+) \(\S+\)$"),
    "predicted": re.compile(r"^  retention by the predicted layer \((\S+)s ahead of the last step, same thresholds\): "
                            r"free (\d+) of (\d+) \(\S+\), occupied (\d+) of (\d+) \(\S+\)$"),
    "walls_left": re.compile(r"^  walls last observed >= (\S+)s before the end learned as changing: (\d+) of (\d+) "
                             r"\(\S+\)$"),
    "walls": re.compile(r"^  walls learned as changing \(static occupied, p_free_given_occ > 0.05\): (\d+) of (\d+), "
                        r"(\d+) of them edge cells \(edge: a free 8-neighbour; (\d+) occupied cells are edge cells\)$"),
    "free": re.compile(r"^  free cells learned as changing \(static free, p_occ_given_free > 0.05\): (\d+) of (\d+)$"),
}


def parse_end(stdout):
    """The end-of-run report as a dict of the CSV's end_ names (without the prefix); asserts
    every line is there."""
    found = {}
    for line in stdout.splitlines():
        for name, pattern in END_LINES.items():
            match = pattern.match(line)
            if match:
                found[name] = match.groups()
    missing = set(END_LINES) - set(found)
    if missing:
        raise AssertionError(f"end-of-run lines missing: {sorted(missing)}\n{stdout}")
    return {
        "p_hit_given_occ": float(found["sensor"][0]), "p_hit_given_free": float(found["sensor"][1]),
        "sensor_learned": found["sensor"][2] == "learned",
        "static_free": int(found["static"][0]), "static_occupied": int(found["static"][1]),
        "observed_cells": int(found["static"][2]),
        "kept_free": int(found["kept"][0]), "kept_occupied": int(found["kept"][2]),
        "retention_after_s": float(found["left"][0]),
        "left_kept_free": int(found["left"][1]), "left_static_free": int(found["left"][2]),
        "left_kept_occupied": int(found["left"][3]), "left_static_occupied": int(found["left"][4]),
        "occupied_changing": int(found["walls"][0]), "occupied_changing_edge": int(found["walls"][2]),
        "occupied_edge": int(found["walls"][3]), "free_changing": int(found["free"][0]),
        "stationary_kept_free": int(found["stationary"][0]), "stationary_kept_occupied": int(found["stationary"][2]),
        "prediction_horizon_s": float(found["predicted"][0]),
        "predicted_kept_free": int(found["predicted"][1]), "predicted_kept_occupied": int(found["predicted"][3]),
        "left_occupied_changing": int(found["walls_left"][1]),
        # consistency of the lines themselves
        "_kept_free_of": int(found["kept"][1]), "_kept_occupied_of": int(found["kept"][3]),
        "_walls_of": int(found["walls"][1]), "_free_of": int(found["free"][1]),
        "_stationary_free_of": int(found["stationary"][1]), "_stationary_occupied_of": int(found["stationary"][3]),
        "_predicted_free_of": int(found["predicted"][2]), "_predicted_occupied_of": int(found["predicted"][4]),
        "_walls_left_after_s": float(found["walls_left"][0]), "_walls_left_of": int(found["walls_left"][2]),
    }


def parse_summary(stdout):
    """(scans read, integrated, rejected), (observed cell-steps, tied)."""
    scans = re.search(r"scans read: (\d+), integrated: (\d+), rejected: (\d+)", stdout)
    cells = re.search(r"(\d+) cells observed in (\d+) cell-steps, (\d+) of them tied", stdout)
    return (tuple(int(v) for v in scans.groups()) if scans else None,
            (int(cells.group(2)), int(cells.group(3))) if cells else None)


class TestCheckBag(unittest.TestCase):
    tmp = None
    runs = {}

    @wall_scene.reported_set_up
    def setUpClass(cls):
        cls.tmp = tempfile.mkdtemp(prefix="test_check_bag_")

    @classmethod
    def tearDownClass(cls):
        shutil.rmtree(cls.tmp, ignore_errors=True)

    def run_once(self, name, bag, args):
        """check_bag with --csv tmp/name.csv (once per name): (stdout, table rows, csv rows)."""
        if name not in self.runs:
            path = os.path.join(self.tmp, name + ".csv")
            rc, stdout, stderr = check_bag([bag, "--csv", path] + args)
            self.assertEqual(rc, 0, f"exit {rc}\nstdout:\n{stdout}\nstderr:\n{stderr}")
            self.runs[name] = (stdout, parse_table(stdout), read_csv(path))
        return self.runs[name]

    def stationary(self):
        return self.run_once("stationary", STATIONARY_BAG,
                             STATIONARY_ARGS + ["--horizon", "0", "--horizon", "1", "--horizon", "5", "--horizon", "60"])

    def neato(self, learning=True, fixed_sensor=False):
        name = "neato" + ("" if learning else "_no_learning") + ("_fixed_sensor" if fixed_sensor else "")
        return self.run_once(name, NEATO_BAG, NEATO_ARGS + ([] if learning else ["--no-learning"]) +
                             (["--no-learn-sensor-model"] if fixed_sensor else []))

    def neato_learners(self):
        """The other learner, each cell's online EM."""
        return self.run_once("neato_learners", NEATO_BAG,
                             NEATO_ARGS + ["--learner", "cell_em", "--retention-after", "5"])

    def assert_consistent(self, run, horizons_s):
        """Table and CSV: one row per horizon, the same numbers, values in range."""
        stdout, table, rows = run
        self.assertEqual([row["horizon_s"] for row in rows], horizons_s, stdout)
        self.assertEqual([row["horizon_s"] for row in table], horizons_s, stdout)
        for shown, row in zip(table, rows):
            for key in ("horizon_steps", "labels", "unseen"):
                self.assertEqual(shown[key], row[key], key)
            self.assertLessEqual(row["unseen"], row["labels"])
            self.assertLessEqual(row["occupied_labels"], row["labels"] - row["unseen"])
            for model in ("dynamic", "static"):
                for measure in ("accuracy", "occupied_accuracy", "free_accuracy", "brier"):
                    value = row[f"{model}_{measure}"]
                    if row["labels"] == row["unseen"]:
                        self.assertTrue(math.isnan(value), f"{model}_{measure} without labels")
                        continue
                    self.assertGreaterEqual(value, 0.0, f"{model}_{measure}")
                    self.assertLessEqual(value, 1.0, f"{model}_{measure}")
                for measure in ("accuracy", "occupied_accuracy", "brier"):
                    value = row[f"{model}_{measure}"]
                    if math.isnan(value):
                        self.assertIsNone(shown[f"{model}_{measure}"])
                    else:
                        self.assertAlmostEqual(shown[f"{model}_{measure}"], value, delta=0.5e-4 + 1e-9)
        return rows

    # --- output and definitions -------------------------------------------------------

    def test_stationary_table_and_csv(self):
        rows = self.assert_consistent(self.stationary(), [0.0, 1.0, 5.0, 60.0])
        stdout = self.stationary()[0]
        scans, (cell_steps, tied) = parse_summary(stdout)
        self.assertEqual(scans, (1265, 1265, 0))
        # Horizon 0: every label (observed cell-step without a tie), none unseen.
        self.assertEqual(rows[0]["labels"], cell_steps - tied)
        self.assertEqual(rows[0]["unseen"], 0)
        # Later horizons lose the labels of the first h steps, and the first sight of cells.
        labels = [row["labels"] for row in rows]
        self.assertEqual(labels, sorted(labels, reverse=True))
        self.assertGreater(rows[1]["unseen"], 0)
        self.assertEqual([row["horizon_steps"] for row in rows], [0, 1, 5, 60])

    def test_static_brier_is_at_least_its_clamp_cost(self):
        # A free cell's static p(occ) never goes below the clamp's 0.12: each free label costs
        # at least 0.12^2 (a model that scored the beliefs as "static" would go far below).
        for rows in (self.stationary()[2], self.neato()[2]):
            for row in rows:
                scored = row["labels"] - row["unseen"]
                if scored == 0:
                    continue
                free_share = (scored - row["occupied_labels"]) / scored
                self.assertGreaterEqual(row["static_brier"], 0.999 * free_share * STATIC_FREE_FLOOR ** 2, row)

    def test_stationary_both_models_accurate_dynamic_brier_lower(self):
        one_second = self.stationary()[2][1]
        for model in ("dynamic", "static"):
            self.assertGreaterEqual(one_second[f"{model}_accuracy"], PARAMS["min_accuracy_stationary"], model)
        self.assertLess(one_second["dynamic_brier"],
                        PARAMS["max_brier_ratio_stationary"] * one_second["static_brier"], one_second)

    def test_neato_default_horizons(self):
        rows = self.assert_consistent(self.neato(), [1.0, 5.0, 30.0, 60.0])
        stdout = self.neato()[0]
        scans, _ = parse_summary(stdout)
        self.assertGreater(scans[1], 150)
        # The robot drives into space it has not seen: unseen labels from 1 s on.
        self.assertGreater(rows[0]["unseen"], 0.01 * rows[0]["labels"])
        # The bag lasts 42 s: nothing to score 60 s ahead, shown as '-' / nan.
        self.assertEqual(rows[3]["labels"], 0)
        self.assertTrue(math.isnan(rows[3]["dynamic_brier"]))
        one_second = rows[0]
        for model in ("dynamic", "static"):
            self.assertGreaterEqual(one_second[f"{model}_accuracy"], PARAMS["min_accuracy_neato"], model)
        self.assertLess(one_second["dynamic_brier"], PARAMS["max_brier_ratio_neato"] * one_second["static_brier"],
                        one_second)

    def test_pose_correction(self):
        # --pose-correction rbpf: the scored map is built at the corrected poses, the same in
        # both passes (the labels come from the corrected scans too), and the filter updates
        # are said. The map's correction changes only where the map as it was 30-60 s ago
        # shows drift (core/pose/corrected_mapping.h): on this 42 s drive it never does, so
        # the scores are those without correction (the filter made the map worse here when it
        # corrected every scan: docs/pose_correction_real.md).
        stdout, _, rows = self.run_once("neato_rbpf", NEATO_BAG, NEATO_ARGS + ["--pose-correction", "rbpf"])
        match = re.search(r"pose correction: 30 particles, (\d+) filter updates a pass", stdout)
        self.assertIsNotNone(match, stdout)
        self.assertGreater(int(match.group(1)), 5)
        plain = self.neato()[2]
        self.assertEqual(len(rows), len(plain))
        for row, without in zip(rows, plain):
            self.assertEqual(row["labels"], without["labels"])
            if row["labels"] > 0:
                self.assertEqual(row["dynamic_brier"], without["dynamic_brier"])
        for row in rows[:2]:
            self.assertGreater(row["dynamic_accuracy"], 0.9, row)
        self.assert_fails([STATIONARY_BAG, "--pose-correction", "rbpf"] + STATIONARY_ARGS, 2, "--laser-pose")
        self.assert_fails([NEATO_BAG, "--pose-correction", "gmapping"], 2, "--pose-correction")

    def test_learning_changes_dynamic_model_only(self):
        # Labels come from the geometry, and the static map ignores transitions: with the
        # sensor model fixed and online learning off only the dynamic columns (and the map at
        # the end) change. (A learned sensor model weighs beam ends by the beliefs, so it, and
        # the static map it feeds, depend on the transitions.)
        learning = self.neato(fixed_sensor=True)[2]
        fixed = self.neato(learning=False, fixed_sensor=True)[2]
        for with_learning, without in zip(learning, fixed):
            for key, value in with_learning.items():
                if key.startswith("dynamic_") or key.startswith("end_"):
                    continue
                if isinstance(value, float) and math.isnan(value):
                    self.assertTrue(math.isnan(without[key]), key)
                else:
                    self.assertEqual(without[key], value, key)
        self.assertNotEqual(learning[0]["dynamic_brier"], fixed[0]["dynamic_brier"])

    def test_labels_do_not_depend_on_the_sensor_model(self):
        learned = self.neato()[2]
        fixed = self.neato(fixed_sensor=True)[2]
        for a, b in zip(learned, fixed):
            for key in ("horizon_steps", "labels", "unseen", "occupied_labels"):
                self.assertEqual(a[key], b[key], key)
        self.assertNotEqual(learned[0]["end_p_hit_given_free"], fixed[0]["end_p_hit_given_free"])

    # --- the map at the end ---------------------------------------------------------------

    def assert_end_report(self, run):
        """stdout's and the CSV's end-of-run values agree, are the same on every CSV row and
        are consistent with each other; returns them."""
        stdout, _, rows = run
        end = parse_end(stdout)
        for row in rows:
            self.assertEqual({k: v for k, v in row.items() if k.startswith("end_")},
                             {k: v for k, v in rows[0].items() if k.startswith("end_")})
        row = rows[0]
        for key, value in end.items():
            if key.startswith("_") or key == "sensor_learned":
                continue
            if isinstance(value, float):
                self.assertAlmostEqual(row["end_" + key], value, delta=0.5e-4 + 1e-9, msg=key)
            else:
                self.assertEqual(row["end_" + key], value, key)
        self.assertEqual(end["_kept_free_of"], end["static_free"])
        self.assertEqual(end["_kept_occupied_of"], end["static_occupied"])
        self.assertEqual(end["_walls_of"], end["static_occupied"])
        self.assertEqual(end["_free_of"], end["static_free"])
        for layer in ("stationary", "predicted"):
            self.assertEqual(end[f"_{layer}_free_of"], end["static_free"], layer)
            self.assertEqual(end[f"_{layer}_occupied_of"], end["static_occupied"], layer)
        self.assertEqual(end["_walls_left_after_s"], end["retention_after_s"])
        self.assertEqual(end["_walls_left_of"], end["left_static_occupied"])
        # The map at the end is the map after the last step (steps = last applied step + 1).
        steps = int(re.search(r"time steps: (\d+) of", stdout).group(1))
        self.assertEqual(row["end_step"], steps - 1)
        self.assertIn(f"map at the end (step {steps - 1})", stdout)
        # A sensor model: both in (0, 1), a hit more likely in an occupied cell.
        self.assertGreater(end["p_hit_given_occ"], 0.0)
        self.assertLess(end["p_hit_given_occ"], 1.0)
        self.assertGreater(end["p_hit_given_free"], 0.0)
        self.assertGreater(end["p_hit_given_occ"], end["p_hit_given_free"])
        # Parts at most their wholes.
        self.assertGreater(end["static_free"], 0)
        self.assertGreater(end["static_occupied"], 0)
        self.assertLessEqual(end["static_free"] + end["static_occupied"], end["observed_cells"])
        self.assertLessEqual(end["kept_free"], end["static_free"])
        self.assertLessEqual(end["kept_occupied"], end["static_occupied"])
        self.assertLessEqual(end["left_static_free"], end["static_free"])
        self.assertLessEqual(end["left_static_occupied"], end["static_occupied"])
        self.assertLessEqual(end["left_kept_free"], end["left_static_free"])
        self.assertLessEqual(end["left_kept_occupied"], end["left_static_occupied"])
        self.assertLessEqual(end["left_kept_free"], end["kept_free"])
        self.assertLessEqual(end["occupied_edge"], end["static_occupied"])
        self.assertLessEqual(end["occupied_changing"], end["static_occupied"])
        self.assertLessEqual(end["occupied_changing_edge"], end["occupied_changing"])
        self.assertLessEqual(end["occupied_changing_edge"], end["occupied_edge"])
        self.assertLessEqual(end["free_changing"], end["static_free"])
        for layer in ("stationary", "predicted"):
            self.assertLessEqual(end[f"{layer}_kept_free"], end["static_free"], layer)
            self.assertLessEqual(end[f"{layer}_kept_occupied"], end["static_occupied"], layer)
        self.assertLessEqual(end["left_occupied_changing"], end["occupied_changing"])
        self.assertLessEqual(end["left_occupied_changing"], end["left_static_occupied"])
        return end

    def test_end_report_default_learns_the_sensor_model(self):
        stdout = self.neato()[0]
        self.assertIn("sensor model learning on", stdout)
        self.assertIn("online learning: kinds of cells (5), switch probability 0.0001, forgetting 0.001 per step",
                      stdout)
        # What the map learned its places to be: five kinds, their shares summing to 1.
        kinds = re.search(r"kinds of cells \(p_occ_given_free / p_free_given_occ per step, share of the cells\): (.*)",
                          stdout)
        self.assertIsNotNone(kinds, stdout)
        shares = [float(kind.split(",")[1]) for kind in kinds.group(1).split(";")]
        self.assertEqual(len(shares), 5)
        self.assertAlmostEqual(sum(shares), 1.0, places=3)
        end = self.assert_end_report(self.neato())
        self.assertTrue(end["sensor_learned"])
        # Learned from the bag: it moved away from its start (0.7 / 0.2).
        self.assertNotEqual((end["p_hit_given_occ"], end["p_hit_given_free"]), (0.7, 0.2))
        self.assertEqual(end["retention_after_s"], 10.0)
        # The predicted layer looks the node's ~prediction_horizon (60 s) ahead.
        self.assertEqual(end["prediction_horizon_s"], 60.0)
        # Learned transitions: the stationary layer classifies cells (it would not at pi = 0.5).
        self.assertGreater(end["stationary_kept_free"], 0)
        # Cells seen at the very end are also seen 10 s before it: the left ones are fewer.
        self.assertLess(end["left_static_free"], end["static_free"])

    def test_end_report_other_learners(self):
        stdout = self.neato_learners()[0]
        self.assertIn("online learning: each cell's online EM\n", stdout)
        end = self.assert_end_report(self.neato_learners())
        self.assertTrue(end["sensor_learned"])
        self.assertEqual(end["retention_after_s"], 5.0)
        # Another learner, other transitions: the dynamic scores differ from the default's.
        self.assertNotEqual(self.neato_learners()[2][0]["dynamic_brier"], self.neato()[2][0]["dynamic_brier"])

    def test_end_report_fixed_sensor_model_and_no_learning(self):
        fixed = self.assert_end_report(self.neato(fixed_sensor=True))
        self.assertFalse(fixed["sensor_learned"])
        self.assertEqual((fixed["p_hit_given_occ"], fixed["p_hit_given_free"]), (0.7, 0.2))
        # Learning off: every cell keeps the prior 0.01 / 0.01, none is learned as changing.
        # The prior's stationary p(occ) is 0.01 / (0.01 + 0.01) = 0.5 and lambda = 0.98: the
        # stationary layer is 0.5 everywhere, the predicted one within 0.5 +- 0.5 * 0.98^60 =
        # [0.351, 0.649], between the thresholds: neither classifies any cell.
        for run in (self.neato(learning=False), self.neato(learning=False, fixed_sensor=True)):
            end = self.assert_end_report(run)
            self.assertEqual(end["occupied_changing"], 0)
            self.assertEqual(end["left_occupied_changing"], 0)
            self.assertEqual(end["free_changing"], 0)
            for layer in ("stationary", "predicted"):
                self.assertEqual((end[f"{layer}_kept_free"], end[f"{layer}_kept_occupied"]), (0, 0), layer)

    def test_end_report_matches_process_bag_layers(self):
        """With the sensor model fixed (in both tools), the counts equal numpy's on the
        static_map, belief and transition layers process_bag writes for the same bag."""
        end = self.assert_end_report(self.neato(fixed_sensor=True))
        out = os.path.join(self.tmp, "process_bag")
        result = subprocess.run([executable("process_bag"), NEATO_BAG, "--out", out, "--no-learn-sensor-model"] + NEATO_ARGS,
                                capture_output=True, text=True, errors="replace", timeout=PARAMS["timeout_s"])
        self.assertEqual(result.returncode, 0, result.stderr)
        layer = {name: np.load(os.path.join(out, name + ".npy"))
                 for name in ("static_map", "belief", "stationary", "predicted", "p_occ_given_free",
                              "p_free_given_occ")}
        static = layer["static_map"]
        with np.errstate(invalid="ignore"):
            free = static < 0.196
            occupied = static > 0.65
            belief_free = layer["belief"] < 0.196
            belief_occupied = layer["belief"] > 0.65
            stationary_free = layer["stationary"] < 0.196
            stationary_occupied = layer["stationary"] > 0.65
            predicted_free = layer["predicted"] < 0.196
            predicted_occupied = layer["predicted"] > 0.65
            walls_changing = occupied & (layer["p_free_given_occ"] > 0.05)
            free_changing = free & (layer["p_occ_given_free"] > 0.05)
        padded = np.pad(free, 1)
        free_neighbour = np.zeros_like(free)
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                if dx or dy:
                    free_neighbour |= padded[1 + dy:1 + dy + free.shape[0], 1 + dx:1 + dx + free.shape[1]]
        edge = occupied & free_neighbour
        expected = {
            "observed_cells": int(np.count_nonzero(~np.isnan(static))),
            "static_free": int(free.sum()), "static_occupied": int(occupied.sum()),
            "kept_free": int((free & belief_free).sum()), "kept_occupied": int((occupied & belief_occupied).sum()),
            "stationary_kept_free": int((free & stationary_free).sum()),
            "stationary_kept_occupied": int((occupied & stationary_occupied).sum()),
            "predicted_kept_free": int((free & predicted_free).sum()),
            "predicted_kept_occupied": int((occupied & predicted_occupied).sum()),
            "occupied_edge": int(edge.sum()), "occupied_changing": int(walls_changing.sum()),
            "occupied_changing_edge": int((walls_changing & edge).sum()), "free_changing": int(free_changing.sum()),
        }
        self.assertEqual({key: end[key] for key in expected}, expected)
        self.assertGreater(expected["occupied_edge"], 0)
        # Neither layer is trivially all or nothing here (the check would then prove little).
        for key in ("stationary_kept_free", "predicted_kept_free", "predicted_kept_occupied"):
            self.assertGreater(expected[key], 0, key)
        self.assertLess(expected["stationary_kept_occupied"], expected["static_occupied"])

    def test_prediction_horizon(self):
        """--prediction-horizon 0: the predicted layer is the belief at the last step (the same
        counts); the horizon is rounded to steps and said in stdout and the CSV."""
        end = self.assert_end_report(self.run_once("neato_prediction_0", NEATO_BAG,
                                                   NEATO_ARGS + ["--prediction-horizon", "0"]))
        self.assertEqual(end["prediction_horizon_s"], 0.0)
        self.assertEqual((end["predicted_kept_free"], end["predicted_kept_occupied"]),
                         (end["kept_free"], end["kept_occupied"]))
        stdout, _, rows = self.run_once("neato_prediction_5", NEATO_BAG, NEATO_ARGS + ["--prediction-horizon", "4.6"])
        end = self.assert_end_report((stdout, None, rows))
        self.assertEqual(end["prediction_horizon_s"], 5.0)
        self.assertIn("retention by the predicted layer (5s ahead of the last step", stdout)

    def test_horizon_rounded_to_steps(self):
        path = os.path.join(self.tmp, "half.csv")
        rc, stdout, stderr = check_bag([NEATO_BAG, "--time-step", "0.5", "--horizon", "1.2", "--horizon", "2",
                                        "--csv", path] + NEATO_ARGS)
        self.assertEqual(rc, 0, stderr)
        self.assertIn("note: horizon 1.2 s is not a whole number of 0.5 s steps: 1s used", stdout)
        rows = read_csv(path)
        self.assertEqual([(row["horizon_s"], row["horizon_steps"]) for row in rows], [(1.0, 2), (2.0, 4)])

    # --- errors ---------------------------------------------------------------------------

    def assert_fails(self, args, rc_expected, *words):
        rc, stdout, stderr = check_bag(args)
        self.assertEqual(rc, rc_expected, f"{args}: exit {rc}\nstdout:\n{stdout}\nstderr:\n{stderr}")
        for word in words:
            self.assertIn(word, stderr)
        return stderr

    def test_missing_bag(self):
        missing = os.path.join(self.tmp, "no_such.bag")
        self.assert_fails([missing], 1, missing, "does not exist")

    def test_bag_without_tf_needs_laser_pose(self):
        self.assert_fails([STATIONARY_BAG], 1, "--laser-pose")

    def test_unwritable_csv(self):
        path = os.path.join(self.tmp, "no_such_dir", "out.csv")
        self.assert_fails([NEATO_BAG, "--csv", path], 1, path)

    def test_failed_run_leaves_no_csv_and_keeps_an_old_one(self):
        path = os.path.join(self.tmp, "failed.csv")
        self.assert_fails([NEATO_BAG, "--fixed-frame", "no_such_frame", "--csv", path], 1, "without a pose",
                          "no_such_frame")
        self.assertFalse(os.path.exists(path))
        with open(path, "w") as file:
            file.write("earlier results\n")
        self.assert_fails([NEATO_BAG, "--fixed-frame", "no_such_frame", "--csv", path], 1, "no_such_frame")
        with open(path) as file:
            self.assertEqual(file.read(), "earlier results\n")

    def test_bad_options(self):
        for args in ([NEATO_BAG, "--horizon", "-1"], [NEATO_BAG, "--horizon", "abc"], [NEATO_BAG, "--horizon"],
                     [NEATO_BAG, "--resolution", "0"], [NEATO_BAG, "--no-such-option"], [NEATO_BAG, NEATO_BAG],
                     [NEATO_BAG, "--csv", ""], [NEATO_BAG, "--horizon", "0.4"], [],
                     [NEATO_BAG, "--retention-after", "-1"], [NEATO_BAG, "--prediction-horizon", "-1"]):
            self.assert_fails(args, 2, "usage: check_bag")

    def test_learner_options_that_contradict(self):
        self.assert_fails([NEATO_BAG, "--learn-sensor-model", "--no-learn-sensor-model"], 2, "contradict")
        self.assert_fails([NEATO_BAG, "--learner", "em"], 2, "--learner", "kinds or cell_em")
        rc, stdout, _ = check_bag(["--help"])
        self.assertEqual(rc, 0)
        for option in ("--learn-sensor-model", "--no-learn-sensor-model", "--retention-after", "--prediction-horizon"):
            self.assertIn(option, stdout)
        self.assertIn("(default: on, as the node's ~learn_sensor_model)", " ".join(stdout.split()))

    def test_refuses_offline_em_options(self):
        """The options of the bag tools that only tune offline EM are refused and not in the usage."""
        for option, value in (("--em-iterations", "5"), ("--em-tolerance", "0.1"), ("--em-prior-weight", "1"),
                              ("--mrf-temperature", "50"), ("--threads", "1")):
            self.assert_fails([NEATO_BAG, option, value], 2, option + " does not apply", "no offline EM",
                              "usage: check_bag")
        rc, stdout, _ = check_bag(["--help"])
        self.assertEqual(rc, 0)
        self.assertIn("--max-free-range", stdout)  # the shared options are listed ...
        for option in ("--em-", "--mrf-temperature", "--threads"):
            self.assertNotIn(option, stdout)  # ... but not these


if __name__ == "__main__":
    rospy.init_node("test_check_bag", anonymous=True)
    for name, default in PARAMS.items():
        PARAMS[name] = rospy.get_param("~" + name, default)
    rostest.rosrun(PKG, "test_check_bag", TestCheckBag)
