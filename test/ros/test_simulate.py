#!/usr/bin/env python3
"""The simulate tool: a simulated run of a scenario written to a bag.

* the bag of dynamic_5_5 (300 steps by default): topics, message counts, frames, stamps and
  the scan geometry; the laser's end points against the true occupancy; the true dynamics
  read back from /ground_truth: the change rates (binomial tolerance computed from the
  counts) and the share of dynamic cells;
* process_bag on that bag: its belief layer against the last true state, its learned
  transitions against the true ones;
* every scenario writes a readable bag; a re-draw writes the new true transitions; the same
  seeds give the same bag;
* the error paths (unknown scenario, bad options, unwritable output, a full disk).

Tolerances are test parameters (test/ros/simulate.test).
"""

import math
import os
import re
import resource
import shutil
import signal
import subprocess
import sys
import tempfile
import unittest

import numpy as np
import rosbag
import rospkg
import rospy
import rostest
import yaml
# This directory is on the path (the script's own): the bag tools' test has the helpers.
from test_bag_tools import executable, read_pgm
import wall_scene

PKG = "dynamic_occupancy_grid"
sys.path.insert(0, os.path.join(rospkg.RosPack().get_path(PKG), "scripts"))
from read_model import load_model  # noqa: E402 (scripts/ is on the path only now)

START_TIME_S = 1.0e9  # simulation time 0 in ROS time (simulate.cpp)
SCENARIOS = ("dynamic_5_5", "dynamic_25_25", "redraw_100", "redraw_300", "parking_lot", "door", "mrf_squares", "dividers")
# dynamic_5_5's configuration (evaluation/simulator.cpp, scenarioConfig): what the data must show.
CHANGE_PROBABILITY = 0.05
DYNAMIC_FRACTION = 0.05
TIME_STEP_S = 1.0
WORLD_CELLS = (50, 50)  # width, height
RESOLUTION_M = 0.1
LASER_MOUNT_X_M = 0.05
TRANSITION_SCALE = 0.1  # simulate's default: this probability per step is written as 100

# Test parameters (private, from simulate.test) and their defaults.
PARAMS = {
    "steps": 300,                   # of the dynamic_5_5 run
    "world_seed": 1,                # and its seeds
    "seed": 1,
    "rate_sigmas": 4.0,             # change rates: allowed deviation in binomial standard deviations
    "lane_half_width_m": 0.3,       # the robot's lane (no dynamic cells): within this of its path
    "dynamic_count_tolerance": 0,   # dynamic cells: allowed difference (cells) to the configured share
    "endpoint_tolerance_m": 0.03,   # 3 sigma of dynamic_5_5's range noise
    "min_endpoint_fraction": 0.999,  # finite beams ending within endpoint_tolerance_m of an occupied cell
    "min_accuracy": 0.97,           # process_bag's belief: correct / classified cells
    "min_wall_occupied": 0.98,      # of the classified wall cells
    "min_wall_seen": 0.7,           # of the wall cells facing the room
    "min_lane_free": 0.99,          # of the classified lane cells
    "min_lane_seen": 0.95,          # of the lane cells
    "min_learned_ratio": 4.0,       # learned rates, dynamic over never-changing cells
    "timeout_s": 60.0,              # per tool run
    "rbpf_steps": 120,              # process_bag --pose-correction rbpf: patrol_office steps
    "rbpf_seed": 12,                # its world and run seed
    "rbpf_odometry_noise": "0.02,0.001,0.01,0.005",
    "rbpf_max_error_ratio": 0.5,    # corrected mean position error at most this share of odometry's
}


def run_tool(tool, args, preexec_fn=None):
    """(return code, stdout, stderr) of a tool run."""
    # The sanitized run (test/sanitizers/run_sanitized.sh) scales the time its slower tools get.
    timeout = PARAMS["timeout_s"] * float(os.environ.get("DOG_TEST_TIMEOUT_SCALE", "1"))
    result = subprocess.run([executable(tool)] + [str(a) for a in args], capture_output=True, text=True,
                            errors="replace", timeout=timeout, preexec_fn=preexec_fn)
    return result.returncode, result.stdout, result.stderr


def read_bag(path):
    """{topic: [(message, bag time in s, connection header)]} in bag order."""
    topics = {}
    with rosbag.Bag(path) as bag:
        for topic, msg, stamp, header in bag.read_messages(return_connection_header=True):
            topics.setdefault(topic, []).append((msg, stamp.to_sec(), header))
    return topics


def grid(msg):
    """An OccupancyGrid's data as a 2D array, row = y."""
    return np.array(msg.data, dtype=np.int16).reshape(msg.info.height, msg.info.width)


def yaw(rotation):
    """Yaw of a quaternion that rotates about z only."""
    return 2.0 * math.atan2(rotation.z, rotation.w)


