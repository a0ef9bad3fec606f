#!/usr/bin/env python3
"""The bag tools (process_bag, offline_em) on the two real recordings of the package.

* data/example/stationary_laser_people.bag: a stationary laser (no tf: --laser-pose 0,0,0)
  in a static room while people walk through it;
* test/data/neato_person_follower.bag: a Neato robot driving in its odom frame.

Checks that every output is written (six layers as map_server files, the model file), that
the maps are plausible (the static room shows as a few thin walls; the robot's scans are
used), that offline EM changes the learned transitions and its objective never decreases,
that its MRF option (--mrf-temperature) reports its Newton iterations and gives other,
smoother transition maps, snapshots, time ranges, offline_em over two bags, and the error
paths (missing, truncated or damaged bag, wrong topic, bad options and temperatures).
Tolerances are test parameters (test/ros/bag_tools.test).
"""

import os
import re
import shutil
import subprocess
import sys
import tempfile
import unittest

import numpy as np
import rospkg
import rospy
import rostest
from catkin.find_in_workspaces import find_in_workspaces

import wall_scene

PKG = "dynamic_occupancy_grid"
LAYERS = ("belief", "predicted", "stationary", "p_occ_given_free", "p_free_given_occ", "static_map")
PACKAGE_DIR = rospkg.RosPack().get_path(PKG)
STATIONARY_BAG = os.path.join(PACKAGE_DIR, "data", "example", "stationary_laser_people.bag")
NEATO_BAG = os.path.join(PACKAGE_DIR, "test", "data", "neato_person_follower.bag")
STATIONARY_ARGS = ["--laser-pose", "0,0,0"]
MRF_TEMPERATURE = "50"  # the paper's T
NEATO_ARGS = ["--fixed-frame", "odom"]

sys.path.insert(0, os.path.join(PACKAGE_DIR, "scripts"))
from read_model import dense_field, load_model  # noqa: E402 (scripts/ is on the path only now)

# Test parameters (private, from bag_tools.test) and their defaults.
PARAMS = {
    "max_occupied_fraction": 0.05,  # of the observed cells of the stationary static_map
    "min_clustered_fraction": 0.6,  # occupied cells with an occupied 8-neighbour
    "min_line_fraction": 0.5,       # occupied cells in elongated clusters (walls)
    "min_integrated_fraction": 0.9,  # of the Neato's scans
    "min_changed_fraction": 0.3,    # cells whose transitions offline EM changed
    "min_mrf_changed_fraction": 0.1,  # cells whose transitions the MRF changed (against plain EM)
    "max_mrf_roughness_ratio": 0.5,   # neighbours' logit differences, MRF against plain EM
    "timeout_s": 60.0,              # per tool run
}


def executable(name):
    found = find_in_workspaces(["libexec"], project=PKG, path=name, first_match_only=True)
    if not found:
        raise RuntimeError(f"{name} not found in the catkin workspaces (built?)")
    return found[0]


def run_tool(tool, args):
    """(return code, stdout, stderr) of a tool run."""
    result = subprocess.run([executable(tool)] + [str(a) for a in args], capture_output=True, text=True,
                            errors="replace", timeout=PARAMS["timeout_s"])
    return result.returncode, result.stdout, result.stderr


def read_pgm(path):
    """A binary PGM (P5, maxval < 256) as a 2D uint8 array, rows as in the file."""
    with open(path, "rb") as file:
        data = file.read()
    fields, pos = [], 0
    while len(fields) < 4:
        while data[pos:pos + 1].isspace():
            pos += 1
        if data[pos:pos + 1] == b"#":
            pos = data.index(b"\n", pos) + 1
            continue
        end = pos
        while not data[end:end + 1].isspace():
            end += 1
        fields.append(data[pos:end])
        pos = end
    pos += 1  # the single whitespace after maxval
    if fields[0] != b"P5":
        raise ValueError(f"{path}: not a binary PGM")
    width, height = int(fields[1]), int(fields[2])
    return np.frombuffer(data[pos:pos + width * height], dtype=np.uint8).reshape(height, width)


