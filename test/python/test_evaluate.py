#!/usr/bin/env python3
"""The evaluate tool end to end, small: its tables, their contract with plot_evaluation.py,
reproducibility, and its errors. Run by test/core_standalone (ctest):
    test_evaluate.py EVALUATE_EXECUTABLE
"""
import csv
import os
import subprocess
import sys
import tempfile
import unittest

EVALUATE = None
PLOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "scripts", "plot_evaluation.py")
METHODS = ["static", "static_unclamped", "online", "offline", "oracle"]
SMALL = ["--scenarios", "dynamic_5_5,redraw_100", "--repetitions", "2", "--path-repetitions", "2",
         "--path-runs", "4", "--threads", "2"]


def evaluate(args):
    run = subprocess.run([EVALUATE] + args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, timeout=600)
    return run.returncode, run.stdout, run.stderr


class EvaluateTool(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.tmp = tempfile.TemporaryDirectory()
        cls.out = os.path.join(cls.tmp.name, "out")
        cls.rc, cls.stdout, cls.stderr = evaluate(["--out", cls.out] + SMALL)

    @classmethod
    def tearDownClass(cls):
        cls.tmp.cleanup()

    def test_writes_the_tables_and_the_summary(self):
        self.assertEqual(self.rc, 0, self.stderr)
        for name in ["accuracy_dynamic_5_5.csv", "accuracy_redraw_100.csv", "parameter_error.csv",
                     "path_planning.csv", "summary.md"]:
            self.assertTrue(os.path.isfile(os.path.join(self.out, name)), name)
        self.assertIn("## Targets", self.stdout)
        self.assertIn(self.out, self.stdout)

    def test_accuracy_table_has_every_step_and_method_in_range(self):
        with open(os.path.join(self.out, "accuracy_dynamic_5_5.csv")) as file:
            rows = list(csv.DictReader(file))
        self.assertEqual(len(rows), 1000)  # the scenario's steps
        self.assertEqual([int(row["step"]) for row in rows[:3]], [0, 1, 2])
        for row in rows:
            for method in METHODS:
                self.assertGreaterEqual(float(row[method + "_mean"]), 0.0)
                self.assertLessEqual(float(row[method + "_mean"]), 100.0)
                self.assertGreaterEqual(float(row[method + "_std"]), 0.0)
        # Two repetitions of different worlds: the spread is not zero everywhere.
        self.assertTrue(any(float(row["online_std"]) > 0.0 for row in rows))

    def test_path_planning_table_rows(self):
        with open(os.path.join(self.out, "path_planning.csv")) as file:
            rows = {row["class"]: row for row in csv.DictReader(file)}
        self.assertEqual(set(rows), {"short", "long", "indirect_long", "unnecessary_indirect_long",
                                     "unnecessary_direct_long", "timeout", "effectiveness"})
        for policy in ["static", "online", "offline", "random", "optimal"]:
            classes = sum(float(rows[c][policy + "_mean"]) for c in rows if c != "effectiveness")
            self.assertAlmostEqual(classes, 100.0, places=2)
            self.assertAlmostEqual(float(rows["effectiveness"][policy + "_mean"]),
                                   float(rows["short"][policy + "_mean"]) + float(rows["long"][policy + "_mean"]),
                                   places=2)
        self.assertEqual(rows["effectiveness"]["paper_offline"], "55.75")

    def test_the_plot_script_reads_what_evaluate_writes(self):
        run = subprocess.run(["/usr/bin/python3", PLOT, self.out], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                             text=True, timeout=300)
        self.assertEqual(run.returncode, 0, run.stderr)
        for name in ["accuracy_dynamic_5_5.png", "accuracy_redraw_100.png", "parameter_error.png",
                     "path_planning.png"]:
            with open(os.path.join(self.out, name), "rb") as file:
                self.assertEqual(file.read(8), b"\x89PNG\r\n\x1a\n", name)

    def test_same_seed_same_numbers(self):
        again = os.path.join(self.tmp.name, "again")
        rc, _, stderr = evaluate(["--out", again, "--scenarios", "dynamic_5_5", "--repetitions", "2",
                                  "--path-repetitions", "0", "--threads", "1"])
        self.assertEqual(rc, 0, stderr)
        with open(os.path.join(self.out, "accuracy_dynamic_5_5.csv")) as a, \
                open(os.path.join(again, "accuracy_dynamic_5_5.csv")) as b:
            self.assertEqual(a.read(), b.read())

    def test_errors(self):
        rc, _, stderr = evaluate(["--scenarios", "nope"])
        self.assertEqual(rc, 2)
        self.assertIn("dynamic_5_5", stderr)  # lists the names
        for args in (["--repetitions", "0"], ["--repetitions", "3000000000"], ["--scenarios", "door"],
                     ["--scenarios", "dynamic_5_5,dynamic_5_5"], ["--scenarios", "none", "--path-repetitions", "0"],
                     ["--no-such-option", "1"], ["--out"]):
            rc, _, stderr = evaluate(args)
            self.assertEqual(rc, 2, args)
            self.assertIn("usage", stderr, args)
        a_file = os.path.join(self.tmp.name, "a_file")
        with open(a_file, "w") as file:
            file.write("x")
        rc, _, stderr = evaluate(["--out", a_file] + SMALL)
        self.assertEqual(rc, 1)
        self.assertIn("not a directory", stderr)


if __name__ == "__main__":
    EVALUATE = sys.argv.pop(1)
    unittest.main()
