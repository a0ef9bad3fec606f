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
         "--path-runs", "4", "--mrf-repetitions", "2", "--memory-repetitions", "2", "--threads", "2",
         "--learning-scenarios", "dynamic_25_25", "--learning-repetitions", "1", "--murphy-repetitions", "3",
         "--murphy-doors-runs", "2"]
MRF_WORLD = (46, 32)  # the mrf_squares scenario's cells (evaluation/simulator.cpp)
# The MRF experiment's learners: the online ones (cell EM without and with the empirical-Bayes
# prior, kinds of cells), and with the two offline EMs.
ONLINE = ("online", "online_kinds")
ONLINE_AND_OFFLINE = ("plain", "mrf") + ONLINE


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
                     "path_planning.csv", "mrf_rmse.csv", "mrf_rmse_by_kind.csv", "mrf_rmse_changing.csv",
                     "mrf_online.csv",
                     "mrf_iterations.csv", "mrf_maps.csv", "memory_navigation.csv", "summary.md"]:
            self.assertTrue(os.path.isfile(os.path.join(self.out, name)), name)
        self.assertIn("## Targets", self.stdout)
        self.assertIn(self.out, self.stdout)

    def test_summary_has_the_mrf_section_and_its_targets(self):
        with open(os.path.join(self.out, "summary.md")) as file:
            summary = file.read()
        self.assertIn("## MRF-smoothed transition maps", summary)
        self.assertLess(summary.index("## MRF-smoothed"), summary.index("## Targets"))
        for cells in ("sparse", "well observed"):
            for parameter in ("p_occ_given_free", "p_free_given_occ"):
                self.assertIn(f"| {cells} | {parameter} |", summary)
        # The headline: per kind of cell, only the parameters its data carry, four methods.
        self.assertIn("| kind | cells | parameter | cells per run | plain EM | MRF EM | MRF vs plain | online | "
                      "online kinds | kinds vs online | best |", summary)
        for kind, parameters in (("changing", ("p_occ_given_free", "p_free_given_occ")),
                                 ("static_free", ("p_occ_given_free",)), ("static_occupied", ("p_free_given_occ",))):
            for cells in ("sparse", "well observed"):
                for parameter in ("p_occ_given_free", "p_free_given_occ"):
                    row = f"| {kind} | {cells} | {parameter} |"
                    (self.assertIn if parameter in parameters else self.assertNotIn)(row, summary)
        self.assertLess(summary.index("| kind | cells | parameter |"), summary.index("| cells | parameter |"))
        for target in ("MRF: well-observed RMSE no higher than plain EM (each kind, the parameters its data carry)",
                       "MRF: EM time ≤ 5× plain EM"):
            self.assertIn(f"| {target}", summary)
        # The sparse-cell target is dropped: its error sat in parameters no data determine.
        self.assertNotIn("sparse-cell RMSE", summary)

    def test_memory_table_and_summary(self):
        with open(os.path.join(self.out, "memory_navigation.csv")) as file:
            rows = list(csv.DictReader(file))
        self.assertEqual([row["method"] for row in rows], ["static", "hmm", "memory"])
        for row in rows:
            self.assertEqual(row["repetitions"], "2")
            self.assertTrue(0.0 <= float(row["goal_reached_percent_mean"]) <= 100.0)
            self.assertGreaterEqual(float(row["path_ratio_mean"]), 1.0)
            self.assertGreaterEqual(float(row["replans_per_episode_mean"]), 0.0)
        # Only the memory model has an LTM.
        self.assertEqual(rows[0]["people_in_ltm_mean"], "")
        self.assertGreaterEqual(float(rows[2]["people_in_ltm_mean"]), 0.0)
        self.assertGreater(float(rows[2]["divider_cells_in_ltm_mean"]), 0.0)
        with open(os.path.join(self.out, "summary.md")) as file:
            summary = file.read()
        self.assertIn("## Memory navigation", summary)
        self.assertLess(summary.index("## Memory navigation"), summary.index("## Targets"))
        for method in ("static", "hmm", "memory"):
            self.assertIn(f"| {method} | ", summary)
        self.assertIn("| memory: people in LTM: 0 |", summary)

    def test_mrf_tables(self):
        with open(os.path.join(self.out, "mrf_rmse.csv")) as file:
            rows = list(csv.DictReader(file))
        self.assertEqual([(row["repetition"], row["method"]) for row in rows],
                         [("0", "plain"), ("0", "mrf"), ("1", "plain"), ("1", "mrf")])
        for plain, mrf in (rows[0:2], rows[2:4]):
            # The same run, so the same cells, split the same way.
            for column in ("world_seed", "run_seed", "sparse_cells", "well_observed_cells"):
                self.assertEqual(plain[column], mrf[column], column)
            self.assertEqual(plain["newton_iterations"], "0")
            self.assertGreater(int(mrf["newton_iterations"]), 0)
            for row in (plain, mrf):
                self.assertGreater(int(row["sparse_cells"]), 0)
                self.assertGreater(int(row["well_observed_cells"]), 0)
                self.assertGreater(float(row["em_seconds"]), 0.0)
                self.assertGreater(int(row["em_iterations"]), 0)
                for cells in ("sparse", "well_observed"):
                    for parameter in ("p_occ_given_free", "p_free_given_occ"):
                        value = float(row[f"{cells}_{parameter}_rmse"])
                        self.assertGreater(value, 0.0)
                        self.assertLess(value, 0.5)  # the EM's bound on the learned probabilities
        self.assertNotEqual(rows[0]["run_seed"], rows[2]["run_seed"])

        # Per kind of cell, four methods: the kinds partition each run's cells; each kind is
        # scored on the parameters its data carry (the other field empty), and their squared
        # errors are part of the whole set's.
        scored = {"changing": ("p_occ_given_free", "p_free_given_occ"), "static_free": ("p_occ_given_free",),
                  "static_occupied": ("p_free_given_occ",)}
        with open(os.path.join(self.out, "mrf_rmse_by_kind.csv")) as file:
            by_kind = list(csv.DictReader(file))
        self.assertEqual(len(by_kind), 2 * 4 * 3 * 2)
        self.assertEqual({k["method"] for k in by_kind}, {"plain", "mrf", "online", "online_kinds"})
        for k in by_kind:
            for parameter in ("p_occ_given_free", "p_free_given_occ"):
                value = k[f"{parameter}_rmse"]
                if parameter not in scored[k["kind"]]:
                    self.assertEqual(value, "", (k, parameter))
                else:
                    self.assertGreaterEqual(float(value), 0.0)
                    self.assertLess(float(value), 0.5)
        for row in rows:
            for cells in ("sparse", "well_observed"):
                for method in ONLINE_AND_OFFLINE if row["method"] == "plain" else ("mrf",):
                    mine = [k for k in by_kind if (k["repetition"], k["method"], k["observed"]) ==
                            (row["repetition"], method, cells)]
                    self.assertEqual(sorted(k["kind"] for k in mine), ["changing", "static_free", "static_occupied"])
                    total = int(row[f"{cells}_cells"])
                    self.assertEqual(sum(int(k["cells"]) for k in mine), total)  # the same cells for all four
                mine = [k for k in by_kind if (k["repetition"], k["method"], k["observed"]) ==
                        (row["repetition"], row["method"], cells)]
                for parameter in ("p_occ_given_free", "p_free_given_occ"):
                    squares = sum(int(k["cells"]) * float(k[f"{parameter}_rmse"]) ** 2 for k in mine
                                  if parameter in scored[k["kind"]])
                    self.assertLessEqual(squares, total * float(row[f"{cells}_{parameter}_rmse"]) ** 2 + 1e-6)
        # The squares' cells are seen, some of each square in both states.
        self.assertGreater(sum(int(k["cells"]) for k in by_kind if k["kind"] == "changing"), 0)
        for row in rows:
            for square in range(4):
                self.assertGreater(int(row[f"square_{square}_cells_both_states"]), 0)

        # The changing cells by what their data show: both states and one state partition them.
        with open(os.path.join(self.out, "mrf_rmse_changing.csv")) as file:
            changing = list(csv.DictReader(file))
        self.assertEqual(len(changing), 2 * 4 * 2 * 2)
        for k in by_kind:
            if k["kind"] != "changing":
                continue
            mine = [c for c in changing if (c["repetition"], c["method"], c["observed"]) ==
                    (k["repetition"], k["method"], k["observed"])]
            self.assertEqual(sorted(c["seen"] for c in mine), ["both_states", "one_state"])
            self.assertEqual(sum(int(c["cells"]) for c in mine), int(k["cells"]))
            for parameter in ("p_occ_given_free", "p_free_given_occ"):
                squares = sum(int(c["cells"]) * float(c[f"{parameter}_rmse"]) ** 2 for c in mine)
                self.assertAlmostEqual(squares, int(k["cells"]) * float(k[f"{parameter}_rmse"]) ** 2, places=5)
        with open(os.path.join(self.out, "summary.md")) as file:
            self.assertIn("| seen in both states | well observed | p_occ_given_free |", file.read())

        # The online learners: the kinds learner has its five kinds (transitions and shares
        # of the cells), cell EM none.
        with open(os.path.join(self.out, "mrf_online.csv")) as file:
            online = list(csv.DictReader(file))
        self.assertEqual([(o["repetition"], o["method"]) for o in online],
                         [(r, m) for r in ("0", "1") for m in ONLINE])
        kind_columns = [f"kind_{k}_{c}" for k in range(5) for c in ("p_occ_given_free", "p_free_given_occ", "weight")]
        for o in online:
            self.assertGreater(float(o["mapping_seconds"]), 0.0)
            self.assertNotIn("prior_p_occ_given_free", o)
            if o["method"] == "online_kinds":
                self.assertAlmostEqual(sum(float(o[f"kind_{k}_weight"]) for k in range(5)), 1.0, places=6)
                for k in range(5):
                    for parameter in ("p_occ_given_free", "p_free_given_occ"):
                        self.assertGreater(float(o[f"kind_{k}_{parameter}"]), 0.0)
                        self.assertLessEqual(float(o[f"kind_{k}_{parameter}"]), 0.5)
            else:
                self.assertEqual({o[c] for c in kind_columns}, {""})
        self.assertEqual([o["world_seed"] for o in online[::2]], [r["world_seed"] for r in rows[::2]])

        with open(os.path.join(self.out, "mrf_iterations.csv")) as file:
            iterations = list(csv.DictReader(file))
        for row in rows:
            mine = [it for it in iterations if it["repetition"] == row["repetition"] and it["method"] == row["method"]]
            self.assertEqual([int(it["iteration"]) for it in mine], list(range(int(row["em_iterations"]) + 1)))
            newton = [int(it["newton_p_occ_to_occ"]) + int(it["newton_p_free_to_free"]) for it in mine[1:]
                      if row["method"] == "mrf"]
            self.assertEqual(sum(newton), int(row["newton_iterations"]))

        with open(os.path.join(self.out, "mrf_maps.csv")) as file:
            cells = list(csv.DictReader(file))
        self.assertEqual(len(cells), MRF_WORLD[0] * MRF_WORLD[1])
        self.assertEqual({(int(c["x"]), int(c["y"])) for c in cells},
                         {(x, y) for x in range(MRF_WORLD[0]) for y in range(MRF_WORLD[1])})
        observed = [c for c in cells if int(c["observed_steps"]) > 0]
        # The first seed's cells: learned values exactly where observed; truth everywhere.
        self.assertEqual(len(observed), int(rows[0]["sparse_cells"]) + int(rows[0]["well_observed_cells"]))
        self.assertEqual(sum(int(c["observed_steps"]) < 10 for c in observed), int(rows[0]["sparse_cells"]))
        for c in cells:
            learned = [c[f"{m}_{p}"] for m in ONLINE_AND_OFFLINE for p in ("p_occ_given_free", "p_free_given_occ")]
            self.assertEqual({bool(value) for value in learned}, {int(c["observed_steps"]) > 0})
            self.assertTrue(c["truth_p_occ_given_free"] and c["truth_p_free_given_occ"])
        # The four squares' truths: 1 / hold time for holds of 7, 42, 63 and 147 steps.
        truths = {round(float(c["truth_p_occ_given_free"]), 6) for c in cells}
        self.assertEqual(truths, {0.0, round(1 / 7, 6), round(1 / 42, 6), round(1 / 63, 6), round(1 / 147, 6)})

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
                     "path_planning.png", "mrf_rmse.png", "mrf_maps.png", "murphy_corridor_fig2.png",
                     "murphy_corridor_fig3.png", "murphy_corridor_fig4.png", "murphy_corridor_tv.png",
                     "murphy_doors.png"]:
            with open(os.path.join(self.out, name), "rb") as file:
                self.assertEqual(file.read(8), b"\x89PNG\r\n\x1a\n", name)

    def test_learning_experiment(self):
        # One row per method and repetition; the summary's table and targets name every method.
        with open(os.path.join(self.out, "learning_dynamic_25_25.csv")) as file:
            rows = list(csv.DictReader(file))
        methods = [row["method"] for row in rows]
        self.assertEqual(methods, ["static", "node_static", "node_default", "textbook", "learning_off", "default",
                                   "cell_em", "offline", "oracle"])
        by_method = {row["method"]: row for row in rows}
        self.assertLess(float(by_method["oracle"]["dynamic_mae"]), 1e-6)  # the truth, rounded to float
        self.assertEqual(float(by_method["static"]["retention"]), 1.0)  # static_map keeps itself
        for row in rows:
            for key in ("accuracy_all", "accuracy_changing", "retention"):
                self.assertGreaterEqual(float(row[key]), 0.0)
                self.assertLessEqual(float(row[key]), 1.0)
        # The oracle knows the changing cells best; learning off (prior 0.01) relaxes to 0.5.
        self.assertGreater(float(by_method["oracle"]["accuracy_changing"]),
                           float(by_method["learning_off"]["accuracy_changing"]))
        with open(os.path.join(self.out, "summary.md")) as file:
            summary = file.read()
        self.assertIn("## Learning that pays off: dynamic_25_25", summary)
        self.assertIn("Accuracy per kind of cell in the same window", summary)
        self.assertIn("dynamic_25_25: online parameter MAE ≤ 0.05 at the end", summary)

    def test_murphy_corridor_tables_and_summary(self):
        # The figures' tables: 1-based t and cells as in the paper, distributions that sum to one.
        with open(os.path.join(self.out, "murphy_corridor_fig3_position.csv")) as file:
            rows = list(csv.DictReader(file))
        self.assertEqual(len(rows), 16 * 8)
        self.assertEqual((rows[0]["t"], rows[0]["cell"]), ("1", "1"))
        estimators = ("exact", "dead_reckoning", "online_em", "online_em_no_smoothing", "offline_em", "rbpf",
                      "rbpf_optimal", "exact_smoothed", "offline_em_smoothed")
        for t in range(1, 17):
            mine = [row for row in rows if row["t"] == str(t)]
            self.assertEqual(sum(int(row["truth"]) for row in mine), 1)
            for estimator in estimators:
                self.assertAlmostEqual(sum(float(row[estimator]) for row in mine), 1.0, places=4)
        # The paper's "almost 70 %" in cell 8 at t = 9.
        self.assertAlmostEqual(float(next(r for r in rows if (r["t"], r["cell"]) == ("9", "8"))["exact"]), 0.685,
                               places=3)
        with open(os.path.join(self.out, "murphy_corridor_fig2_maps.csv")) as file:
            maps = list(csv.DictReader(file))
        self.assertEqual(len(maps), 16 * 256)
        last = [row for row in maps if row["t"] == "16"]
        self.assertEqual(max(last, key=lambda row: float(row["probability"]))["labels"], "01010101")
        with open(os.path.join(self.out, "murphy_corridor_fig2_cells.csv")) as file:
            self.assertEqual(len(list(csv.DictReader(file))), 16 * 8)
        with open(os.path.join(self.out, "murphy_corridor_fig4_rbpf.csv")) as file:
            self.assertEqual(len(list(csv.DictReader(file))), 16 * 8)
        with open(os.path.join(self.out, "murphy_corridor_errors.csv")) as file:
            errors = list(csv.DictReader(file))
        self.assertEqual({row["variant"] for row in errors}, {"paper", "simulated_static", "simulated_dynamic"})
        for row in errors:
            self.assertEqual(row["runs"], "3")
            self.assertTrue(0.0 <= float(row["position_tv_mean"]) <= 1.0)
            self.assertEqual(row["map_error_mean"] == "", row["estimator"] == "dead_reckoning")
            if row["estimator"] == "exact":
                self.assertEqual(float(row["position_tv_mean"]), 0.0)
        with open(os.path.join(self.out, "murphy_corridor_particles.csv")) as file:
            sweep = list(csv.DictReader(file))
        self.assertEqual([row["particles"] for row in sweep], ["10", "50", "200", "1000"])
        # More particles, closer to exact.
        self.assertLess(float(sweep[-1]["mean_tv_mean"]), float(sweep[0]["mean_tv_mean"]))
        with open(os.path.join(self.out, "summary.md")) as file:
            summary = file.read()
        self.assertIn("## Murphy's 1D corridor", summary)
        self.assertLess(summary.index("## Murphy's 1D corridor"), summary.index("## Targets"))
        self.assertIn("| Murphy: online EM lost on the way back", summary)

    def test_murphy_doors_tables_and_summary(self):
        with open(os.path.join(self.out, "murphy_doors_runs.csv")) as file:
            rows = list(csv.DictReader(file))
        self.assertEqual([(row["run"], row["policy"]) for row in rows],
                         [("0", "entropy"), ("0", "random"), ("1", "entropy"), ("1", "random")])
        for row in rows:
            for key in ("door_accuracy", "near_door_share", "localisation", "static_accuracy"):
                self.assertTrue(0.0 <= float(row[key]) <= 1.0, (key, row))
            self.assertGreaterEqual(float(row["door_staleness_steps"]), 0.0)
        with open(os.path.join(self.out, "murphy_doors_maps.csv")) as file:
            cells = list(csv.DictReader(file))
        self.assertEqual(len(cells), 15 * 11)
        self.assertEqual(sum(1 for cell in cells if cell["cell"] == "door"), 4)
        # Each policy's robot stood somewhere 2000 times (the default steps), never on a wall.
        for policy in ("entropy", "random"):
            self.assertEqual(sum(int(cell[policy + "_visits"]) for cell in cells), 2000)
            self.assertEqual(sum(int(cell[policy + "_visits"]) for cell in cells if cell["cell"] == "wall"), 0)
        with open(os.path.join(self.out, "summary.md")) as file:
            summary = file.read()
        self.assertIn("## Murphy's 2D world with doors", summary)
        self.assertIn("| Murphy's doors: the entropy-driven robot keeps the doors more current", summary)

    def test_pose_correction_in_another_world(self):
        # --pose-correction-scenario and --pose-correction-steps pick the comparison's world
        # and length: a short parking lot run, a row per estimator, the world in the summary.
        out = os.path.join(self.tmp.name, "pose_parking")
        rc, _, stderr = evaluate(["--out", out, "--scenarios", "none", "--path-repetitions", "0",
                                  "--mrf-repetitions", "0", "--memory-repetitions", "0", "--learning-scenarios", "none",
                                  "--murphy-repetitions", "0", "--murphy-doors-runs", "0", "--pose-correction-runs", "1",
                                  "--pose-correction-scenario", "parking_lot", "--pose-correction-steps", "12",
                                  "--pose-correction-particles", "5", "--threads", "1"])
        self.assertEqual(rc, 0, stderr)
        with open(os.path.join(out, "pose_correction_errors.csv")) as file:
            rows = list(csv.DictReader(file))
        self.assertEqual([row["estimator"] for row in rows],
                         ["known_pose", "odometry", "rbpf_static", "rbpf_hmm", "rbpf_oracle"])
        with open(os.path.join(out, "pose_correction_trajectory.csv")) as file:
            self.assertEqual(len(list(csv.DictReader(file))), 12)  # one scan a step in the parking lot
        with open(os.path.join(out, "pose_correction_learned.csv")) as file:
            learned = list(csv.DictReader(file))
        self.assertEqual([(row["learner"], row["kind"]) for row in learned],
                         [(learner, kind) for learner in ("known_pose", "rbpf_hmm")
                          for kind in ("static_occupied", "static_free", "changing")])
        for row in learned:
            self.assertTrue(0.0 <= float(row["learned_changing_share"]) <= 1.0, row)
        with open(os.path.join(out, "summary.md")) as file:
            self.assertIn("## Mapping under pose uncertainty (parking_lot, 1 runs of 12", file.read())

    def test_murphy_same_seed_same_numbers_on_any_threads(self):
        again = os.path.join(self.tmp.name, "murphy_again")
        rc, _, stderr = evaluate(["--out", again, "--scenarios", "none", "--path-repetitions", "0",
                                  "--mrf-repetitions", "0", "--memory-repetitions", "0", "--learning-scenarios", "none",
                                  "--murphy-repetitions", "3", "--murphy-doors-runs", "0", "--threads", "1"])
        self.assertEqual(rc, 0, stderr)
        names = ["murphy_corridor_errors.csv", "murphy_corridor_fig2_cells.csv", "murphy_corridor_fig2_maps.csv",
                 "murphy_corridor_fig3_position.csv", "murphy_corridor_fig4_rbpf.csv", "murphy_corridor_particles.csv"]
        self.assertEqual(sorted(os.listdir(again)), names + ["summary.md"])
        for name in names:
            with open(os.path.join(self.out, name)) as a, open(os.path.join(again, name)) as b:
                self.assertEqual(a.read(), b.read(), name)

    def test_same_seed_same_numbers(self):
        again = os.path.join(self.tmp.name, "again")
        rc, _, stderr = evaluate(["--out", again, "--scenarios", "dynamic_5_5", "--repetitions", "2",
                                  "--path-repetitions", "0", "--mrf-repetitions", "0", "--memory-repetitions", "0",
                                  "--learning-repetitions", "0", "--murphy-repetitions", "0", "--murphy-doors-runs", "0", "--threads", "1"])
        self.assertEqual(rc, 0, stderr)
        with open(os.path.join(self.out, "accuracy_dynamic_5_5.csv")) as a, \
                open(os.path.join(again, "accuracy_dynamic_5_5.csv")) as b:
            self.assertEqual(a.read(), b.read())
        # --mrf-repetitions 0 skips the MRF experiment.
        self.assertFalse(os.path.exists(os.path.join(again, "mrf_rmse.csv")))
        self.assertFalse(os.path.exists(os.path.join(again, "memory_navigation.csv")))
        with open(os.path.join(again, "summary.md")) as file:
            self.assertNotIn("MRF", file.read())

    def test_mrf_same_seed_same_numbers_on_any_threads(self):
        again = os.path.join(self.tmp.name, "mrf_again")
        rc, _, stderr = evaluate(["--out", again, "--scenarios", "none", "--path-repetitions", "0",
                                  "--mrf-repetitions", "2", "--memory-repetitions", "0", "--learning-scenarios", "none",
                                  "--murphy-repetitions", "0", "--murphy-doors-runs", "0", "--threads", "1"])
        self.assertEqual(rc, 0, stderr)
        self.assertEqual(sorted(os.listdir(again)), ["mrf_iterations.csv", "mrf_maps.csv", "mrf_online.csv",
                                                     "mrf_rmse.csv", "mrf_rmse_by_kind.csv", "mrf_rmse_changing.csv",
                                                     "summary.md"])
        for name in ("mrf_maps.csv", "mrf_iterations.csv", "mrf_rmse_by_kind.csv", "mrf_rmse_changing.csv"):
            with open(os.path.join(self.out, name)) as a, open(os.path.join(again, name)) as b:
                self.assertEqual(a.read(), b.read(), name)
        # Everything but the wall time.
        tables = []
        for directory in (self.out, again):
            with open(os.path.join(directory, "mrf_rmse.csv")) as file:
                tables.append([{k: v for k, v in row.items() if k != "em_seconds"} for row in csv.DictReader(file)])
        self.assertEqual(tables[0], tables[1])

    def test_mrf_temperature_option(self):
        # Another T changes the MRF's maps only: plain EM's rows stay as they were.
        again = os.path.join(self.tmp.name, "mrf_t5")
        rc, _, stderr = evaluate(["--out", again, "--scenarios", "none", "--path-repetitions", "0",
                                  "--mrf-repetitions", "2", "--mrf-temperature", "5", "--memory-repetitions", "0",
                                  "--learning-scenarios", "none", "--murphy-repetitions", "0", "--murphy-doors-runs", "0", "--threads", "2"])
        self.assertEqual(rc, 0, stderr)
        with open(os.path.join(again, "summary.md")) as file:
            self.assertIn("with the MRF prior at T = 5.", file.read())
        tables = []
        for directory in (self.out, again):
            with open(os.path.join(directory, "mrf_rmse_by_kind.csv")) as file:
                tables.append(list(csv.DictReader(file)))
        for method in ("plain",) + ONLINE:
            self.assertEqual([r for r in tables[0] if r["method"] == method], [r for r in tables[1] if r["method"] == method])
        self.assertNotEqual([r for r in tables[0] if r["method"] == "mrf"], [r for r in tables[1] if r["method"] == "mrf"])

    def test_memory_same_seed_same_numbers_on_any_threads(self):
        again = os.path.join(self.tmp.name, "memory_again")
        rc, _, stderr = evaluate(["--out", again, "--scenarios", "none", "--path-repetitions", "0",
                                  "--mrf-repetitions", "0", "--memory-repetitions", "2", "--learning-scenarios", "none",
                                  "--murphy-repetitions", "0", "--murphy-doors-runs", "0", "--threads", "1"])
        self.assertEqual(rc, 0, stderr)
        self.assertEqual(sorted(os.listdir(again)), ["memory_navigation.csv", "summary.md"])
        tables = []
        for directory in (self.out, again):
            with open(os.path.join(directory, "memory_navigation.csv")) as file:
                tables.append([{k: v for k, v in row.items() if k != "seconds"} for row in csv.DictReader(file)])
        self.assertEqual(tables[0], tables[1])

    def test_help_and_errors_name_the_option(self):
        rc, stdout, stderr = evaluate(["--help"])
        self.assertEqual(rc, 0, stderr)
        self.assertTrue(stdout.startswith("usage: evaluate [options]"), stdout)
        for entry in ("-h [ --help ]", "--out DIR", "--scenarios A,B,...", "--mrf-temperature T", "--threads N"):
            self.assertIn(entry, stdout)
        for args, message in ((["--repetitions", "x"], "evaluate: --repetitions: needs a whole number in [1, 100000], got 'x'"),
                              (["--mrf-temperature", "0"], "evaluate: --mrf-temperature: needs a number >= 1e-09, got '0'"),
                              (["--pose-correction-particles", "0"],
                               "evaluate: --pose-correction-particles: needs a whole number in [1, 10000], got '0'"),
                              (["--pose-correction-scenario", "nope"],
                               "evaluate: --pose-correction-scenario: unknown scenario 'nope' (known: dynamic_5_5,"),
                              (["--pose-correction-steps", "1"],
                               "evaluate: --pose-correction-steps: needs a whole number in [2, 1000000], got '1'"),
                              (["--scenarios", "door"], "evaluate: --scenarios: the door scenario is the path planning"),
                              (["--seed", "1", "--seed", "2"], "'--seed' cannot be specified more than once"),
                              (["--out"], "'--out' is missing")):
            rc, _, stderr = evaluate(args)
            self.assertEqual(rc, 2, args)
            self.assertIn(message, stderr)
            self.assertIn("usage: evaluate", stderr)

    def test_errors(self):
        rc, _, stderr = evaluate(["--scenarios", "nope"])
        self.assertEqual(rc, 2)
        self.assertIn("dynamic_5_5", stderr)  # lists the names
        for args in (["--repetitions", "0"], ["--repetitions", "3000000000"], ["--scenarios", "door"],
                     ["--scenarios", "mrf_squares"], ["--mrf-repetitions", "-1"], ["--mrf-repetitions", "x"],
                     ["--mrf-temperature", "0"], ["--mrf-temperature", "1e-10"], ["--mrf-temperature", "-5"],
                     ["--mrf-temperature", "nan"],
                     ["--mrf-temperature", "inf"], ["--mrf-temperature", "5x"],
                     ["--scenarios", "dynamic_5_5,dynamic_5_5"],
                     ["--scenarios", "dividers"], ["--memory-repetitions", "-1"],
                     ["--scenarios", "none", "--path-repetitions", "0", "--mrf-repetitions", "0",
                      "--memory-repetitions", "0", "--learning-scenarios", "none", "--murphy-repetitions", "0", "--murphy-doors-runs", "0"],
                     ["--murphy-repetitions", "-1"], ["--murphy-repetitions", "x"],
                     ["--learning-scenarios", "nope"], ["--learning-repetitions", "-1"],
                     ["--learning-scenarios", "patrol,patrol"],
                     ["--pose-correction-particles", "0"], ["--pose-correction-particles", "x"],
                     ["--pose-correction-scenario", ""], ["--pose-correction-steps", "x"],
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
