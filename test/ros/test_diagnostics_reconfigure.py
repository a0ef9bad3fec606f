#!/usr/bin/env python3
"""mapping_node's /diagnostics (scan rate, tf, dropped scans, map), dynamic_reconfigure (a bad
sensor model refused, a good one used by the next step) and the `map` topic's map_server
thresholds, on the wall scene. The tests run in order (test_01 ...) on one node."""

import math
import os
import sys
import unittest

import dynamic_reconfigure.client
import rospy
import rostest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from nav_msgs.msg import OccupancyGrid

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import wall_scene  # noqa: E402
from wall_scene import BEHIND_POINTS, FREE_POINTS, WALL_POINTS, grid_value  # noqa: E402

NODE = '/mapper'
# Parameters of diagnostics_reconfigure.test.
OCCUPIED_THRESH = 0.65  # map_server's defaults (map_topic/occupied_thresh, free_thresh)
FREE_THRESH = 0.196
LEVELS = {DiagnosticStatus.OK: 'OK', DiagnosticStatus.WARN: 'WARN', DiagnosticStatus.ERROR: 'ERROR',
          DiagnosticStatus.STALE: 'STALE'}


def find_status(array, suffix):
    """The status of `array` whose name ends with ': ' + suffix, or None."""
    for status in array.status:
        if status.name.endswith(': ' + suffix):
            return status
    return None


def values_of(status):
    return {pair.key: pair.value for pair in status.values}


def describe(array):
    return '; '.join('%s %s (%s)' % (s.name, LEVELS.get(s.level, s.level), s.message) for s in array.status) \
        if array else 'no /diagnostics'


