#!/usr/bin/env python3
"""mapping_node's services on the wall scene: get_cell, predict_map, save_model, load_model,
reset, export_layers (map_server files and the .npy values) and run_offline_em, each with its
error cases; relative paths of save_model / export_layers resolved against the node's working
directory and answered as absolute paths. The tests run in the order of their names and share
the node (save/reset/load change its map)."""

import math
import os
import shutil
import sys
import tempfile
import time
import unittest
import xmlrpc.client

import numpy as np
import rosbag
import rosgraph
import rospy
import rostest
from nav_msgs.msg import OccupancyGrid
from std_srvs.srv import Trigger
from tf2_msgs.msg import TFMessage

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import wall_scene  # noqa: E402
from dynamic_occupancy_grid.msg import OfflineEmProgress  # noqa: E402
from wall_scene import (BEHIND_POINTS, FREE_POINTS, OUTSIDE_FAN_POINTS, RESOLUTION, TIME_STEP,  # noqa: E402
                        WALL_CELL, WALL_POINTS, grid_value, same_geometry_problems, wall_problems)

NODE = '/mapper'
STEPS = 12
# services.test: online_em/p_min, p_max.
P_MIN = 1e-4
P_MAX = 0.5
# Scans in the bag recorded for offline EM, and iterations asked for: a run of about a
# second (a second request, sent as soon as the first is answered, must find it running;
# the sanitized build takes five times as long, and a busy CI machine longer still).
BAG_SCANS = 800
OFFLINE_EM_ITERATIONS = 300
OFFLINE_EM_TIMEOUT = 20.0 * float(os.environ.get('DOG_TEST_TIMEOUT_SCALE', '1'))
# The bag and EM iterations of the runs with and without the MRF.
MRF_BAG_SCANS = 200
MRF_ITERATIONS = 20


def cell_fields(response):
    """GetCell response as a comparable tuple (NaN compares equal to NaN)."""
    fields = []
    for name in response.__slots__:
        value = getattr(response, name)
        if isinstance(value, float) and math.isnan(value):
            value = 'nan'
        elif isinstance(value, (list, tuple)):
            value = tuple(value)
        fields.append((name, value))
    return fields


def write_wall_bag(path, start, scans):
    """A bag of the wall scene: /tf_static (map -> laser) and `scans` scans on /scan, two
    per time step."""
    transform = wall_scene.laser_transform(start)
    with rosbag.Bag(path, 'w') as bag:
        bag.write('/tf_static', TFMessage(transforms=[transform]), rospy.Time.from_sec(start))
        for i in range(scans):
            stamp = start + (i + 0.5) * TIME_STEP / 2.0
            scan = wall_scene.make_scan(stamp)
            bag.write('/scan', scan, rospy.Time.from_sec(stamp))


def read_pgm(data):
    """(magic, width, height, maxval, pixels) of a binary PGM (comments allowed)."""
    fields = []
    position = 0
    while len(fields) < 4:
        while data[position:position + 1].isspace():
            position += 1
        if data[position:position + 1] == b'#':
            position = data.index(b'\n', position) + 1
            continue
        end = position
        while not data[end:end + 1].isspace():
            end += 1
        fields.append(data[position:end])
        position = end
    position += 1  # the single whitespace after maxval
    return fields[0], int(fields[1]), int(fields[2]), int(fields[3]), data[position:]