def laser_pose(robot, mount):
    """(x, y, yaw) of the laser: the transforms odom -> base_link and base_link -> laser chained."""
    heading = yaw(robot.rotation)
    cos, sin = math.cos(heading), math.sin(heading)
    return (robot.translation.x + cos * mount.translation.x - sin * mount.translation.y,
            robot.translation.y + sin * mount.translation.x + cos * mount.translation.y,
            heading + yaw(mount.rotation))


def read_layer(directory, name):
    """A map_server layer (PGM + YAML) as (image with row 0 = south, as the grid, yaml dict)."""
    with open(os.path.join(directory, name + ".yaml")) as file:
        info = yaml.safe_load(file)
    return read_pgm(os.path.join(directory, info["image"]))[::-1], info


class TestSimulate(unittest.TestCase):
    tmp = None
    bag_path = None
    topics = None

    @wall_scene.reported_set_up
    def setUpClass(cls):
        cls.tmp = tempfile.mkdtemp(prefix="test_simulate_")
        cls.bag_path = os.path.join(cls.tmp, "dynamic_5_5.bag")
        cls.simulate_run = run_tool("simulate", ["--scenario", "dynamic_5_5", "--steps", PARAMS["steps"],
                                                 "--world-seed", PARAMS["world_seed"], "--seed", PARAMS["seed"],
                                                 "--out", cls.bag_path])
        cls.topics = read_bag(cls.bag_path) if cls.simulate_run[0] == 0 else {}

    @classmethod
    def tearDownClass(cls):
        shutil.rmtree(cls.tmp, ignore_errors=True)

    def setUp(self):
        rc, stdout, stderr = self.simulate_run
        self.assertEqual(rc, 0, f"simulate failed: exit {rc}\nstdout:\n{stdout}\nstderr:\n{stderr}")

    # --- the data of the run ----------------------------------------------------------------

    def truth(self):
        """True states (steps x height x width, True = occupied) and their stamps."""
        messages = self.topics["/ground_truth"]
        return np.array([grid(m) == 100 for m, _, _ in messages]), np.array([t for _, t, _ in messages])

    def robot_positions(self):
        return np.array([[m.transforms[0].transform.translation.x, m.transforms[0].transform.translation.y]
                         for m, _, _ in self.topics["/tf"]])

    def cell_centres(self):
        info = self.topics["/ground_truth"][0][0].info
        ys, xs = np.mgrid[0:info.height, 0:info.width]
        return (xs + 0.5) * info.resolution, (ys + 0.5) * info.resolution

    def lane(self):
        """Cells whose centre lies within the lane's half width of a robot position (in both
        coordinates: the simulator's lane is a band around an axis-aligned loop)."""
        cx, cy = self.cell_centres()
        lane = np.zeros(cx.shape, dtype=bool)
        half = PARAMS["lane_half_width_m"]
        for x, y in self.robot_positions():
            lane |= (np.abs(cx - x) < half) & (np.abs(cy - y) < half)
        return lane

    # --- (a) the bag ---------------------------------------------------------------------------

    def test_topics_and_counts(self):
        steps = PARAMS["steps"]
        counts = {topic: len(messages) for topic, messages in self.topics.items()}
        self.assertEqual(counts, {"/scan": steps, "/tf": steps, "/tf_static": 1, "/ground_truth": steps,
                                  "/ground_truth_p_occ_given_free": 1, "/ground_truth_p_free_given_occ": 1})
        self.assertIn(f"-> {self.bag_path}", self.simulate_run[1])

    def test_frames(self):
        for msg, _, _ in self.topics["/scan"]:
            self.assertEqual(msg.header.frame_id, "laser")
        for msg, _, _ in self.topics["/tf"]:
            self.assertEqual([(t.header.frame_id, t.child_frame_id) for t in msg.transforms], [("odom", "base_link")])
        (mount, _, header), = self.topics["/tf_static"]
        self.assertEqual([(t.header.frame_id, t.child_frame_id) for t in mount.transforms], [("base_link", "laser")])
        # Recorded as from a latched publisher, as rosbag record keeps /tf_static.
        self.assertEqual(header.get("latching"), b"1")
        translation = mount.transforms[0].transform.translation
        self.assertAlmostEqual(translation.x, LASER_MOUNT_X_M)
        self.assertAlmostEqual(translation.y, 0.0)
        for topic in ("/ground_truth", "/ground_truth_p_occ_given_free", "/ground_truth_p_free_given_occ"):
            for msg, _, _ in self.topics[topic]:
                self.assertEqual(msg.header.frame_id, "odom")
                self.assertEqual((msg.info.width, msg.info.height), WORLD_CELLS)
                self.assertAlmostEqual(msg.info.resolution, RESOLUTION_M, places=6)
                origin = msg.info.origin
                self.assertEqual((origin.position.x, origin.position.y, origin.orientation.w), (0.0, 0.0, 1.0))

    def test_stamps(self):
        for topic, messages in self.topics.items():
            stamps = [msg.header.stamp.to_sec() if hasattr(msg, "header") else msg.transforms[0].header.stamp.to_sec()
                      for msg, _, _ in messages]
            # Recorded when stamped ...
            np.testing.assert_allclose(stamps, [t for _, t, _ in messages], atol=1e-6, err_msg=topic)
            # ... in order, from simulation time 0.
            self.assertTrue(all(b > a for a, b in zip(stamps, stamps[1:])), topic)
            self.assertGreaterEqual(stamps[0], START_TIME_S, topic)
        _, truth_stamps = self.truth()
        np.testing.assert_allclose(truth_stamps - START_TIME_S, np.arange(PARAMS["steps"]) * TIME_STEP_S, atol=1e-6)
        # Scan k and its odometry fall into step k.
        scan_stamps = np.array([t for _, t, _ in self.topics["/scan"]])
        self.assertTrue(((scan_stamps >= truth_stamps) & (scan_stamps < truth_stamps + TIME_STEP_S)).all())
        np.testing.assert_allclose(scan_stamps, [t for _, t, _ in self.topics["/tf"]], atol=1e-6)

    def test_scan_geometry(self):
        for msg, _, _ in self.topics["/scan"]:
            beams = round((msg.angle_max - msg.angle_min) / msg.angle_increment) + 1
            self.assertEqual(len(msg.ranges), beams)
            self.assertTrue(0.0 <= msg.range_min < msg.range_max)
            ranges = np.array(msg.ranges)
            finite = np.isfinite(ranges)
            # Readings in range; the rest are +inf (no return) or NaN (dropout).
            self.assertTrue(((ranges[finite] >= msg.range_min) & (ranges[finite] < msg.range_max)).all())
            self.assertTrue((np.isnan(ranges) | (ranges == np.inf) | finite).all())
        self.assertGreater(np.mean([np.isfinite(m.ranges).mean() for m, _, _ in self.topics["/scan"]]), 0.5)

    def test_end_points_hit_occupied_cells(self):
        """The scans, placed with /tf and /tf_static, see the true world: their end points
        lie in or next to (within the range noise: a beam that clips a cell's corner has a
        short chord there) occupied cells. Frames, angles and stamps all have to agree."""
        states, truth_stamps = self.truth()
        resolution = self.topics["/ground_truth"][0][0].info.resolution
        mount = self.topics["/tf_static"][0][0].transforms[0].transform
        near = total = 0
        for (scan, stamp, _), (odometry, _, _) in zip(self.topics["/scan"], self.topics["/tf"]):
            laser_x, laser_y, laser_yaw = laser_pose(odometry.transforms[0].transform, mount)
            ranges = np.array(scan.ranges)
            angles = laser_yaw + scan.angle_min + scan.angle_increment * np.arange(ranges.size)
            finite = np.isfinite(ranges)
            end_x = laser_x + ranges[finite] * np.cos(angles[finite])
            end_y = laser_y + ranges[finite] * np.sin(angles[finite])
            occupied = np.pad(states[np.searchsorted(truth_stamps, stamp, side="right") - 1], 1)
            found = np.zeros(end_x.shape, dtype=bool)
            for dx in (-1, 0, 1):
                for dy in (-1, 0, 1):
                    cell_x = np.floor(end_x / resolution).astype(int) + dx
                    cell_y = np.floor(end_y / resolution).astype(int) + dy
                    # Distance from the end point to the square of that cell.
                    gap_x = np.maximum(np.maximum(cell_x * resolution - end_x, end_x - (cell_x + 1) * resolution), 0.0)
                    gap_y = np.maximum(np.maximum(cell_y * resolution - end_y, end_y - (cell_y + 1) * resolution), 0.0)
                    inside = (cell_x >= -1) & (cell_y >= -1) & (cell_x <= occupied.shape[1] - 2) & \
                        (cell_y <= occupied.shape[0] - 2)
                    is_occupied = np.zeros_like(found)
                    is_occupied[inside] = occupied[cell_y[inside] + 1, cell_x[inside] + 1]
                    found |= is_occupied & (np.hypot(gap_x, gap_y) <= PARAMS["endpoint_tolerance_m"])
            near += found.sum()
            total += finite.sum()
        self.assertGreater(total, 0)
        self.assertGreaterEqual(near / total, PARAMS["min_endpoint_fraction"], f"{near} of {total} end points")

    def test_change_rates_match_configuration(self):
        """Free -> occupied and occupied -> free rates of the cells that change, pooled over
        cells and steps, within rate_sigmas binomial standard deviations of the configured
        probability (each step of a cell is a Bernoulli trial given its state)."""
        states, _ = self.truth()
        changing = (states != states[0]).any(axis=0)
        self.assertGreater(changing.sum(), 0)
        before, after = states[:-1][:, changing], states[1:][:, changing]
        for name, was, becomes in (("p_occ_given_free", ~before, after), ("p_free_given_occ", before, ~after)):
            trials = was.sum()
            changes = (was & becomes).sum()
            sigma = math.sqrt(CHANGE_PROBABILITY * (1.0 - CHANGE_PROBABILITY) / trials)
            rate = changes / trials
            self.assertLess(abs(rate - CHANGE_PROBABILITY), PARAMS["rate_sigmas"] * sigma,
                            f"{name}: {changes} changes in {trials} steps = {rate:.4f}, sigma {sigma:.4f}")
        # Cells that never change are static: a dynamic cell keeps its state for all the
        # steps with probability (1 - p)^(steps - 1), 2e-7 for 300 steps.
        truth = grid(self.topics["/ground_truth_p_occ_given_free"][0][0])
        np.testing.assert_array_equal(changing, truth > 0)
        expected = round(CHANGE_PROBABILITY / TRANSITION_SCALE * 100)
        self.assertEqual(set(np.unique(truth[changing])), {expected})
        np.testing.assert_array_equal(grid(self.topics["/ground_truth_p_free_given_occ"][0][0]), truth)

    def test_share_of_dynamic_cells(self):
        """The configured share of the candidate cells (free, off the robot's lane) is dynamic:
        the simulator draws round(share * candidates) of them."""
        states, _ = self.truth()
        changing = (states != states[0]).any(axis=0)
        candidates = (~states).any(axis=0) & ~self.lane()
        self.assertFalse((changing & self.lane()).any(), "a dynamic cell on the robot's lane")
        self.assertLessEqual(abs(changing.sum() - DYNAMIC_FRACTION * candidates.sum()),
                             0.5 + PARAMS["dynamic_count_tolerance"],
                             f"{changing.sum()} dynamic of {candidates.sum()} candidate cells")

    # --- (b) process_bag on the run ----------------------------------------------------------

    def process_bag(self):
        """process_bag on the run (once): its output directory."""
        out = os.path.join(self.tmp, "process_bag")
        if not os.path.isdir(out):
            rc, stdout, stderr = run_tool("process_bag", [self.bag_path, "--out", out, "--resolution", RESOLUTION_M,
                                                          "--time-step", TIME_STEP_S])
            self.assertEqual(rc, 0, f"exit {rc}\nstdout:\n{stdout}\nstderr:\n{stderr}")
            self.assertIn(f"scans read: {PARAMS['steps']}, integrated: {PARAMS['steps']}, rejected: 0", stdout)
        return out

    def test_process_bag_belief_matches_last_truth(self):
        image, layer = read_layer(self.process_bag(), "belief")
        width, height = WORLD_CELLS
        self.assertAlmostEqual(layer["resolution"], RESOLUTION_M, places=6)
        # The layer's pixels as world cells (both lattices start at multiples of the resolution).
        offset_x = round(layer["origin"][0] / RESOLUTION_M)
        offset_y = round(layer["origin"][1] / RESOLUTION_M)
        occupied = np.zeros((height, width), dtype=bool)
        free = np.zeros_like(occupied)
        rows, cols = np.mgrid[0:image.shape[0], 0:image.shape[1]]
        world_x, world_y = cols + offset_x, rows + offset_y
        inside = (world_x >= 0) & (world_y >= 0) & (world_x < width) & (world_y < height)
        occupied[world_y[inside], world_x[inside]] = image[inside] == 0
        free[world_y[inside], world_x[inside]] = image[inside] == 254
        # Nothing classified outside the world.
        self.assertFalse(((image == 0) | (image == 254))[~inside].any())

        states, _ = self.truth()
        last = states[-1]
        classified = occupied | free
        accuracy = ((occupied & last) | (free & ~last)).sum() / classified.sum()
        walls = states.all(axis=0)
        # Wall cells facing the room: next to a cell that is free at some time.
        open_cells = (~states).any(axis=0)
        padded = np.pad(open_cells, 1)
        facing = walls & np.any([np.roll(np.roll(padded, dy, 0), dx, 1)[1:-1, 1:-1]
                                 for dy, dx in ((0, 1), (0, -1), (1, 0), (-1, 0))], axis=0)
        lane = self.lane()
        report = (f"accuracy {accuracy:.3f} of {classified.sum()} classified cells; walls: "
                  f"{(occupied & walls).sum()} occupied, {(free & walls).sum()} free of {facing.sum()} facing the "
                  f"room; lane: {(free & lane).sum()} free, {(occupied & lane).sum()} occupied of {lane.sum()}")
        self.assertGreaterEqual(accuracy, PARAMS["min_accuracy"], report)
        self.assertGreaterEqual((occupied & walls).sum() / (classified & walls).sum(), PARAMS["min_wall_occupied"],
                                report)
        self.assertGreaterEqual((occupied & facing).sum() / facing.sum(), PARAMS["min_wall_seen"], report)
        self.assertGreaterEqual((free & lane).sum() / (classified & lane).sum(), PARAMS["min_lane_free"], report)
        self.assertGreaterEqual((classified & lane).sum() / lane.sum(), PARAMS["min_lane_seen"], report)

    def test_process_bag_learns_which_cells_change(self):
        """Online learning against the true transitions (/ground_truth_p_*): the truly dynamic
        cells get much larger learned rates than the cells that never change."""
        model = load_model(os.path.join(self.process_bag(), "model.dogm"))
        x = model.x + round(model.config["origin_x_m"] / RESOLUTION_M)
        y = model.y + round(model.config["origin_y_m"] / RESOLUTION_M)
        inside = (x >= 0) & (y >= 0) & (x < WORLD_CELLS[0]) & (y < WORLD_CELLS[1])
        x, y = x[inside], y[inside]
        states, _ = self.truth()
        dynamic = (grid(self.topics["/ground_truth_p_occ_given_free"][0][0]) > 0)[y, x]
        # The rate out of a state is learned only where the state is seen: free -> occupied
        # on the always-free cells, occupied -> free on the walls.
        for name, never_changing in (("p_occ_given_free", (~states).all(axis=0)[y, x]),
                                     ("p_free_given_occ", states.all(axis=0)[y, x])):
            learned = model[name][inside]
            ratio = learned[dynamic].mean() / learned[never_changing].mean()
            self.assertGreaterEqual(ratio, PARAMS["min_learned_ratio"],
                                    f"{name}: mean {learned[dynamic].mean():.4f} on {dynamic.sum()} dynamic cells, "
                                    f"{learned[never_changing].mean():.4f} on {never_changing.sum()} static ones")

    # --- every scenario, re-draws, reproducibility ----------------------------------------------

    def test_every_scenario_writes_a_bag(self):
        for scenario in SCENARIOS:
            path = os.path.join(self.tmp, f"{scenario}_short.bag")
            rc, stdout, stderr = run_tool("simulate", ["--scenario", scenario, "--steps", 3, "--out", path])
            self.assertEqual(rc, 0, f"{scenario}: exit {rc}\n{stderr}")
            self.assertIn(f"scenario {scenario}:", stdout)
            topics = read_bag(path)
            self.assertEqual(len(topics["/ground_truth"]), 3, scenario)
            self.assertEqual(len(topics["/tf"]), len(topics["/scan"]), scenario)
            self.assertGreaterEqual(len(topics["/scan"]), 3, scenario)
            self.assertFalse(os.path.exists(path + ".tmp"), scenario)

    def test_redraw_writes_new_truth(self):
        path = os.path.join(self.tmp, "redraw_100.bag")
        rc, _, stderr = run_tool("simulate", ["--scenario", "redraw_100", "--steps", 102, "--out", path])
        self.assertEqual(rc, 0, stderr)
        topics = read_bag(path)
        for topic in ("/ground_truth_p_occ_given_free", "/ground_truth_p_free_given_occ"):
            (first, first_t, header), (second, second_t, _) = topics[topic]
            self.assertEqual(header.get("latching"), b"1")
            self.assertAlmostEqual(first_t, START_TIME_S)
            self.assertAlmostEqual(second_t, START_TIME_S + 100 * TIME_STEP_S)
            # Another set of dynamic cells, as many.
            self.assertFalse(np.array_equal(grid(first) > 0, grid(second) > 0), topic)
            self.assertEqual((grid(first) > 0).sum(), (grid(second) > 0).sum(), topic)

    def test_same_seeds_same_bag(self):
        paths = [os.path.join(self.tmp, name) for name in ("seed_a.bag", "seed_b.bag", "seed_c.bag")]
        for path, seed in zip(paths, (7, 7, 8)):
            rc, _, stderr = run_tool("simulate", ["--steps", 20, "--world-seed", 3, "--seed", seed, "--out", path])
            self.assertEqual(rc, 0, stderr)
        runs = [read_bag(path) for path in paths]
        scans = [np.array([m.ranges for m, _, _ in run["/scan"]]) for run in runs]
        np.testing.assert_array_equal(scans[0], scans[1])  # NaN (dropouts) equal NaN here
        self.assertFalse(np.array_equal(scans[0], scans[2], equal_nan=True))
        # The world seed alone fixes which cells are dynamic.
        truths = [grid(run["/ground_truth_p_occ_given_free"][0][0]) for run in runs]
        np.testing.assert_array_equal(truths[0], truths[2])

    def test_drifting_odometry(self):
        # With --odometry-noise /tf drifts from the truth, which /ground_truth_pose keeps; the
        # scans and the world are the same as without it (its own random stream).
        paths = [os.path.join(self.tmp, name) for name in ("true_pose.bag", "drift.bag")]
        for path, extra in zip(paths, ([], ["--odometry-noise", "0.01,0.0005,0.002,0.0005"])):
            rc, _, stderr = run_tool("simulate", ["--scenario", "patrol", "--steps", 120, "--out", path] + extra)
            self.assertEqual(rc, 0, stderr)
        plain, drift = (read_bag(path) for path in paths)
        self.assertNotIn("/ground_truth_pose", plain)
        np.testing.assert_array_equal(np.array([m.ranges for m, _, _ in plain["/scan"]]),
                                      np.array([m.ranges for m, _, _ in drift["/scan"]]))
        truth = drift["/ground_truth_pose"]
        self.assertEqual(len(truth), len(drift["/tf"]))
        errors = []
        for (pose, stamp, _), (tf, tf_stamp, _), (exact, _, _) in zip(truth, drift["/tf"], plain["/tf"]):
            self.assertEqual(stamp, tf_stamp)
            self.assertEqual(pose.header.frame_id, "odom")
            odom = tf.transforms[0].transform.translation
            true = exact.transforms[0].transform.translation
            # The true pose is the pose /tf carries without drift.
            self.assertAlmostEqual(pose.pose.position.x, true.x, places=9)
            self.assertAlmostEqual(pose.pose.position.y, true.y, places=9)
            errors.append(math.hypot(odom.x - true.x, odom.y - true.y))
        self.assertEqual(errors[0], 0.0)  # odometry starts at the true pose
        # It drifts, more the longer the robot drives (60 m here: decimetres, not kilometres).
        quarter = len(errors) // 4
        self.assertGreater(np.mean(errors[-quarter:]), np.mean(errors[:quarter]))
        self.assertGreater(errors[-1], 0.05)
        self.assertLess(max(errors), 20.0)
        for bad in ("1,2,3", "0.1,-0.1,0.1,0.1", "a,b,c,d", "0.1,0.1,0.1,nan"):
            rc, _, stderr = run_tool("simulate", ["--odometry-noise", bad, "--out", os.path.join(self.tmp, "bad.bag")])
            self.assertEqual(rc, 2, stderr)
            self.assertIn("--odometry-noise", stderr)

    def test_process_bag_pose_correction(self):
        # process_bag --pose-correction rbpf on a patrol with drifting odometry: the corrected
        # trajectory (TUM, the laser's poses in the map frame, which starts at odometry's first
        # pose: the true one) against the truth, and odometry's against it.
        bag = os.path.join(self.tmp, "patrol_drift.bag")
        rc, _, stderr = run_tool("simulate", ["--scenario", "patrol_office", "--steps", PARAMS["rbpf_steps"],
                                              "--world-seed", PARAMS["rbpf_seed"], "--seed", PARAMS["rbpf_seed"],
                                              "--odometry-noise", PARAMS["rbpf_odometry_noise"], "--out", bag])
        self.assertEqual(rc, 0, stderr)
        out = os.path.join(self.tmp, "rbpf")
        # The filter told the simulated odometry's noise (the default is real odometry's, 0.001).
        rc, stdout, stderr = run_tool("process_bag", [bag, "--resolution", "0.1", "--pose-correction", "rbpf",
                                                      "--odometry-alphas", PARAMS["rbpf_odometry_noise"],
                                                      "--out", out])
        self.assertEqual(rc, 0, f"stdout:\n{stdout}\nstderr:\n{stderr}")
        self.assertIn("pose correction: 30 particles", stdout)
        topics = read_bag(bag)
        mount = topics["/tf_static"][0][0].transforms[0].transform.translation
        truth = {m.header.stamp.to_nsec(): m.pose for m, _, _ in topics["/ground_truth_pose"]}
        odometry = {m.transforms[0].header.stamp.to_nsec(): m.transforms[0].transform for m, _, _ in topics["/tf"]}

        def laser(x, y, q):  # the laser's position on a base pose (the mount has no rotation)
            yaw = 2.0 * math.atan2(q.z, q.w)
            return (x + math.cos(yaw) * mount.x - math.sin(yaw) * mount.y,
                    y + math.sin(yaw) * mount.x + math.cos(yaw) * mount.y)

        rows = np.loadtxt(os.path.join(out, "trajectory.tum"), comments="#", ndmin=2)
        self.assertEqual(rows.shape[1], 8)
        self.assertGreater(len(rows), 50)
        self.assertTrue(np.all(np.diff(rows[:, 0]) > 0), "stamps not increasing")
        np.testing.assert_allclose(np.linalg.norm(rows[:, 4:8], axis=1), 1.0, atol=1e-6)
        np.testing.assert_array_equal(rows[:, 3:6], 0.0)  # z, qx, qy: a planar pose
        errors, odometry_errors = [], []
        for row in rows:
            stamp = int(round(row[0] * 1e9))
            true = laser(truth[stamp].position.x, truth[stamp].position.y, truth[stamp].orientation)
            odom = laser(odometry[stamp].translation.x, odometry[stamp].translation.y, odometry[stamp].rotation)
            errors.append(math.hypot(row[1] - true[0], row[2] - true[1]))
            odometry_errors.append(math.hypot(odom[0] - true[0], odom[1] - true[1]))
        print(f"process_bag --pose-correction rbpf: laser position error mean {np.mean(errors):.3f} m, "
              f"odometry {np.mean(odometry_errors):.3f} m, {len(rows)} filter updates")
        self.assertGreater(np.mean(odometry_errors), 1.0, "too little drift to test anything")
        self.assertLess(np.mean(errors), PARAMS["rbpf_max_error_ratio"] * np.mean(odometry_errors))
        # The layers and the model are written as without correction, and the best particle's
        # own map beside them: on the cells both know, mostly the same side of 0.5.
        for name in ("belief.pgm", "static_map.yaml", "model.dogm", "best_particle_belief.pgm",
                     "best_particle_belief.yaml", "best_particle_predicted.npy", "best_particle_predicted.yaml"):
            self.assertTrue(os.path.isfile(os.path.join(out, name)), name)
        self.assertIn("best_particle_belief", stdout)
        layers = {}
        for name in ("belief", "best_particle_belief", "best_particle_predicted"):
            with open(os.path.join(out, name + ".yaml")) as file:
                meta = yaml.safe_load(file)
            layers[name] = (np.load(os.path.join(out, name + ".npy")), meta["origin"], meta["resolution"])
        (belief, belief_origin, resolution), (best, best_origin, best_resolution) = \
            layers["belief"], layers["best_particle_belief"]
        self.assertEqual(best_resolution, resolution)
        # The best particle's map --prediction-horizon ahead: its window and unknown cells.
        predicted = layers["best_particle_predicted"]
        self.assertEqual(predicted[1:], (best_origin, best_resolution))
        np.testing.assert_array_equal(np.isnan(predicted[0]), np.isnan(best))
        # The best particle's cells inside the belief layer's window (both on the same lattice).
        dx = int(round((best_origin[0] - belief_origin[0]) / resolution))
        dy = int(round((best_origin[1] - belief_origin[1]) / resolution))
        rows = slice(max(0, -dy), min(best.shape[0], belief.shape[0] - dy))
        cols = slice(max(0, -dx), min(best.shape[1], belief.shape[1] - dx))
        best_part = best[rows, cols]
        belief_part = belief[rows.start + dy:rows.stop + dy, cols.start + dx:cols.stop + dx]
        known = ~np.isnan(best_part) & ~np.isnan(belief_part)
        both = int(np.count_nonzero(known))
        agree = int(np.count_nonzero((best_part[known] > 0.5) == (belief_part[known] > 0.5)))
        print(f"best_particle_belief agrees with belief on {agree} of {both} cells")
        self.assertGreater(both, 1000)
        self.assertGreater(agree, 0.9 * both)
        # The model's beliefs are the best particle's own map where it saw the cell by the
        # mapper's last update of it (process_bag says how many): predicted to the model's last
        # step, they are on best_particle_belief's side of 0.5 (predicted to the filter's last
        # update, a few steps earlier at most) in more cells than the belief layer is (the
        # map along the best particle's poses as the scans came, which a model without the
        # particle's beliefs would hold).
        counted = re.search(r"beliefs of (\d+) cells from the best particle's map, (\d+) kept", stdout)
        self.assertIsNotNone(counted, stdout)
        model = load_model(os.path.join(out, "model.dogm"))
        self.assertEqual(int(counted.group(1)) + int(counted.group(2)), model.cell_count)
        self.assertGreater(int(counted.group(1)), 0.5 * model.cell_count)
        p, a, b = (model[name].astype(np.float64) for name in ("p_occ", "p_occ_given_free", "p_free_given_occ"))
        moving = a + b > 0
        stationary = np.where(moving, a / np.where(moving, a + b, 1.0), p)
        now = stationary + (p - stationary) * (1.0 - a - b) ** (model.last_applied_step - model["last_step"])
        cols = model.x.astype(np.int64) + int(round((model.config["origin_x_m"] - best_origin[0]) / resolution))
        rows = model.y.astype(np.int64) + int(round((model.config["origin_y_m"] - best_origin[1]) / resolution))
        inside = (cols >= 0) & (cols < best.shape[1]) & (rows >= 0) & (rows < best.shape[0])
        particle = best[rows[inside], cols[inside]]
        seen = ~np.isnan(particle)
        same = int(np.count_nonzero((now[inside][seen] > 0.5) == (particle[seen] > 0.5)))
        layer_cols = model.x.astype(np.int64) + int(round((model.config["origin_x_m"] - belief_origin[0]) / resolution))
        layer_rows = model.y.astype(np.int64) + int(round((model.config["origin_y_m"] - belief_origin[1]) / resolution))
        layer = belief[layer_rows[inside][seen], layer_cols[inside][seen]]
        layer_same = int(np.count_nonzero((layer > 0.5) == (particle[seen] > 0.5)))
        print(f"the model's beliefs agree with best_particle_belief on {same} of {int(np.count_nonzero(seen))} cells, "
              f"the belief layer on {layer_same}")
        # Measured: 20604 of 21124 (97.5 %), the belief layer 20287. The cells kept (the
        # particle saw them after the mapper's last update of them) hold the mapper's belief,
        # and the mapper now maps at odometry until a settled map asks for a correction
        # (core/pose/corrected_mapping.h), so more of them differ from the particle's than when
        # it mapped at the best particle's pose of each scan (over 99 %).
        self.assertGreater(same, 0.97 * np.count_nonzero(seen))
        self.assertGreater(same, layer_same)

        # The options' checks.
        for args, named in ((["--pose-correction", "amcl"], "--pose-correction"),
                            (["--trajectory", "t.tum"], "--trajectory"),
                            (["--pose-correction", "rbpf", "--laser-pose", "0,0,0"], "--laser-pose"),
                            (["--pose-correction", "rbpf", "--particles", "0"], "--particles"),
                            (["--pose-correction", "rbpf", "--odometry-alphas", "0.1,0.1,-0.1,0.1"],
                             "--odometry-alphas"),
                            (["--pose-correction", "rbpf", "--update-distance", "0"], "--update-distance"),
                            (["--pose-correction", "rbpf", "--resample-threshold", "2"], "--resample-threshold")):
            rc, _, stderr = run_tool("process_bag", [bag, "--out", os.path.join(self.tmp, "bad")] + args)
            self.assertEqual(rc, 2, f"{args}: {stderr}")
            self.assertIn("usage: process_bag", stderr)
            self.assertIn(named, stderr.split("usage:")[0], stderr)

    # --- (c) errors ----------------------------------------------------------------------------

    def assert_fails(self, args, rc_expected, *words, preexec_fn=None):
        rc, stdout, stderr = run_tool("simulate", args, preexec_fn)
        self.assertEqual(rc, rc_expected, f"simulate {args}: exit {rc}\nstdout:\n{stdout}\nstderr:\n{stderr}")
        for word in words:
            self.assertIn(word, stderr)
        return stderr

    def assert_nothing_written(self, path):
        self.assertFalse(os.path.exists(path + ".tmp"), "the partial file is left")
        self.assertFalse(os.path.isfile(path), "a bag is written")

    def test_unknown_scenario_lists_names(self):
        path = os.path.join(self.tmp, "unknown.bag")
        self.assert_fails(["--scenario", "no_such_world", "--out", path], 2, "no_such_world", "usage: simulate",
                          *SCENARIOS)
        self.assert_nothing_written(path)

    def test_bad_options(self):
        out = ["--out", os.path.join(self.tmp, "bad.bag")]
        for args in (["--steps", "0"] + out, ["--steps", "ten"] + out, ["--seed", "-1"] + out,
                     ["--world-seed", "x"] + out, ["--transition-scale", "2"] + out, ["--no-such-option"] + out,
                     ["--scenario"], ["--steps", "5"], []):
            self.assert_fails(args, 2, "usage: simulate")

    def test_unwritable_output(self):
        missing_dir = os.path.join(self.tmp, "no_such_dir", "run.bag")
        self.assert_fails(["--steps", 5, "--out", missing_dir], 1, missing_dir, "No such file or directory")
        self.assert_nothing_written(missing_dir)
        # The bag is written, then cannot replace a directory: the written file goes.
        directory = os.path.join(self.tmp, "a_directory.bag")
        os.mkdir(directory)
        self.assert_fails(["--steps", 5, "--out", directory], 1, directory)
        self.assertTrue(os.path.isdir(directory))
        self.assertFalse(os.path.exists(directory + ".tmp"))

    def test_full_disk(self):
        """A write that fails half-way (a file size limit, as a full disk) is an error, not a
        crash, and leaves no partial file."""
        def limit_file_size():
            signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # fail the write with EFBIG instead
            resource.setrlimit(resource.RLIMIT_FSIZE, (200000, 200000))
        path = os.path.join(self.tmp, "full.bag")
        self.assert_fails(["--steps", PARAMS["steps"], "--out", path], 1, path, preexec_fn=limit_file_size)
        self.assert_nothing_written(path)


if __name__ == "__main__":
    rospy.init_node("test_simulate", anonymous=True)
    for name, default in PARAMS.items():
        PARAMS[name] = rospy.get_param("~" + name, default)
    rostest.rosrun(PKG, "test_simulate", TestSimulate)