def components(mask):
    """8-connected components of a boolean 2D array, as lists of (row, col)."""
    seen = np.zeros_like(mask, dtype=bool)
    result = []
    for start in zip(*np.nonzero(mask)):
        if seen[start]:
            continue
        seen[start] = True
        stack, cells = [start], []
        while stack:
            r, c = stack.pop()
            cells.append((r, c))
            for dr in (-1, 0, 1):
                for dc in (-1, 0, 1):
                    rr, cc = r + dr, c + dc
                    if 0 <= rr < mask.shape[0] and 0 <= cc < mask.shape[1] and mask[rr, cc] and not seen[rr, cc]:
                        seen[rr, cc] = True
                        stack.append((rr, cc))
        result.append(cells)
    return result


def parse_objective(stdout):
    match = re.search(r"^offline EM objective per iteration:(.*)$", stdout, re.M)
    return [float(v) for v in match.group(1).split()] if match else None


def parse_newton(stdout):
    """Newton iterations of each MRF M-step as (p(occ->occ), p(free->free)) pairs; None
    without the line (no MRF)."""
    match = re.search(r"^offline EM MRF Newton iterations per M-step \(p\(occ->occ\)/p\(free->free\)\):(.*)$",
                      stdout, re.M)
    return [tuple(int(n) for n in pair.split("/")) for pair in match.group(1).split()] if match else None


def logit_roughness(model):
    """Mean squared difference of the logits of p(occ -> occ) and of p(free -> free) between
    observed 8-neighbour cells: what the MRF prior penalises (THEORY.md §7)."""
    squares = []
    for field in ("p_free_given_occ", "p_occ_given_free"):
        stay, _ = dense_field(model, field)
        stay = 1.0 - stay
        logit = np.log(stay / (1.0 - stay))
        # Each pair once: right, up, up-right and down-right neighbours.
        for dy, dx in ((0, 1), (1, 0), (1, 1), (-1, 1)):
            a = logit[max(dy, 0):logit.shape[0] + min(dy, 0), dx:]
            b = logit[max(-dy, 0):logit.shape[0] + min(-dy, 0), :logit.shape[1] - dx]
            difference = (a - b)[~np.isnan(a) & ~np.isnan(b)]
            squares.append(difference ** 2)
    return np.concatenate(squares).mean()


def parse_scans(stdout):
    match = re.search(r"scans read: (\d+), integrated: (\d+), rejected: (\d+)", stdout)
    return tuple(int(v) for v in match.groups()) if match else None


