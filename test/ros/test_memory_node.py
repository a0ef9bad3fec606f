#!/usr/bin/env python3
"""mapping_node's memory model (Morris et al.): ~ltm, ~stm (+ _updates) and ~hypotheses with
~model memory, both models with ~model both, ~reset, and bad ~model / ~memory/* values.

The scene (memory_node.test): the laser faces the wall x = WALL_X of wall_scene.py and
alternates between the poses A and B, 0.6 m apart (more than ~memory/update_distance), one
scan each: the first two scans make update 0, every later scan one update. With Table I's
values a new cell migrates when hit in three consecutive updates. The wall is seen in
updates 0..5 (in LTM from update 2, the base map; wall cells in one pose's fan only are hit
every other update and migrate at update 4, so the base map takes updates 0..4); OBJECT_1
appears in updates 3..5 (it migrates to LTM at update 5 as configuration 1); OBJECT_2 in
update 5 only (STM, not LTM). Each scan comes with its transform on /tf at its stamp. The test waits
for each update's ~hypotheses before sending the next scan."""

import math
import os
import sys
import threading
import time
import unittest

import rosgraph
import rospy
import rostest
from map_msgs.msg import OccupancyGridUpdate
from nav_msgs.msg import OccupancyGrid
from std_srvs.srv import Trigger
from tf2_msgs.msg import TFMessage

import dynamic_occupancy_grid.srv as dog_srv
from dynamic_occupancy_grid.msg import MapHypotheses

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import wall_scene  # noqa: E402
from wall_scene import (ANGLE_INCREMENT, ANGLE_MIN, BEAMS, LASER_Y, RESOLUTION, WALL_X,  # noqa: E402
                        grid_value, same_geometry_problems)

MEMORY = '/memory_mapper'
BOTH = '/both_mapper'
POSE_A = (1.02, LASER_Y)
POSE_B = (0.42, LASER_Y)
# Objects: segments x = X, y in [Y0, Y1], inside one cell each (away from cell borders).
OBJECT_1 = (2.05, 2.11, 2.19)
OBJECT_2 = (2.05, 1.91, 1.99)
OBJECT_1_POINT = (2.05, 2.15)
OBJECT_2_POINT = (2.05, 1.95)
# Wall cells inside both poses' fans and never behind an object; cells swept free.
WALL_POINTS = [(WALL_X, y) for y in (1.65, 1.75, 2.05, 2.45)]
FREE_POINTS = [(x, 2.05) for x in (1.25, 1.55, 1.85, 2.35, 2.65, 2.85)]
# (pose, objects) of each scan; scan k >= 1 completes update k - 1.
SCANS = [
    (POSE_A, []),
    (POSE_B, []),                      # update 0: the wall into STM
    (POSE_A, []),                      # update 1
    (POSE_B, []),                      # update 2: the wall migrates (base map)
    (POSE_A, [OBJECT_1]),              # update 3: object 1 into STM
    (POSE_B, [OBJECT_1]),              # update 4
    (POSE_A, [OBJECT_1, OBJECT_2]),    # update 5: object 1 migrates (configuration 1), object 2 into STM
]
UPDATES = len(SCANS) - 1
SCAN_PERIOD = 0.6  # s of simulated time between scans
MAX_PUBLISHED_HYPOTHESES = 4  # memory_node.test
OCCUPIED = 50


def ray_cast(pose, objects):
    """Ranges of the scene's beams from `pose` to the wall or the nearest object."""
    x, y = pose
    ranges = []
    for i in range(BEAMS):
        angle = ANGLE_MIN + i * ANGLE_INCREMENT
        best = (WALL_X - x) / math.cos(angle)
        for ox, y0, y1 in objects:
            y_hit = y + (ox - x) * math.tan(angle)
            if y0 <= y_hit <= y1:
                best = min(best, (ox - x) / math.cos(angle))
        ranges.append(best)
    return ranges


def wait_until(clock, predicate, timeout=wall_scene.DEFAULT_TIMEOUT, tick=0.02):
    """Polls `predicate` every 20 ms wall time, advancing `clock` by `tick` each time (so
    that the nodes' publish timers run); returns its last value (falsy on time out)."""
    deadline = time.time() + timeout
    event = threading.Event()
    while True:
        value = predicate()
        if value or time.time() >= deadline or rospy.is_shutdown():
            return value
        clock.advance(tick)
        event.wait(0.02)


def stamp_of(msg):
    return msg.header.stamp.to_sec()


