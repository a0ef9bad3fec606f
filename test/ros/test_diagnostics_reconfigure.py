#!/usr/bin/env python3
"""mapping_node's /diagnostics (scan rate, tf, dropped scans, map), dynamic_reconfigure (a bad
sensor model refused, a good one used by the next step, sensor-model learning on and off,
the sensor model in use in the map status) and the `map` topic's map_server thresholds, on
the wall scene. The tests run in order (test_01 ...) on one node."""

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

    @wall_scene.reported_set_up
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
        # The ghosts the node dropped are not scans the scene's sync must wait for.
        self.scene.rebase_after_untracked()

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
        self.assertTrue(config['learn_sensor_model'])  # the node's default (not set in the .test)
        self.assertAlmostEqual(config['p_hit_given_occ'], 0.7)
        result = client.update_configuration({'p_hit_given_occ': 0.3, 'p_hit_given_free': 0.4})
        self.assertAlmostEqual(result['p_hit_given_occ'], 0.7)
        self.assertAlmostEqual(result['p_hit_given_free'], 0.2)
        self.assertAlmostEqual(rospy.get_param(NODE + '/p_hit_given_occ'), 0.7)

    def sensor_model_after_step(self, step, condition=lambda values: True):
        """The map status of a /diagnostics published after the call once step `step` (the
        node's number) is applied and `condition(values)` holds: its values, and the sensor
        model in use (p_hit_given_occ, p_hit_given_free, beam ends learned from)."""
        def applied(array):
            status = find_status(array, 'map')
            if status is None:
                return False
            values = values_of(status)
            return values.get('last applied step') == str(step) and condition(values)

        values = values_of(find_status(self.wait_for_diagnostics(applied), 'map'))
        return values, (float(values['sensor model p_hit_given_occ']), float(values['sensor model p_hit_given_free']),
                        float(values['sensor model learned from (beam ends)']))

    def apply_steps(self, count):
        """`count` steps of wall scans, applied; the node's number of the last."""
        self.scene.feed_steps(count)
        self.scene.finish()
        cell = self.scene.wait_for_cell_step(self.scene.last_step)
        self.assertEqual(cell.steps_since_observed, 0)
        return cell.last_observed_step

    def test_05_sensor_model_learned_by_default_and_fixed_when_turned_off(self):
        client = self.client()
        step = self.apply_steps(2)
        values, learned = self.sensor_model_after_step(step)
        # The node's default: learned online from 0.7 / 0.2. The wall ends every beam that
        # reaches it, the swept cells only see misses.
        self.assertEqual(values['learn sensor model'], 'True')
        self.assertEqual(values['learn transitions'], 'False')
        self.assertGreater(learned[2], 0.0)
        self.assertGreater(learned[0], 0.7 + 1e-3, values)
        self.assertLess(learned[1], 0.2 - 1e-3, values)

        # Off, together with a parameter that does not touch the sensor model: the model
        # learned so far stays in use (no restart from 0.7 / 0.2) ...
        result = client.update_configuration({'learn_sensor_model': False, 'transition_scale': 0.2})
        self.assertFalse(result['learn_sensor_model'])
        values, fixed = self.sensor_model_after_step(step, lambda v: v['learn sensor model'] == 'False')
        self.assertEqual(fixed, learned, values)
        # ... and fixed: the next steps do not change it.
        step = self.apply_steps(2)
        values, after = self.sensor_model_after_step(step)
        self.assertEqual(values['learn sensor model'], 'False')
        self.assertEqual(after, learned, values)
        client.update_configuration({'transition_scale': 0.1})

    def test_06_new_sensor_model_weighs_the_next_step(self):
        scene = self.scene
        x, y = WALL_POINTS[2]
        client = self.client()
        result = client.update_configuration({'p_hit_given_occ': 0.55, 'p_hit_given_free': 0.45})
        self.assertAlmostEqual(result['p_hit_given_occ'], 0.55)
        # The wall cell after its last step, then one step of two scans (two hits) with the
        # new model (learn_transitions is off: the transitions stay the prior ones;
        # learn_sensor_model is off since test_05: the model stays the one set).
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

    def test_07_map_topic_is_static_map_scaled_like_map_server(self):
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

    def test_08_sensor_model_learning_on_again_starts_from_the_model_set(self):
        client = self.client()
        # test_06 set 0.7 / 0.2 last, with learning off: the start, with no sums.
        result = client.update_configuration({'learn_sensor_model': True})
        self.assertTrue(result['learn_sensor_model'])
        cell = self.scene.get_cell(*WALL_POINTS[2])
        values, start = self.sensor_model_after_step(cell.last_observed_step,
                                                     lambda v: v['learn sensor model'] == 'True')
        self.assertEqual(start, (0.7, 0.2, 0.0), values)
        # Steps with learning on again: it learns from there.
        step = self.apply_steps(2)
        values, learned = self.sensor_model_after_step(step)
        self.assertEqual(values['learn sensor model'], 'True')
        self.assertGreater(learned[2], 0.0, values)
        self.assertGreater(learned[0], 0.7 + 1e-3, values)
        self.assertLess(learned[1], 0.2 - 1e-3, values)


if __name__ == '__main__':
    rostest.rosrun(wall_scene.PKG, 'diagnostics_reconfigure', TestDiagnosticsReconfigure)