class TestBagTools(unittest.TestCase):
    tmp = None
    runs = {}

    @wall_scene.reported_set_up
    def setUpClass(cls):
        cls.tmp = tempfile.mkdtemp(prefix="test_bag_tools_")

    @classmethod
    def tearDownClass(cls):
        shutil.rmtree(cls.tmp, ignore_errors=True)

    def process(self, name, bag, args):
        """process_bag on `bag` into tmp/name (once per name): (rc, stdout, stderr, out_dir)."""
        if name not in self.runs:
            out = os.path.join(self.tmp, name)
            self.runs[name] = run_tool("process_bag", [bag, "--out", out] + args) + (out,)
        return self.runs[name]

    def stationary(self, offline_em=False):
        return self.process("stationary_em" if offline_em else "stationary", STATIONARY_BAG,
                            STATIONARY_ARGS + (["--offline-em"] if offline_em else []))

    def neato(self, offline_em=False):
        return self.process("neato_em" if offline_em else "neato", NEATO_BAG,
                            NEATO_ARGS + (["--offline-em"] if offline_em else ["--snapshot-every", "10"]))

    def with_mrf(self, name, bag, args):
        """process_bag --offline-em with the MRF at the paper's temperature."""
        return self.process(name, bag, args + ["--offline-em", "--mrf-temperature", MRF_TEMPERATURE])

    def load(self, path):
        return load_model(path)

    def assert_outputs(self, run):
        rc, stdout, stderr, out = run
        self.assertEqual(rc, 0, f"exit {rc}\nstdout:\n{stdout}\nstderr:\n{stderr}")
        for layer in LAYERS:
            for ext in ("pgm", "yaml"):
                path = os.path.join(out, f"{layer}.{ext}")
                self.assertTrue(os.path.isfile(path) and os.path.getsize(path) > 0, f"{path} missing")
            self.assertIn(f"{layer}.pgm", stdout)
            with open(os.path.join(out, f"{layer}.yaml")) as file:
                self.assertIn(f"image: {layer}.pgm", file.read())
            image = read_pgm(os.path.join(out, f"{layer}.pgm"))
            self.assertTrue((image != 205).any(), f"{layer}: no known cell")
            # The values: float32, row 0 at the bottom (the PGM is north up), NaN unknown.
            values = np.load(os.path.join(out, f"{layer}.npy"))
            self.assertEqual((values.dtype, values.shape), (np.dtype("<f4"), image.shape), layer)
            upright = values[::-1]
            self.assertTrue((image[np.isnan(upright)] == 205).all(), f"{layer}: a NaN cell is not unknown")
            known = upright[~np.isnan(upright)]
            self.assertTrue(known.size > 0 and (known >= 0).all() and (known <= 1).all(), layer)
            if not layer.startswith("p_"):  # probabilities: the PGM classes are thresholds of the values
                self.assertTrue((upright[image == 0] >= 0.645).all(), layer)
                self.assertTrue((upright[image == 254] <= 0.255).all(), layer)
        model = self.load(os.path.join(out, "model.dogm"))
        self.assertGreater(model.cell_count, 1000)
        self.assertIsNotNone(model.last_applied_step)
        return model

    # --- outputs and plausibility -------------------------------------------------------

    def test_stationary_bag_writes_six_layers_and_model(self):
        self.assert_outputs(self.stationary())
        self.assertEqual(parse_scans(self.stationary()[1]), (1265, 1265, 0))

    def test_neato_bag_writes_six_layers_and_model(self):
        self.assert_outputs(self.neato())

    def test_stationary_static_map_shows_thin_walls(self):
        _, _, _, out = self.stationary()
        image = read_pgm(os.path.join(out, "static_map.pgm"))
        occupied = image == 0
        known = image != 205
        fraction = occupied.sum() / known.sum()
        self.assertGreater(occupied.sum(), 50, "no walls at all")
        self.assertLess(fraction, PARAMS["max_occupied_fraction"], "people or noise fill the static map")
        # Walls are lines: occupied cells have occupied neighbours (random noise at this
        # density would have one in ~10% of the cases) ...
        padded = np.pad(occupied, 1)
        neighbours = sum(np.roll(np.roll(padded, dr, 0), dc, 1) for dr in (-1, 0, 1) for dc in (-1, 0, 1)
                         if dr or dc)[1:-1, 1:-1]
        clustered = (occupied & (neighbours > 0)).sum() / occupied.sum()
        self.assertGreater(clustered, PARAMS["min_clustered_fraction"])
        # ... and most of them lie in elongated clusters (second principal axis much shorter).
        in_lines = 0
        for cells in components(occupied):
            if len(cells) < 5:
                continue
            spread = np.linalg.eigvalsh(np.cov(np.array(cells, dtype=float).T))
            if spread[0] < 0.15 * spread[1]:
                in_lines += len(cells)
        self.assertGreater(in_lines / occupied.sum(), PARAMS["min_line_fraction"])

    def test_max_range_turns_long_readings_into_no_return(self):
        # --max-range 1 with --max-free-range 0: readings beyond 1 m are ignored, so only the
        # cells within 1 m of the laser are mapped.
        base = self.load(os.path.join(self.neato()[3], "model.dogm"))
        rc, stdout, stderr, out = self.process("neato_max_range", NEATO_BAG,
                                               NEATO_ARGS + ["--max-range", "1", "--max-free-range", "0"])
        self.assertEqual(rc, 0, stderr)
        short = self.load(os.path.join(out, "model.dogm"))
        self.assertGreater(short.cell_count, 0)
        self.assertLess(short.cell_count, 0.5 * base.cell_count, stdout)

    def test_neato_bag_uses_most_scans(self):
        rc, stdout, _, out = self.neato()
        self.assertEqual(rc, 0)
        read, integrated, rejected = parse_scans(stdout)
        self.assertGreater(read, 150)
        self.assertGreaterEqual(integrated / read, PARAMS["min_integrated_fraction"], stdout)
        self.assertEqual(rejected, 0)
        for layer in ("static_map", "belief"):
            self.assertGreater((read_pgm(os.path.join(out, f"{layer}.pgm")) == 0).sum(), 50, layer)

    # --- offline EM -----------------------------------------------------------------------

    def check_offline_em(self, online, offline):
        online_model = self.assert_outputs(online)
        offline_model = self.assert_outputs(offline)
        stdout = offline[1]
        objective = parse_objective(stdout)
        self.assertIsNotNone(objective, stdout)
        self.assertGreater(len(objective), 1)
        for before, after in zip(objective, objective[1:]):
            self.assertGreaterEqual(after, before - 1e-9 * abs(before) - 1e-6, "EM objective decreased")
        self.assertGreater(objective[-1], objective[0])
        self.assertRegex(stdout, r"offline EM: \d+ iterations .*, \d+ of \d+ cells converged")
        # The same cells, other transitions.
        self.assertEqual(online_model.cell_count, offline_model.cell_count)
        np.testing.assert_array_equal(online_model.x, offline_model.x)
        np.testing.assert_array_equal(online_model.y, offline_model.y)
        changed = ((np.abs(online_model.p_occ_given_free - offline_model.p_occ_given_free) > 1e-3) |
                   (np.abs(online_model.p_free_given_occ - offline_model.p_free_given_occ) > 1e-3))
        self.assertGreater(changed.mean(), PARAMS["min_changed_fraction"])
        for field in ("p_occ_given_free", "p_free_given_occ"):
            values = offline_model[field]
            self.assertTrue(((values >= 1e-4 - 1e-7) & (values <= 0.5 + 1e-7)).all(), field)
        # The exported transition layers differ too.
        self.assertFalse(np.array_equal(read_pgm(os.path.join(online[3], "p_free_given_occ.pgm")),
                                        read_pgm(os.path.join(offline[3], "p_free_given_occ.pgm"))))

    def test_offline_em_changes_transitions_stationary(self):
        self.check_offline_em(self.stationary(), self.stationary(offline_em=True))

    def test_offline_em_changes_transitions_neato(self):
        self.check_offline_em(self.neato(), self.neato(offline_em=True))

    def test_em_prior_weight_pulls_towards_prior(self):
        rc, stdout, stderr, out = self.process("neato_em_prior", NEATO_BAG,
                                               NEATO_ARGS + ["--offline-em", "--em-prior-weight", "10"])
        self.assertEqual(rc, 0, stderr)
        rc, stdout, stderr, ml_out = self.process("neato_em_ml", NEATO_BAG,
                                                  NEATO_ARGS + ["--offline-em", "--em-prior-weight", "0"])
        self.assertEqual(rc, 0, stderr)
        ml = load_model(os.path.join(ml_out, "model.dogm"))
        map_estimate = load_model(os.path.join(out, "model.dogm"))
        prior = 0.01
        for field in ("p_occ_given_free", "p_free_given_occ"):
            self.assertLess(np.abs(map_estimate[field] - prior).mean(), np.abs(ml[field] - prior).mean(), field)

    def check_mrf(self, plain_stdout, plain_model, mrf_stdout, mrf_model):
        """Offline EM with the MRF against plain EM on the same bag: the Newton iterations are
        reported (one pair per M-step, only with the MRF) and the transition maps differ and
        are smoother."""
        self.assertIsNone(parse_newton(plain_stdout), plain_stdout)
        self.assertIn(f"MRF temperature {MRF_TEMPERATURE}", mrf_stdout)
        self.assertRegex(mrf_stdout, r"offline EM: \d+ iterations \(all cells together\)")
        newton = parse_newton(mrf_stdout)
        self.assertIsNotNone(newton, mrf_stdout)
        self.assertEqual(len(newton), len(parse_objective(mrf_stdout)) - 1, mrf_stdout)
        self.assertTrue(all(occ >= 0 and free >= 0 for occ, free in newton), newton)
        self.assertTrue(newton[0][0] > 0 and newton[0][1] > 0, "the first M-step made no Newton step")
        np.testing.assert_array_equal(plain_model.x, mrf_model.x)
        np.testing.assert_array_equal(plain_model.y, mrf_model.y)
        changed = ((np.abs(plain_model.p_occ_given_free - mrf_model.p_occ_given_free) > 1e-3) |
                   (np.abs(plain_model.p_free_given_occ - mrf_model.p_free_given_occ) > 1e-3))
        self.assertGreater(changed.mean(), PARAMS["min_mrf_changed_fraction"])
        self.assertLess(logit_roughness(mrf_model), PARAMS["max_mrf_roughness_ratio"] * logit_roughness(plain_model))

    def test_offline_em_mrf_stationary(self):
        mrf = self.with_mrf("stationary_mrf", STATIONARY_BAG, STATIONARY_ARGS)
        plain = self.stationary(offline_em=True)
        self.check_offline_em(self.stationary(), mrf)
        self.check_mrf(plain[1], self.assert_outputs(plain), mrf[1], self.assert_outputs(mrf))

    def test_offline_em_mrf_neato(self):
        mrf = self.with_mrf("neato_mrf", NEATO_BAG, NEATO_ARGS)
        plain = self.neato(offline_em=True)
        self.check_offline_em(self.neato(), mrf)
        self.check_mrf(plain[1], self.assert_outputs(plain), mrf[1], self.assert_outputs(mrf))

    def test_offline_em_tool_mrf(self):
        runs = []
        for name, extra in (("plain", []), ("mrf", ["--mrf-temperature", MRF_TEMPERATURE])):
            model_path = os.path.join(self.tmp, f"tool_{name}.dogm")
            rc, stdout, stderr = run_tool("offline_em", [NEATO_BAG, "--out", model_path] + NEATO_ARGS + extra)
            self.assertEqual(rc, 0, stderr)
            runs += [stdout, self.load(model_path)]
        self.check_mrf(*runs)

    def test_offline_em_tool_on_two_bags(self):
        model_path = os.path.join(self.tmp, "two_bags.dogm")
        rc, stdout, stderr = run_tool("offline_em", [NEATO_BAG, NEATO_BAG, "--out", model_path] + NEATO_ARGS)
        self.assertEqual(rc, 0, stderr)
        self.assertEqual(stdout.count(NEATO_BAG + ":"), 2)
        self.assertRegex(stdout, r"offline EM: \d+ iterations .*, \d+ of \d+ cells converged, objective ")
        objective = parse_objective(stdout)
        self.assertGreater(objective[-1], objective[0])
        self.assertIn("model -> " + model_path, stdout)
        model = self.load(model_path)
        # The second bag continues the timeline of the first: about twice the steps.
        single = self.load(os.path.join(self.neato()[3], "model.dogm"))
        self.assertGreaterEqual(model.last_applied_step + 1, 2 * (single.last_applied_step + 1) - 1)
        self.assertGreater(model.cell_count, 1000)

    def test_static_transform_from_tf_static(self):
        """A bag whose only transform is on /tf_static: the same map as with --laser-pose."""
        import rosbag
        from geometry_msgs.msg import TransformStamped
        from tf2_msgs.msg import TFMessage
        path = os.path.join(self.tmp, "tf_static.bag")
        with rosbag.Bag(STATIONARY_BAG) as source, rosbag.Bag(path, "w") as target:
            for count, (topic, msg, stamp) in enumerate(source.read_messages(topics=["/scan"])):
                if count == 0:
                    transform = TransformStamped()
                    transform.header.stamp = msg.header.stamp
                    transform.header.frame_id = "map"
                    transform.child_frame_id = msg.header.frame_id
                    transform.transform.rotation.w = 1.0
                    target.write("/tf_static", TFMessage([transform]), stamp)
                if count == 200:
                    break
                target.write(topic, msg, stamp)
        runs = [run_tool("process_bag", [path, "--out", os.path.join(self.tmp, name)] + args)
                for name, args in (("tf_static", ["--fixed-frame", "map"]), ("tf_static_pose", STATIONARY_ARGS))]
        for rc, stdout, stderr in runs:
            self.assertEqual(rc, 0, stderr)
            self.assertEqual(parse_scans(stdout), (200, 200, 0))
        self.assertIn("without a pose in 'map': 0", runs[0][1])
        for layer in LAYERS:
            np.testing.assert_array_equal(read_pgm(os.path.join(self.tmp, "tf_static", f"{layer}.pgm")),
                                          read_pgm(os.path.join(self.tmp, "tf_static_pose", f"{layer}.pgm")))

    # --- snapshots and time range -------------------------------------------------------

    def test_snapshots(self):
        rc, stdout, _, out = self.neato()
        self.assertEqual(rc, 0)
        snapshots = sorted(os.listdir(os.path.join(out, "snapshots")))
        self.assertEqual(snapshots, ["10s", "20s", "30s", "40s"])
        for name in snapshots:
            for layer in LAYERS:
                self.assertTrue(os.path.isfile(os.path.join(out, "snapshots", name, f"{layer}.pgm")))
        # Knowledge grows as the bag is read.
        known = [(read_pgm(os.path.join(out, "snapshots", name, "static_map.pgm")) != 205).sum()
                 for name in snapshots]
        self.assertEqual(known, sorted(known))

    def test_time_range(self):
        origin = self.load(os.path.join(self.neato()[3], "model.dogm"))
        start = origin.clock_origin_s + 10.0
        out = os.path.join(self.tmp, "neato_range")
        rc, stdout, stderr = run_tool("process_bag", [NEATO_BAG, "--out", out, "--start-time", start,
                                                      "--end-time", start + 20.0] + NEATO_ARGS)
        self.assertEqual(rc, 0, stderr)
        read, integrated, _ = parse_scans(stdout)
        self.assertGreater(read, 60)
        self.assertLess(read, 120)  # 196 scans over 42 s
        self.assertRegex(stdout, r"outside the time range: \d+")

    # --- errors ---------------------------------------------------------------------------

    def assert_fails(self, tool, args, rc_expected, *words):
        rc, stdout, stderr = run_tool(tool, args)
        self.assertEqual(rc, rc_expected, f"{tool} {args}: exit {rc}\nstdout:\n{stdout}\nstderr:\n{stderr}")
        for word in words:
            self.assertIn(word, stderr)
        return stderr

    def test_missing_bag(self):
        missing = os.path.join(self.tmp, "no_such.bag")
        self.assert_fails("process_bag", [missing, "--out", os.path.join(self.tmp, "x")], 1, missing, "does not exist")
        self.assert_fails("offline_em", [NEATO_BAG, missing, "--out", os.path.join(self.tmp, "x.dogm")], 1, missing)

    def test_truncated_bag(self):
        with open(NEATO_BAG, "rb") as file:
            data = file.read()
        for fraction in (0.0, 0.01, 0.5, 0.999):
            path = os.path.join(self.tmp, f"truncated_{fraction}.bag")
            with open(path, "wb") as file:
                file.write(data[:int(len(data) * fraction)])
            stderr = self.assert_fails("process_bag", [path, "--out", os.path.join(self.tmp, "x")] + NEATO_ARGS,
                                       1, path)
            self.assertRegex(stderr, r"truncated|corrupt")
            self.assert_fails("offline_em", [path, "--out", os.path.join(self.tmp, "x.dogm")] + NEATO_ARGS, 1, path)

    def test_damaged_bag_does_not_crash(self):
        with open(NEATO_BAG, "rb") as file:
            data = bytearray(file.read())
        for seed, start in enumerate((len(data) // 3, len(data) // 2, 2 * len(data) // 3)):
            damaged = bytearray(data)
            damaged[start:start + 4096] = bytes(4096)  # a block of zeros inside the chunks
            path = os.path.join(self.tmp, f"damaged_{seed}.bag")
            with open(path, "wb") as file:
                file.write(damaged)
            rc, _, stderr = run_tool("process_bag", [path, "--out", os.path.join(self.tmp, "damaged")] + NEATO_ARGS)
            self.assertIn(rc, (0, 1), f"crashed: exit {rc}\n{stderr}")
            if rc == 1:
                self.assertIn(path, stderr)

    def test_wrong_topic(self):
        stderr = self.assert_fails("process_bag", [NEATO_BAG, "--topic", "/no_such_scan", "--out",
                                                   os.path.join(self.tmp, "x")], 1, "/no_such_scan", NEATO_BAG)
        self.assertIn("/scan", stderr)  # the LaserScan topics the bag has
        self.assert_fails("process_bag", [NEATO_BAG, "--topic", "/odom", "--out", os.path.join(self.tmp, "x")], 1,
                          "nav_msgs/Odometry")

    def test_bag_without_tf_needs_laser_pose(self):
        self.assert_fails("process_bag", [STATIONARY_BAG, "--out", os.path.join(self.tmp, "x")], 1, "--laser-pose")

    def test_bad_options(self):
        out = ["--out", os.path.join(self.tmp, "x")]
        for args in ([NEATO_BAG, "--resolution", "-1"], [NEATO_BAG, "--resolution", "abc"],
                     [NEATO_BAG, "--em-iterations", "0"], [NEATO_BAG, "--threads", "two"],
                     [NEATO_BAG, "--p-hit-given-occ", "1.5"], [NEATO_BAG, "--p-hit-given-occ", "0.1"],
                     [NEATO_BAG, "--laser-pose", "1,2"], [NEATO_BAG, "--snapshot-every", "0"],
                     [NEATO_BAG, "--max-range", "0"], [NEATO_BAG, "--max-range", "-2"],
                     [NEATO_BAG, "--no-such-option"], [NEATO_BAG, "--time-step"], [NEATO_BAG, NEATO_BAG], []):
            self.assert_fails("process_bag", args + out, 2, "usage: process_bag")
        self.assert_fails("offline_em", [NEATO_BAG], 2, "--out", "usage: offline_em")
        self.assert_fails("offline_em", ["--out", os.path.join(self.tmp, "x.dogm")], 2, "no bag")
        self.assert_fails("offline_em", [NEATO_BAG, "--em-tolerance", "-1", "--out", "x.dogm"], 2, "usage: offline_em")

    def test_help_and_errors_name_the_option(self):
        """--help prints the generated usage; a bad value, a missing or repeated option is named."""
        for tool in ("process_bag", "offline_em"):
            rc, stdout, stderr = run_tool(tool, ["--help"])
            self.assertEqual(rc, 0, stderr)
            self.assertTrue(stdout.startswith(f"usage: {tool} BAG"), stdout)
            for entry in ("-h [ --help ]", "--out ", "--resolution M", "--laser-pose X,Y,YAW", "--threads N"):
                self.assertIn(entry, stdout)
            self.assertEqual(stderr, "")
        out = ["--out", os.path.join(self.tmp, "named")]
        self.assert_fails("process_bag", [NEATO_BAG, "--resolution", "abc"] + out, 2,
                          "process_bag: --resolution: needs a number > 0, got 'abc'", "usage: process_bag")
        self.assert_fails("process_bag", [NEATO_BAG, "--threads", "-1"] + out, 2,
                          "process_bag: --threads: needs a whole number in [0, 1024], got '-1'")
        self.assert_fails("process_bag", [NEATO_BAG, "--laser-pose", "1,2,x"] + out, 2,
                          "process_bag: --laser-pose: needs X,Y,YAW")
        self.assert_fails("process_bag", [NEATO_BAG, "--resolution", "0.1", "--resolution", "0.2"] + out, 2,
                          "'--resolution' cannot be specified more than once")
        self.assert_fails("process_bag", [NEATO_BAG, "--res", "0.1"] + out, 2, "unrecognised option '--res'")
        self.assert_fails("offline_em", [NEATO_BAG], 2, "'--out' is required")

    def test_bad_mrf_temperature(self):
        out_dir = os.path.join(self.tmp, "refused_mrf")
        model_path = os.path.join(self.tmp, "refused_mrf.dogm")
        for value in ("-1", "-1e-9", "nan", "inf", "abc", ""):
            for tool, args in (("process_bag", [NEATO_BAG, "--offline-em", "--out", out_dir]),
                               ("offline_em", [NEATO_BAG, "--out", model_path])):
                self.assert_fails(tool, args + ["--mrf-temperature", value], 2, f"{tool}: --mrf-temperature",
                                  f"usage: {tool}", "--mrf-temperature T")
        self.assert_fails("offline_em", [NEATO_BAG, "--out", model_path, "--mrf-temperature"], 2,
                          "'--mrf-temperature' is missing")
        # Refused before any work: nothing written.
        self.assertFalse(os.path.exists(out_dir))
        self.assertFalse(os.path.exists(model_path))


if __name__ == "__main__":
    rospy.init_node("test_bag_tools", anonymous=True)
    for name, default in PARAMS.items():
        PARAMS[name] = rospy.get_param("~" + name, default)
    rostest.rosrun(PKG, "test_bag_tools", TestBagTools)