def patched_grid(full_recorder, updates_recorder, stamp):
    """The grid a client of <layer> + <layer>_updates shows at `stamp`: the newest full grid
    up to it with the later updates up to it applied; None without a full grid."""
    fulls = [m for m in full_recorder.snapshot() if stamp_of(m) <= stamp + 1e-6 and m.info.width > 0]
    if not fulls:
        return None
    full = fulls[-1]
    grid = OccupancyGrid(header=full.header, info=full.info, data=list(full.data))
    for update in updates_recorder.snapshot():
        if not stamp_of(full) < stamp_of(update) <= stamp + 1e-6:
            continue
        for row in range(update.height):
            for column in range(update.width):
                grid.data[(update.y + row) * full.info.width + update.x + column] = \
                    update.data[row * update.width + column]
    return grid


class TestMemoryNode(unittest.TestCase):

    @wall_scene.reported_set_up
    def setUpClass(cls):
        rospy.init_node('test_memory_node')
        cls.clock = wall_scene.SimClock()
        cls.record = {}
        for node in (MEMORY, BOTH):
            for store in ('ltm', 'stm'):
                cls.record[node, store] = wall_scene.TopicRecorder(node + '/' + store, OccupancyGrid)
                cls.record[node, store + '_updates'] = wall_scene.TopicRecorder(
                    node + '/' + store + '_updates', OccupancyGridUpdate)
            cls.record[node, 'hypotheses'] = wall_scene.TopicRecorder(node + '/hypotheses', MapHypotheses)
        scan_publisher = rospy.Publisher('/scan', wall_scene.LaserScan, queue_size=100)
        tf_publisher = rospy.Publisher('/tf', TFMessage, queue_size=100)
        # Both nodes listen to the scans and to /tf (not latched: wait for the connections).
        deadline = time.time() + wall_scene.STARTUP_TIMEOUT
        while scan_publisher.get_num_connections() < 2 or tf_publisher.get_num_connections() < 2:
            if time.time() > deadline:
                raise AssertionError('the nodes did not subscribe to /scan and /tf')
            threading.Event().wait(0.05)
        rospy.wait_for_service(MEMORY + '/reset', wall_scene.STARTUP_TIMEOUT)
        rospy.wait_for_service(BOTH + '/get_cell', wall_scene.STARTUP_TIMEOUT)
        cls.stamps = []  # stamp of the scan that completed each update
        for k, (pose, objects) in enumerate(SCANS):
            stamp = cls.clock.now + SCAN_PERIOD
            cls.clock.set(stamp)
            transform = TFMessage(transforms=[wall_scene.laser_transform(stamp, x=pose[0], y=pose[1])])
            tf_publisher.publish(transform)
            scan_publisher.publish(wall_scene.make_scan(stamp, ranges=ray_cast(pose, objects)))
            # Both nodes take the scan with the clock standing still, then the clock runs so
            # that their publish timers send what the update changed.
            cls.wait_taken(k + 1, lambda: tf_publisher.publish(transform))
            if k == 0:
                continue
            cls.stamps.append(stamp)
            done = cls.record[MEMORY, 'hypotheses'].wait_for(lambda m, k=k: m.updates == k, clock=cls.clock)
            if done is None:
                raise AssertionError('%s published no hypotheses after update %d (scan %d); got updates %s; %s' % (
                    MEMORY, k - 1, k, [m.updates for m in cls.record[MEMORY, 'hypotheses'].snapshot()],
                    cls.statuses()))
        done = cls.record[BOTH, 'hypotheses'].wait_for(lambda m: m.updates == UPDATES, clock=cls.clock)
        if done is None:
            raise AssertionError('%s did not make %d memory updates' % (BOTH, UPDATES))

    @classmethod
    def statuses(cls):
        return {node: rospy.ServiceProxy(node + '/get_status', dog_srv.GetStatus)() for node in (MEMORY, BOTH)}

    @classmethod
    def wait_taken(cls, count, resend_transform):
        """Waits (wall time) until each node has integrated, dropped or refused `count` scans.
        A scan waits in a node's tf filter until its transform comes; /tf is not latched and,
        under load, a node has been seen to miss the transform sent just after its
        subscriptions connected (CI, sanitized build): each second a node holds a scan it
        has not taken, `resend_transform()` sends the transform again (same stamp: tf2
        keeps one)."""
        deadline = time.time() + wall_scene.DEFAULT_TIMEOUT
        resend_at = time.time() + 1.0
        while True:
            statuses = cls.statuses()
            taken = [s.scans_integrated + s.scans_dropped_tf + s.scans_dropped_invalid + s.scans_dropped_late +
                     s.scans_refused_by_memory for s in statuses.values()]
            if min(taken) >= count:
                return
            if time.time() > deadline:
                raise AssertionError('the nodes took %s of %d scans (received %s): %s' % (
                    taken, count, [s.scans_received for s in statuses.values()], statuses))
            if time.time() >= resend_at:
                resend_transform()
                resend_at = time.time() + 1.0
            threading.Event().wait(0.005)

    def grid_after(self, node, store, update):
        """~ltm or ~stm of `node` after `update` (0-based), from its full grids and updates."""
        stamp = self.stamps[update]
        full, updates = self.record[node, store], self.record[node, store + '_updates']

        def arrived():
            return any(abs(stamp_of(m) - stamp) < 1e-6 for m in full.snapshot() + updates.snapshot())

        self.assertTrue(wait_until(self.clock, arrived),
                        '%s/%s: nothing stamped %.3f (update %d)' % (node, store, stamp, update))
        grid = patched_grid(full, updates, stamp)
        self.assertIsNotNone(grid, '%s/%s: no full grid' % (node, store))
        return grid

    def values(self, grid, points):
        return [grid_value(grid, x, y) for x, y in points]

    # --- one update vs three: STM and LTM ---------------------------------------------------------
    def test_wall_seen_once_is_in_stm_not_ltm(self):
        ltm = self.grid_after(MEMORY, 'ltm', 0)
        stm = self.grid_after(MEMORY, 'stm', 0)
        self.assertEqual(same_geometry_problems(stm, ltm), [])
        self.assertEqual(ltm.header.frame_id, 'map')
        self.assertAlmostEqual(ltm.info.resolution, RESOLUTION, places=6)
        # A new STM point: l_min = 0.40, sigma = 0.60.
        for value in self.values(stm, WALL_POINTS):
            self.assertEqual(value, 60, 'stm wall after update 0: %s' % self.values(stm, WALL_POINTS))
        self.assertEqual(self.values(ltm, WALL_POINTS), [0] * len(WALL_POINTS))
        self.assertEqual(self.values(ltm, FREE_POINTS), [0] * len(FREE_POINTS))
        self.assertEqual(self.values(stm, FREE_POINTS), [0] * len(FREE_POINTS))

    def test_wall_seen_three_times_is_in_ltm(self):
        # After two updates: rehearsed, 0.40 + logit(0.7) = 1.25, sigma = 0.78; not in LTM.
        self.assertEqual(self.values(self.grid_after(MEMORY, 'stm', 1), WALL_POINTS), [78] * len(WALL_POINTS))
        self.assertEqual(self.values(self.grid_after(MEMORY, 'ltm', 1), WALL_POINTS), [0] * len(WALL_POINTS))
        for update in (2, UPDATES - 1):
            ltm = self.grid_after(MEMORY, 'ltm', update)
            stm = self.grid_after(MEMORY, 'stm', update)
            wall = self.values(ltm, WALL_POINTS)
            self.assertTrue(all(v is not None and v > OCCUPIED for v in wall), 'ltm wall after update %d: %s'
                            % (update, wall))
            self.assertEqual(self.values(stm, WALL_POINTS), [0] * len(WALL_POINTS), 'migrated: no longer in STM')
            self.assertEqual(self.values(ltm, FREE_POINTS), [0] * len(FREE_POINTS))
        # Never observed: unknown.
        ltm = self.grid_after(MEMORY, 'ltm', UPDATES - 1)
        for x, y in [(WALL_X + 0.5, LASER_Y), (POSE_A[0], LASER_Y + 1.5)]:
            self.assertIn(grid_value(ltm, x, y), (None, -1))

    def test_object_seen_once_is_in_stm_not_ltm(self):
        last = UPDATES - 1
        ltm = self.grid_after(MEMORY, 'ltm', last)
        stm = self.grid_after(MEMORY, 'stm', last)
        self.assertEqual(grid_value(stm, *OBJECT_2_POINT), 60)
        self.assertEqual(grid_value(ltm, *OBJECT_2_POINT), 0)
        # Object 1, seen in three updates, has migrated.
        self.assertGreater(grid_value(ltm, *OBJECT_1_POINT), OCCUPIED)
        self.assertEqual(grid_value(stm, *OBJECT_1_POINT), 0)
        # After update 4 (seen twice) object 1 was in STM only.
        self.assertEqual(grid_value(self.grid_after(MEMORY, 'stm', 4), *OBJECT_1_POINT), 78)
        self.assertEqual(grid_value(self.grid_after(MEMORY, 'ltm', 4), *OBJECT_1_POINT), 0)

    def test_updates_are_smaller_than_the_grid(self):
        ltm = self.grid_after(MEMORY, 'ltm', UPDATES - 1)
        updates = self.record[MEMORY, 'ltm_updates'].snapshot()
        # Updates 1..5 change cells within the bounds of update 0 (seen from both poses): sent
        # as updates (the grids after them, checked above, come from these). Those from pose A,
        # whose fan is narrower, cover less than the grid.
        self.assertEqual(len(updates), UPDATES - 1)
        for update in updates:
            self.assertEqual(update.header.frame_id, 'map')
            self.assertEqual(len(update.data), update.width * update.height)
            self.assertTrue(update.x >= 0 and update.x + update.width <= ltm.info.width)
            self.assertTrue(update.y >= 0 and update.y + update.height <= ltm.info.height)
            self.assertTrue(all(-1 <= v <= 100 for v in update.data))
        from_a = [u for u in updates if any(abs(stamp_of(u) - self.stamps[k]) < 1e-6 for k in (1, 3, 5))]
        self.assertEqual(len(from_a), 3)
        for update in from_a:
            self.assertLess(update.width * update.height, ltm.info.width * ltm.info.height)

    # --- hypotheses --------------------------------------------------------------------------------
    def final_hypotheses(self, node=MEMORY):
        msg = self.record[node, 'hypotheses'].wait_for(lambda m: m.updates == UPDATES)
        self.assertIsNotNone(msg)
        return msg

    def test_hypotheses(self):
        msg = self.final_hypotheses()
        ltm = self.grid_after(MEMORY, 'ltm', UPDATES - 1)
        self.assertAlmostEqual(stamp_of(msg), self.stamps[-1], places=3)
        self.assertEqual(msg.header.frame_id, 'map')
        # The base map (0: the wall, from update 2) and object 1 (configuration 1, update 5).
        self.assertEqual(list(msg.configuration_ids), [0, 1])
        self.assertEqual(list(msg.configuration_created_update), [2, 5])
        self.assertEqual(msg.configuration_cells[1], 1)
        self.assertAlmostEqual(msg.configuration_presence[1], 1.0 / (1.0 + math.exp(-4.59)), places=4)
        self.assertEqual(msg.total_hypotheses, 2)
        self.assertEqual(len(msg.hypotheses), min(2, MAX_PUBLISHED_HYPOTHESES))
        self.assertAlmostEqual(sum(h.weight for h in msg.hypotheses), 1.0, places=9)
        weights = [h.weight for h in msg.hypotheses]
        self.assertEqual(weights, sorted(weights, reverse=True))
        best, other = msg.hypotheses
        self.assertEqual((list(best.configurations), list(best.excluded)), ([1], []))
        self.assertEqual((list(other.configurations), list(other.excluded)), ([], [1]))
        self.assertAlmostEqual(best.weight, msg.configuration_presence[1], places=9)
        for hypothesis in msg.hypotheses:
            self.assertEqual(same_geometry_problems(hypothesis.map, ltm), [])
            self.assertTrue(set(hypothesis.map.data) <= {-1, 0, 100})
            self.assertEqual(self.values(hypothesis.map, WALL_POINTS), [100] * len(WALL_POINTS))
            self.assertEqual(self.values(hypothesis.map, FREE_POINTS), [0] * len(FREE_POINTS))
            self.assertEqual(grid_value(hypothesis.map, *OBJECT_2_POINT), 0, 'only in STM: free')
        self.assertEqual(grid_value(best.map, *OBJECT_1_POINT), 100)
        self.assertEqual(grid_value(other.map, *OBJECT_1_POINT), 0)

    # --- which model runs ----------------------------------------------------------------------------
    def test_memory_model_alone_has_no_hmm_interface(self):
        master = rosgraph.Master('/test_memory_node')
        publishers, _, services = master.getSystemState()
        published = {topic for topic, nodes in publishers if MEMORY in nodes}
        offered = {name for name, nodes in services if MEMORY in nodes}
        for topic in ('ltm', 'stm', 'ltm_updates', 'stm_updates', 'hypotheses'):
            self.assertIn(MEMORY + '/' + topic, published)
        for topic in ('belief', 'belief_updates', 'predicted', 'static_map', 'offline_em_progress'):
            self.assertNotIn(MEMORY + '/' + topic, published)
        self.assertIn(MEMORY + '/reset', offered)
        self.assertIn(MEMORY + '/get_status', offered)
        status = rospy.ServiceProxy(MEMORY + '/get_status', wall_scene.dog_srv.GetStatus)()
        self.assertEqual(status.last_applied_step, -1, status)  # no cell HMM, no step
        self.assertGreater(status.scans_integrated, 0, status)
        self.assertEqual(status.scans_received, status.scans_integrated + status.scans_dropped_tf +
                         status.scans_dropped_invalid + status.scans_dropped_late + status.scans_refused_by_memory,
                         status)
        for service in ('get_cell', 'predict_map', 'save_model', 'load_model', 'export_layers', 'run_offline_em'):
            self.assertNotIn(MEMORY + '/' + service, offered)
        both = {topic for topic, nodes in publishers if BOTH in nodes}
        for topic in ('belief', 'static_map', 'ltm', 'stm', 'hypotheses'):
            self.assertIn(BOTH + '/' + topic, both)
        self.assertIn(BOTH + '/get_cell', {name for name, nodes in services if BOTH in nodes})

    def test_both_models_on_the_same_scans(self):
        for store in ('ltm', 'stm'):
            mine = self.grid_after(BOTH, store, UPDATES - 1)
            alone = self.grid_after(MEMORY, store, UPDATES - 1)
            self.assertEqual(same_geometry_problems(mine, alone), [], store)
            self.assertEqual(list(mine.data), list(alone.data), store)
        self.assertEqual([h.weight for h in self.final_hypotheses(BOTH).hypotheses],
                         [h.weight for h in self.final_hypotheses().hypotheses])

        # The HMM maps the wall too (its time steps close as the clock moves on).
        get_cell = rospy.ServiceProxy(BOTH + '/get_cell', wall_scene.dog_srv.GetCell)
        cell = {}

        def wall_in_belief():
            cell['response'] = get_cell(x=WALL_X, y=2.05)
            return cell['response'].observed and cell['response'].belief > 0.65

        self.assertTrue(wait_until(self.clock, wall_in_belief), '%s: the HMM does not map the wall: %s'
                        % (BOTH, cell.get('response')))

    # --- bad parameters, reset ---------------------------------------------------------------------
    def test_bad_parameters(self):
        cases = [
            ('model', '_model:=hmmm'),
            ('model', '_model:=3'),
            ('memory/stm_p_hit', '_model:=memory _memory/stm_p_hit:=0.4'),
            ('memory/ltm_l_min', '_model:=both _memory/ltm_l_min:=5.0'),
            ('memory/update_distance', '_model:=memory _memory/update_distance:=0'),
            ('memory/hypothesis_configurations', '_model:=memory _memory/hypothesis_configurations:=11'),
            ('memory/max_published_hypotheses', '_model:=memory _memory/max_published_hypotheses:=0'),
            ('model_file', '_model:=memory _model_file:=/tmp/model.dogm'),
        ]
        wall_scene.assert_bad_parameters_stop_node(self, cases, 'bad_memory_parameter')

    def test_zz_reset(self):
        # Last (the tests run in name order): it clears the memory the others look at.
        response = rospy.ServiceProxy(MEMORY + '/reset', Trigger)()
        self.assertTrue(response.success, response.message)
        # The reset publishes once, stamped with the node's ROS time, which may still be the
        # last scan's stamp (the clock need not have moved since: the node can publish an
        # update's hypotheses at the scan's own time). The messages on subscription came
        # before the scans, so "at or after the last scan" tells the reset's apart.
        # A wait generous in wall time: the reset's publish failed to come within the default
        # 15 s once, in a full run beside another two-core job.
        cleared = self.record[MEMORY, 'hypotheses'].wait_for(
            lambda m: m.updates == 0 and stamp_of(m) >= self.stamps[-1] - 1e-6 and len(m.configuration_ids) == 0,
            timeout=60.0, clock=self.clock)
        self.assertIsNotNone(cleared, 'no empty hypotheses after ~reset: got %s' % [
            (m.updates, stamp_of(m), len(m.configuration_ids)) for m in self.record[MEMORY, 'hypotheses'].snapshot()])
        empty = self.record[MEMORY, 'ltm'].wait_for(
            lambda m: m.info.width == 0 and stamp_of(m) >= self.stamps[-1] - 1e-6, timeout=60.0, clock=self.clock)
        self.assertIsNotNone(empty, 'no empty ~ltm after ~reset')


if __name__ == '__main__':
    rostest.rosrun(wall_scene.PKG, 'test_memory_node', TestMemoryNode)