class TestDiagnosticsReconfigure(unittest.TestCase):

    @classmethod
    def setUpClass(cls):
        rospy.init_node('test_diagnostics_reconfigure')
        cls.scene = wall_scene.WallScene(NODE)
        cls.diagnostics = wall_scene.TopicRecorder('/diagnostics', DiagnosticArray)
        cls.scene.wait_for_node()
        cls.scene.broadcast_tf()
        cls.scene.first_scan()

    def wait_for_diagnostics(self, condition, feed=None, timeout=20.0):
        """Waits for a /diagnostics message published after the call that satisfies
        `condition(array)`, calling `feed()` (publishing scans) or else advancing the clock
        between polls; returns it, or fails naming the last statuses seen."""
        seen = len(self.diagnostics.snapshot())
        result = {}

        def arrived():
            if feed is not None:
                feed()
            for array in self.diagnostics.snapshot()[seen:]:
                result['last'] = array
                if condition(array):
                    result['match'] = array
                    return True
            return False

        self.scene.wait_until(arrived, timeout=timeout, tick=0.05)
        self.assertIn('match', result, 'no matching /diagnostics; last: %s' % describe(result.get('last')))
        return result['match']

    def feed_wall(self):
        self.scene.feed_steps(1)

    def test_01_all_ok_while_scanning(self):
        def all_ok(array):
            names = ('scans /scan topic status', 'tf', 'scans dropped', 'map', 'offline EM')
            statuses = [find_status(array, name) for name in names]
            return all(s is not None and s.level == DiagnosticStatus.OK for s in statuses)

        array = self.wait_for_diagnostics(all_ok, feed=self.feed_wall)
        rate = values_of(find_status(array, 'scans /scan topic status'))
        self.assertIn('Actual frequency (Hz)', rate)
        mapping = values_of(find_status(array, 'map'))
        self.assertGreater(int(mapping['cells allocated']), 0)
        self.assertIn('step lag (s)', mapping)
        self.assertEqual(values_of(find_status(array, 'offline EM'))['phase'], 'idle')

    def test_02_missing_tf_is_an_error(self):
        # Scans of a frame nobody broadcasts: they wait in the tf filter until its queue
        # (5) overflows, and no scan is integrated meanwhile.
        def feed_ghost():
            self.scene.clock.advance(0.05)
            self.scene.scan_publisher.publish(self.scene.make_scan(self.scene.clock.now, frame_id='ghost_laser'))

        def tf_error(array):
            status = find_status(array, 'tf')
            return status is not None and status.level == DiagnosticStatus.ERROR

        array = self.wait_for_diagnostics(tf_error, feed=feed_ghost)
        tf = find_status(array, 'tf')
        self.assertIn("'map'", tf.message)
        self.assertGreater(int(values_of(tf)['tf failures']), 0)
        self.assertIn('ghost_laser', values_of(tf)['last tf failure'])
        dropped = values_of(find_status(array, 'scans dropped'))
        self.assertGreater(int(dropped['dropped: no transform (tf)']), 0)
        # The scans still arrive: their rate is fine.
        self.assertEqual(find_status(array, 'scans /scan topic status').level, DiagnosticStatus.OK, describe(array))

    def test_03_rate_and_map_degrade_when_scans_stop(self):
        def stale(array):
            rate = find_status(array, 'scans /scan topic status')
            mapping = find_status(array, 'map')
            return (rate is not None and rate.level in (DiagnosticStatus.WARN, DiagnosticStatus.ERROR) and
                    mapping is not None and mapping.level == DiagnosticStatus.WARN)

        array = self.wait_for_diagnostics(stale)  # only the clock moves
        self.assertIn('behind ROS time', find_status(array, 'map').message)
        # Scans again: the rate and the map recover.
        self.wait_for_diagnostics(
            lambda a: find_status(a, 'scans /scan topic status').level == DiagnosticStatus.OK and
            find_status(a, 'map').level == DiagnosticStatus.OK, feed=self.feed_wall)

    def client(self):
        return dynamic_reconfigure.client.Client(NODE, timeout=15.0)

    def test_04_reconfigure_starts_from_the_parameters_and_refuses_a_bad_sensor_model(self):
        client = self.client()
        config = client.get_configuration(timeout=10.0)
        self.assertAlmostEqual(config['publish_period'], 0.1)   # from the .test, not the .cfg default
        self.assertAlmostEqual(config['full_map_period'], 0.0)
        self.assertFalse(config['learn_transitions'])
        self.assertAlmostEqual(config['p_hit_given_occ'], 0.7)
        result = client.update_configuration({'p_hit_given_occ': 0.3, 'p_hit_given_free': 0.4})
        self.assertAlmostEqual(result['p_hit_given_occ'], 0.7)
        self.assertAlmostEqual(result['p_hit_given_free'], 0.2)
        self.assertAlmostEqual(rospy.get_param(NODE + '/p_hit_given_occ'), 0.7)

    def test_05_new_sensor_model_weighs_the_next_step(self):
        scene = self.scene
        x, y = WALL_POINTS[2]
        client = self.client()
        result = client.update_configuration({'p_hit_given_occ': 0.55, 'p_hit_given_free': 0.45})
        self.assertAlmostEqual(result['p_hit_given_occ'], 0.55)
        # The wall cell after its last step, then one step of two scans (two hits) with the
        # new model (learn_transitions is off: the transitions stay the prior ones).
        scene.finish()
        before = scene.wait_for_cell_step(scene.last_step)
        self.assertEqual(before.steps_since_observed, 0)
        scene.feed_steps(1)
        scene.finish()
        after = scene.wait_for_cell_step(scene.last_step)
        self.assertGreater(after.last_observed_step, before.last_observed_step)

        def expected(p_hit_given_occ, p_hit_given_free, hits=2):
            p_of, p_fo = before.p_occ_given_free, before.p_free_given_occ
            p = before.belief
            for _ in range(after.last_observed_step - before.last_observed_step):
                p = p * (1.0 - p_fo) + (1.0 - p) * p_of
            ratio = (p_hit_given_occ / p_hit_given_free) ** hits
            return p * ratio / (p * ratio + 1.0 - p)

        self.assertAlmostEqual(after.belief, expected(0.55, 0.45), delta=1e-4)
        self.assertGreater(abs(after.belief - expected(0.7, 0.2)), 1e-3)
        client.update_configuration({'p_hit_given_occ': 0.7, 'p_hit_given_free': 0.2})

    def test_06_map_topic_is_static_map_scaled_like_map_server(self):
        scene = self.scene
        maps = wall_scene.TopicRecorder('/map', OccupancyGrid)
        static = wall_scene.TopicRecorder(NODE + '/static_map', OccupancyGrid)
        try:
            scene.feed_steps(2)
            scene.finish()
            stamp = scene.step_end(scene.last_step)

            def final(msg):
                return abs(msg.header.stamp.to_sec() - stamp) < 1e-3 and msg.info.width > 0

            grid = maps.wait_for(final, clock=scene.clock)
            reference = static.wait_for(final, clock=scene.clock)
        finally:
            maps.unregister()
            static.unregister()
        self.assertIsNotNone(grid, 'no /map of the last step')
        self.assertIsNotNone(reference, 'no static_map of the last step')
        self.assertEqual(wall_scene.same_geometry_problems(grid, reference), [])
        for x, y in WALL_POINTS:
            self.assertEqual(grid_value(grid, x, y), 100)
        for x, y in FREE_POINTS:
            self.assertEqual(grid_value(grid, x, y), 0)
        for x, y in BEHIND_POINTS:
            self.assertIn(grid_value(grid, x, y), (None, -1))
        # Every cell as map_server's scale mode reads p = static_map / 100 (cells whose raw
        # value lies within rounding of a threshold are skipped).
        for value, raw in zip(grid.data, reference.data):
            if raw == -1:
                self.assertEqual(value, -1)
                continue
            p = raw / 100.0
            if p > OCCUPIED_THRESH + 0.006:
                self.assertEqual(value, 100, 'raw %d' % raw)
            elif p < FREE_THRESH - 0.006:
                self.assertEqual(value, 0, 'raw %d' % raw)
            elif FREE_THRESH + 0.006 < p < OCCUPIED_THRESH - 0.006:
                scaled = 1.0 + 98.0 * (p - FREE_THRESH) / (OCCUPIED_THRESH - FREE_THRESH)
                self.assertLessEqual(abs(value - scaled), 2.0, 'raw %d' % raw)


if __name__ == '__main__':
    rostest.rosrun(wall_scene.PKG, 'diagnostics_reconfigure', TestDiagnosticsReconfigure)