class TestServices(unittest.TestCase):

    @wall_scene.reported_set_up
    def setUpClass(cls):
        rospy.init_node('test_services')
        cls.tmp = tempfile.mkdtemp(prefix='dog_services_')
        cls.scene = wall_scene.WallScene(NODE)
        cls.belief = wall_scene.TopicRecorder(NODE + '/belief', OccupancyGrid)
        cls.stationary = wall_scene.TopicRecorder(NODE + '/stationary', OccupancyGrid)
        cls.progress = wall_scene.TopicRecorder(NODE + '/offline_em_progress', OfflineEmProgress)
        cls.scene.wait_for_node()
        cls.scene.broadcast_tf()
        cls.scene.first_scan()
        cls.scene.feed_steps(STEPS - 1)
        cls.scene.finish()
        cls.last_step = cls.scene.last_step
        response = cls.scene.wait_for_cell_step(cls.last_step)
        assert response.observed and response.last_observed_step == cls.last_step, response
        cls.final_stamp = cls.scene.step_end(cls.last_step)

    @classmethod
    def tearDownClass(cls):
        shutil.rmtree(cls.tmp, ignore_errors=True)

    def call(self, name, **request):
        return self.scene.service(name)(**request)

    def wall_cell(self):
        return self.scene.get_cell(*WALL_POINTS[2])

    def belief_grid(self, stamp=None, predicate=None):
        """The newest full belief grid of the map's last step (full_map_period is 0: every
        publish tick sends one)."""
        stamp = self.final_stamp if stamp is None else stamp

        def wanted(msg):
            return (abs(msg.header.stamp.to_sec() - stamp) < 1e-3 and msg.info.width > 0 and
                    (predicate is None or predicate(msg)))

        grid = self.belief.wait_for(wanted, clock=self.scene.clock)
        self.assertIsNotNone(grid, 'no belief grid stamped %.3f; got %s' % (
            stamp, [round(m.header.stamp.to_sec(), 3) for m in self.belief.snapshot()[-10:]]))
        return grid

    # --- get_status --------------------------------------------------------------------------
    def test_00_get_status(self):
        """The node's counts: every scan of setUpClass mapped, none dropped, the map's clock
        at the last step."""
        status = self.call('get_status')
        scans = 1 + 2 * (STEPS - 1)  # first_scan, then two per step
        self.assertEqual(status.scans_received, scans, status)
        self.assertEqual(status.scans_integrated, scans, status)
        self.assertEqual((status.scans_dropped_tf, status.scans_dropped_invalid, status.scans_dropped_late,
                          status.scans_refused_by_memory), (0, 0, 0, 0), status)
        self.assertEqual(status.last_applied_step, self.wall_cell().last_observed_step)
        self.assertAlmostEqual(status.map_stamp, self.final_stamp, places=6)

    # --- get_cell ----------------------------------------------------------------------------
    def test_01_get_cell_wall(self):
        cell = self.wall_cell()
        self.assertTrue(cell.observed, cell.message)
        self.assertEqual((cell.cell_x, cell.cell_y), WALL_CELL)
        self.assertAlmostEqual(cell.center_x, WALL_CELL[0] * RESOLUTION + RESOLUTION / 2, places=6)
        self.assertAlmostEqual(cell.center_y, WALL_CELL[1] * RESOLUTION + RESOLUTION / 2, places=6)
        self.assertGreater(cell.belief, 0.65)
        self.assertGreater(cell.static_p_occ, 0.65)
        self.assertEqual(cell.last_observed_step, self.last_step)
        self.assertEqual(cell.steps_since_observed, 0)
        self.assertEqual(cell.observed_steps, STEPS)
        for p in (cell.p_occ_given_free, cell.p_free_given_occ):
            self.assertGreaterEqual(p, P_MIN * (1 - 1e-6))
            self.assertLessEqual(p, P_MAX * (1 + 1e-6))
        stationary = cell.p_occ_given_free / (cell.p_occ_given_free + cell.p_free_given_occ)
        self.assertAlmostEqual(cell.stationary_p_occ, stationary, places=5)
        self.assertGreater(cell.mixing_time_steps, 0)
        self.assertAlmostEqual(cell.mixing_time_s, cell.mixing_time_steps * TIME_STEP, places=6)
        # The mixing time is the first step at which the prediction is within 0.01 of the
        # stationary p(occ): |belief - stationary| (1 - a - b)^n <= 0.01.
        rate = 1.0 - cell.p_occ_given_free - cell.p_free_given_occ
        n = cell.mixing_time_steps
        self.assertLessEqual(abs(cell.belief - stationary) * rate ** n, 0.01 + 1e-6)
        self.assertGreater(abs(cell.belief - stationary) * rate ** (n - 1), 0.01 - 1e-6)
        # The default learner: the cell's posterior over the map's kinds of cells, and no
        # online EM counts.
        self.assertEqual(cell.learner, 'kinds')
        self.assertEqual(len(cell.kind_posterior), 5)
        self.assertTrue(all(p >= 0.0 for p in cell.kind_posterior), cell.kind_posterior)
        self.assertAlmostEqual(sum(cell.kind_posterior), 1.0, places=6)
        self.assertEqual(list(cell.expected_transitions), [0.0, 0.0, 0.0, 0.0])
        # A wall seen occupied in every step: a kind that keeps its state, so it stays a wall.
        self.assertLess(cell.p_free_given_occ, 0.01)
        # The belief layer shows the same value.
        grid = self.belief_grid()
        self.assertLessEqual(abs(grid_value(grid, *WALL_POINTS[2]) - 100.0 * cell.belief), 0.51)

    def test_02_get_cell_swept_and_unobserved(self):
        free = self.scene.get_cell(*FREE_POINTS[3])
        self.assertTrue(free.observed)
        self.assertLess(free.belief, 0.25)
        self.assertLess(free.static_p_occ, 0.25)
        for x, y in BEHIND_POINTS + OUTSIDE_FAN_POINTS + [(-40.0, 70.0)]:
            cell = self.scene.get_cell(x, y)
            self.assertFalse(cell.observed, '(%.2f, %.2f): %s' % (x, y, cell))
            self.assertTrue(cell.message)
        for x, y in ((float('nan'), 2.0), (3.0, float('inf')), (1e15, 0.0)):
            cell = self.scene.get_cell(x, y)
            self.assertFalse(cell.observed)
            self.assertTrue(cell.message, 'no message for (%r, %r)' % (x, y))

    # --- predict_map ---------------------------------------------------------------------------
    def test_03_predict_map(self):
        belief = self.belief_grid()
        now = self.call('predict_map', horizon=0.0)
        self.assertTrue(now.success, now.message)
        self.assertEqual(same_geometry_problems(now.map, belief), [])
        self.assertEqual(list(now.map.data), list(belief.data), 'horizon 0 differs from ~belief')
        self.assertAlmostEqual(now.map.header.stamp.to_sec(), self.final_stamp, places=3)

        stationary = self.stationary.wait_for(
            lambda m: abs(m.header.stamp.to_sec() - self.final_stamp) < 1e-3 and m.info.width > 0,
            clock=self.scene.clock)
        self.assertIsNotNone(stationary)
        far = self.call('predict_map', horizon=1e6)
        self.assertTrue(far.success, far.message)
        self.assertEqual(same_geometry_problems(far.map, belief), [])
        self.assertAlmostEqual(far.map.header.stamp.to_sec(), self.final_stamp + 1e6, delta=1.0)
        near = self.call('predict_map', horizon=5.0 * TIME_STEP)
        self.assertTrue(near.success, near.message)
        compared = 0
        for x, y in WALL_POINTS + FREE_POINTS:
            b = grid_value(belief, x, y)
            s = grid_value(stationary, x, y)
            f = grid_value(far.map, x, y)
            m = grid_value(near.map, x, y)
            self.assertNotEqual(s, -1, 'stationary unknown at (%.2f, %.2f)' % (x, y))
            self.assertLessEqual(abs(f - s), 1, '(%.2f, %.2f): 1e6 s ahead %d, stationary %d' % (x, y, f, s))
            self.assertLessEqual(abs(m - s), abs(b - s) + 1, '(%.2f, %.2f)' % (x, y))
            compared += 1
        self.assertGreater(compared, 0)
        for x, y in BEHIND_POINTS:
            self.assertIn(grid_value(far.map, x, y), (None, -1))

    def test_04_predict_map_bad_horizon(self):
        for horizon in (-1.0, -1e-9, float('nan'), float('inf'), -float('inf'), 1e300):
            response = self.call('predict_map', horizon=horizon)
            self.assertFalse(response.success, 'horizon %r accepted' % horizon)
            self.assertTrue(response.message)
            self.assertEqual(len(response.map.data), 0)

    # --- save_model / load_model / reset -------------------------------------------------------------
    def save(self, name):
        path = os.path.join(self.tmp, name)
        response = self.call('save_model', path=path)
        self.assertTrue(response.success, response.message)
        self.assertTrue(os.path.isfile(path), path)
        self.assertGreater(os.path.getsize(path), 0)
        return path

    def test_05_save_model(self):
        self.save('model.dogm')
        # Saving again replaces the file.
        self.save('model.dogm')
        blocker = os.path.join(self.tmp, 'a_file')
        with open(blocker, 'w') as f:
            f.write('not a directory')
        directory = os.path.join(self.tmp, 'a_directory')
        os.mkdir(directory)
        for path in ('', os.path.join(blocker, 'model.dogm'), os.path.join(self.tmp, 'missing', 'dir', 'm.dogm'),
                     directory):
            response = self.call('save_model', path=path)
            if path.endswith('m.dogm') and response.success:
                continue  # creating missing directories is allowed
            self.assertFalse(response.success, 'save_model to %r succeeded' % path)
            self.assertTrue(response.message)
            if path:
                self.assertIn(path, response.message)
        self.assertEqual(open(blocker).read(), 'not a directory')
        self.assertTrue(os.path.isdir(directory))
        # Failed saves leave no temporary files behind (.<name>.dogtmp.XXXXXX).
        self.assertEqual(sorted(f for f in os.listdir(self.tmp) if '.dogtmp.' in f or f.endswith('.tmp')), [])

    def test_06_load_bad_models(self):
        good = self.save('good.dogm')
        with open(good, 'rb') as f:
            data = f.read()
        bad = {
            'garbage.dogm': b'this is not a model\n' * 50,
            'empty.dogm': b'',
            'truncated.dogm': data[:len(data) // 2],
            'truncated_end.dogm': data[:-1],
            'flipped.dogm': data[:len(data) // 2] + bytes([data[len(data) // 2] ^ 0xFF]) + data[len(data) // 2 + 1:],
        }
        before = cell_fields(self.wall_cell())
        belief_before = self.belief_grid()
        paths = [os.path.join(self.tmp, 'does_not_exist.dogm'), self.tmp]
        for name, content in sorted(bad.items()):
            path = os.path.join(self.tmp, name)
            with open(path, 'wb') as f:
                f.write(content)
            paths.append(path)
        for path in paths:
            response = self.call('load_model', path=path)
            self.assertFalse(response.success, 'load_model(%s) succeeded: %s' % (path, response.message))
            self.assertIn(path, response.message)
            self.assertIn('unchanged', response.message)
            self.assertGreater(len(response.message), len('; the live model is unchanged') + 5, response.message)
            self.assertEqual(cell_fields(self.wall_cell()), before, 'load_model(%s) changed the map' % path)
        self.assertEqual(list(self.belief_grid().data), list(belief_before.data))

    def test_07_save_reset_load(self):
        before = cell_fields(self.wall_cell())
        belief_before = self.belief_grid()
        path = self.save('before_reset.dogm')

        reset = rospy.ServiceProxy(NODE + '/reset', Trigger)()
        self.assertTrue(reset.success, reset.message)
        empty = self.belief.wait_for(lambda m: all(v == -1 for v in m.data), clock=self.scene.clock)
        self.assertIsNotNone(empty, 'belief was not cleared by ~reset')
        self.assertFalse(self.wall_cell().observed)
        response = self.call('predict_map', horizon=0.0)
        self.assertFalse(response.success, 'predict_map on an empty map: %s' % response.message)
        response = self.call('export_layers', directory=os.path.join(self.tmp, 'export_empty'))
        self.assertFalse(response.success, 'export_layers on an empty map: %s' % response.message)

        response = self.call('load_model', path=path)
        self.assertTrue(response.success, response.message)
        self.assertEqual(cell_fields(self.wall_cell()), before)
        # The layers come back as they were (same step, same stamp).
        loaded = self.belief_grid(predicate=lambda m: list(m.data) == list(belief_before.data))
        self.assertEqual(same_geometry_problems(loaded, belief_before), [])
        self.assertEqual(wall_problems(loaded), [])

    # --- export_layers --------------------------------------------------------------------------------
    def test_08_export_layers(self):
        directory = os.path.join(self.tmp, 'export', 'nested')
        response = self.call('export_layers', directory=directory)
        self.assertTrue(response.success, response.message)
        self.assertTrue(response.message.endswith(' ' + directory), response.message)
        pgm = sorted(f for f in response.files if f.endswith('.pgm'))
        yaml = sorted(f for f in response.files if f.endswith('.yaml'))
        npy = sorted(f for f in response.files if f.endswith('.npy'))
        self.assertEqual((len(pgm), len(yaml), len(npy), len(response.files)), (6, 6, 6, 18), response.files)
        self.assertEqual(sorted(os.listdir(directory)), sorted(os.path.basename(f) for f in response.files))
        belief = self.belief_grid()
        for f in pgm:
            with open(f, 'rb') as stream:
                data = stream.read()
            magic, width, height, maximum, pixels = read_pgm(data)
            self.assertEqual(magic, b'P5', f)
            self.assertEqual((width, height), (belief.info.width, belief.info.height), f)
            self.assertEqual(len(pixels), width * height, f)
            self.assertLessEqual(max(pixels), maximum)
        for f in yaml:
            text = open(f).read()
            self.assertIn(os.path.basename(f)[:-len('.yaml')] + '.pgm', text)
            self.assertIn('resolution', text)
            resolution = [line for line in text.splitlines() if line.startswith('resolution')][0]
            self.assertAlmostEqual(float(resolution.split(':')[1]), RESOLUTION, places=6)
        # The values: float32 over the same window, rows in OccupancyGrid order (row 0 at the
        # bottom), NaN where the published grid says -1; the belief is the published grid / 100.
        for f in npy:
            values = np.load(f, allow_pickle=False)
            shape = (belief.info.height, belief.info.width)
            self.assertEqual((values.dtype, values.shape), (np.dtype('<f4'), shape), f)
            self.assertEqual(list(np.isnan(values).ravel()), [v == -1 for v in belief.data], f)
            known = values[~np.isnan(values)]
            self.assertTrue(known.size > 0 and (known >= 0).all() and (known <= 1).all(), f)
        values = np.load(os.path.join(directory, 'belief.npy')).ravel()
        published = np.where(np.isnan(values), -1, np.rint(100 * values.astype(np.float64)))
        self.assertEqual(list(published.astype(int)), list(belief.data))

        blocker = os.path.join(self.tmp, 'export_blocker')
        with open(blocker, 'w') as f:
            f.write('x')
        for bad in ('', blocker, os.path.join(blocker, 'sub')):
            response = self.call('export_layers', directory=bad)
            self.assertFalse(response.success, 'export_layers(%r) succeeded' % bad)
            self.assertTrue(response.message)
        self.assertEqual(open(blocker).read(), 'x')

    def node_working_directory(self):
        """The mapper's working directory (it is on this machine: /proc/PID/cwd)."""
        uri = rosgraph.Master('/test_services').lookupNode(NODE)
        code, message, pid = xmlrpc.client.ServerProxy(uri).getPid('/test_services')
        self.assertEqual(code, 1, message)
        return os.readlink('/proc/%d/cwd' % pid)

    def test_08b_relative_paths(self):
        """save_model and export_layers resolve a relative path against the node's working
        directory (as the OS does; ~/.ros under roslaunch) and answer with the absolute path.
        The relative path here leads from there into this test's directory (with '..')."""
        cwd = self.node_working_directory()
        target = os.path.join(self.tmp, 'relative')
        os.makedirs(target)
        relative = os.path.relpath(target, cwd)
        self.assertFalse(os.path.isabs(relative))
        model = os.path.join(target, 'model.dogm')
        response = self.call('save_model', path=os.path.join(relative, 'model.dogm'))
        self.assertTrue(response.success, response.message)
        self.assertTrue(response.message.endswith(' to ' + model), response.message)
        self.assertTrue(os.path.isfile(model))

        directory = os.path.join(target, 'layers')
        response = self.call('export_layers', directory=os.path.join(relative, 'layers'))
        self.assertTrue(response.success, response.message)
        self.assertTrue(response.message.endswith(' ' + directory), response.message)
        self.assertEqual(len(response.files), 18, response.files)
        for f in response.files:
            self.assertEqual(os.path.dirname(f), directory, f)
            self.assertTrue(os.path.isfile(f), f)
        # A failure names the absolute path too.
        blocker = os.path.join(target, 'blocker')
        with open(blocker, 'w') as f:
            f.write('x')
        response = self.call('export_layers', directory=os.path.join(relative, 'blocker', 'sub'))
        self.assertFalse(response.success, response.message)
        self.assertIn(os.path.join(target, 'blocker'), response.message)

    # --- run_offline_em -------------------------------------------------------------------------------
    def progress_of(self, bag, phases=None, after=0):
        """Progress messages about `bag` received after index `after`."""
        return [m for m in self.progress.snapshot()[after:]
                if m.bag_path == bag and (phases is None or m.phase in phases)]

    def test_09_offline_em_refused(self):
        blocker = os.path.join(self.tmp, 'not_a_bag.bag')
        with open(blocker, 'wb') as f:
            f.write(b'#ROSBAG V2.0\n' + b'\x00' * 100)
        bag_without_scans = os.path.join(self.tmp, 'no_scans.bag')
        with rosbag.Bag(bag_without_scans, 'w') as bag:
            bag.write('/other', TFMessage(), rospy.Time(1))
        for path in ('', os.path.join(self.tmp, 'missing.bag'), blocker, bag_without_scans, self.tmp):
            start = time.time()
            response = self.call('run_offline_em', bag_path=path)
            self.assertFalse(response.success, 'run_offline_em(%r) started' % path)
            self.assertTrue(response.message)
            self.assertLess(time.time() - start, 5.0, 'refusing %r took long' % path)
        response = self.call('run_offline_em', bag_path=os.path.join(self.tmp, 'missing.bag'), tolerance=float('nan'))
        self.assertFalse(response.success)

    def test_10_offline_em(self):
        bag = os.path.join(self.tmp, 'wall.bag')
        write_wall_bag(bag, 5000.0, BAG_SCANS)
        before = self.wall_cell()
        seen = len(self.progress.snapshot())
        first = self.call('run_offline_em', bag_path=bag, max_iterations=OFFLINE_EM_ITERATIONS, tolerance=0.0)
        second = self.call('run_offline_em', bag_path=bag)
        self.assertTrue(first.success, first.message)
        end = self.progress.wait_for(lambda m: m.bag_path == bag and m.phase in ('done', 'failed'),
                                     timeout=OFFLINE_EM_TIMEOUT)
        self.assertIsNotNone(end, 'no end of the offline EM run in %.0f s: %s' % (
            OFFLINE_EM_TIMEOUT, [(m.phase, m.fraction) for m in self.progress_of(bag, after=seen)]))
        self.assertEqual(end.phase, 'done', end.message)
        self.assertGreater(end.cells_applied, 0, end.message)
        self.assertFalse(second.success, 'a second run_offline_em was accepted while one ran (%s); the first '
                         'ended after %d progress messages' % (second.message, len(self.progress_of(bag, after=seen))))
        self.assertIn('in progress', second.message)
        messages = self.progress_of(bag, after=seen)
        self.assertEqual(messages[-1].phase, 'done')
        self.assertIn('reading', [m.phase for m in messages])
        self.assertTrue(all(0.0 <= m.fraction <= 1.0 for m in messages))
        after = self.wall_cell()
        self.assertTrue(after.observed)
        self.assertTrue(abs(after.p_occ_given_free - before.p_occ_given_free) > 1e-9 or
                        abs(after.p_free_given_occ - before.p_free_given_occ) > 1e-9,
                        'offline EM left the wall cell transitions as they were: %s' % after)
        # A static wall seen for 400 steps: occupied -> free is rarer than online EM,
        # which saw 12 steps with a prior of 0.01, thought.
        self.assertLess(after.p_free_given_occ, before.p_free_given_occ)
        self.assertEqual(after.belief, before.belief)
        # The next request is accepted again.
        again = self.call('run_offline_em', bag_path=bag, max_iterations=1)
        self.assertTrue(again.success, again.message)
        end = self.progress.wait_for(lambda m: m.bag_path == bag and m.phase in ('done', 'failed') and m is not end,
                                     timeout=OFFLINE_EM_TIMEOUT)
        self.assertIsNotNone(end)
        self.assertEqual(end.phase, 'done', end.message)

    def test_11_offline_em_corrupt_bag(self):
        good = os.path.join(self.tmp, 'small.bag')
        write_wall_bag(good, 7000.0, 60)
        with open(good, 'rb') as f:
            data = bytearray(f.read())
        truncated = os.path.join(self.tmp, 'truncated.bag')
        with open(truncated, 'wb') as f:
            f.write(data[:int(len(data) * 0.6)])
        # Index intact, message data overwritten: found corrupt while reading.
        scrambled = os.path.join(self.tmp, 'scrambled.bag')
        middle = len(data) // 2
        data[middle:middle + 4000] = b'\xff' * 4000
        with open(scrambled, 'wb') as f:
            f.write(data)
        before = cell_fields(self.wall_cell())
        for path in (truncated, scrambled):
            seen = len(self.progress.snapshot())
            response = self.call('run_offline_em', bag_path=path)
            if response.success:
                end = self.progress.wait_for(lambda m: m.bag_path == path and m.phase in ('done', 'failed'),
                                             timeout=OFFLINE_EM_TIMEOUT)
                self.assertIsNotNone(end, 'no end of the offline EM run on %s' % path)
                self.assertEqual(end.phase, 'failed', '%s: %s' % (path, end.message))
                self.assertTrue(end.message)
            else:
                self.assertTrue(response.message)
                self.assertEqual(self.progress_of(path, after=seen), [])
            self.assertEqual(cell_fields(self.wall_cell()), before, 'offline EM on %s changed the map' % path)

    def offline_em_to_the_end(self, bag, **request):
        """Runs offline EM on `bag` and waits for its end: the run's last progress message."""
        earlier = set(id(m) for m in self.progress.snapshot())
        response = self.call('run_offline_em', bag_path=bag, **request)
        self.assertTrue(response.success, response.message)
        end = self.progress.wait_for(lambda m: m.bag_path == bag and m.phase in ('done', 'failed') and
                                     id(m) not in earlier, timeout=OFFLINE_EM_TIMEOUT)
        self.assertIsNotNone(end, 'no end of the offline EM run on %s in %.0f s' % (bag, OFFLINE_EM_TIMEOUT))
        self.assertEqual(end.phase, 'done', end.message)
        return end

    def transitions(self):
        """(p_occ_given_free, p_free_given_occ) of the wall and swept cells."""
        return [(cell.p_occ_given_free, cell.p_free_given_occ)
                for cell in (self.scene.get_cell(x, y) for x, y in WALL_POINTS + FREE_POINTS)]

    def test_12_offline_em_mrf(self):
        bag = os.path.join(self.tmp, 'wall_mrf.bag')
        write_wall_bag(bag, 9000.0, MRF_BAG_SCANS)
        plain = self.offline_em_to_the_end(bag, max_iterations=MRF_ITERATIONS, tolerance=0.0)
        self.assertEqual(len(plain.objective), MRF_ITERATIONS + 1)  # tolerance 0: every iteration
        self.assertEqual(plain.mrf_temperature, 0.0)  # services.test leaves ~offline_em/mrf_temperature at 0
        self.assertEqual((len(plain.mrf_newton_iterations_occ), len(plain.mrf_newton_iterations_free)), (0, 0))
        self.assertNotIn('Newton', plain.message)
        plain_transitions = self.transitions()

        mrf = self.offline_em_to_the_end(bag, max_iterations=MRF_ITERATIONS, tolerance=0.0, mrf_temperature=50.0)
        self.assertEqual(mrf.mrf_temperature, 50.0)
        self.assertEqual(len(mrf.objective), MRF_ITERATIONS + 1)
        self.assertEqual(len(mrf.mrf_newton_iterations_occ), MRF_ITERATIONS)
        self.assertEqual(len(mrf.mrf_newton_iterations_free), MRF_ITERATIONS)
        self.assertGreater(mrf.mrf_newton_iterations_occ[0], 0)
        self.assertGreater(mrf.mrf_newton_iterations_free[0], 0)
        self.assertIn('MRF temperature 50', mrf.message)
        self.assertIn('Newton iterations', mrf.message)
        self.assertGreater(mrf.objective[-1], mrf.objective[0])
        mrf_transitions = self.transitions()
        self.assertTrue(any(abs(a - b) > 1e-6 for before, after in zip(plain_transitions, mrf_transitions)
                            for a, b in zip(before, after)),
                        'the MRF left the transitions as plain EM learned them: %s' % mrf_transitions)

    def test_13_offline_em_mrf_refused(self):
        bag = os.path.join(self.tmp, 'wall_mrf_refused.bag')
        write_wall_bag(bag, 9000.0, 20)
        before = cell_fields(self.wall_cell())
        seen = len(self.progress.snapshot())
        for temperature in (-1.0, -1e-9, float('nan'), float('inf'), -float('inf')):
            response = self.call('run_offline_em', bag_path=bag, mrf_temperature=temperature)
            self.assertFalse(response.success, 'mrf_temperature %r accepted' % temperature)
            self.assertIn('mrf_temperature', response.message)
        self.assertEqual(self.progress_of(bag, after=seen), [])
        self.assertEqual(cell_fields(self.wall_cell()), before)


if __name__ == '__main__':
    rostest.rosrun(wall_scene.PKG, 'test_services', TestServices)
