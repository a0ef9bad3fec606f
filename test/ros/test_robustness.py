#!/usr/bin/env python3
"""mapping_node against bad input: bad parameters stop it with an error naming the
parameter; malformed scans, scans without transform and time jumping back leave it alive
and mapping. The tests run in the order of their names and share the node."""

import math
import os
import sys
import unittest

import rospy
import rostest
from nav_msgs.msg import OccupancyGrid
from std_srvs.srv import Trigger

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import wall_scene  # noqa: E402
from wall_scene import (ANGLE_INCREMENT, ANGLE_MAX, ANGLE_MIN, BEAMS, RESOLUTION, WALL_POINTS, WALL_X,  # noqa: E402
                        grid_value, wall_problems, wall_ranges)

NODE = '/mapper'
MAX_MAP_SIZE = 40.0          # robustness.test
TIME_JUMP_THRESHOLD = 2.0    # robustness.test
NAN = float('nan')
INF = float('inf')


class TestRobustness(unittest.TestCase):

    @classmethod
    def setUpClass(cls):
        rospy.init_node('test_robustness')
        cls.scene = wall_scene.WallScene(NODE)
        cls.belief = wall_scene.TopicRecorder(NODE + '/belief', OccupancyGrid)
        cls.scene.wait_for_node()
        # No transform yet: test_02 sends a scan before it.

    def alive(self):
        """The node answers a service call."""
        response = self.scene.get_cell(*WALL_POINTS[2])
        self.assertIsNotNone(response)
        return response

    def map_wall(self, steps=8, check_behind=False):
        """Normal scans for `steps` steps; the belief must show the wall."""
        last = self.scene.feed_steps(steps)
        self.scene.finish()
        cell = self.scene.wait_for_cell_step(last)
        self.assertTrue(cell.observed)
        self.assertEqual(cell.steps_since_observed, 0)
        stamp = self.scene.step_end(last)
        problems = []

        def mapped(msg):
            if abs(msg.header.stamp.to_sec() - stamp) > 1e-3 or msg.info.width == 0:
                return False
            problems[:] = wall_problems(msg, check_behind=check_behind)
            return not problems

        grid = self.belief.wait_for(mapped, clock=self.scene.clock)
        self.assertIsNotNone(grid, 'belief after step %d (stamp %.3f) does not show the wall: %s' % (
            last, stamp, problems or 'no grid with that stamp'))
        return grid

    # --- parameters ---------------------------------------------------------------------------------
    def test_01_bad_parameters(self):
        cases = [
            ('resolution', '_resolution:=-1'),
            ('resolution', '_resolution:=abc'),
            ('time_step', '_time_step:=0'),
            ('publish_period', '_publish_period:=0'),
            ('scan_queue_size', '_scan_queue_size:=0'),
            ('scan_queue_size', '_scan_queue_size:=2.5'),
            ('learn_transitions', '_learn_transitions:=maybe'),
            ('p_hit_given', '_p_hit_given_occ:=0.1'),
            ('initial_p_occ', '_initial_p_occ:=1.0'),
            ('p_min', '_online_em/p_min:=0.9'),
            ('max_iterations', '_offline_em/max_iterations:=0'),
            ('mrf_temperature', '_offline_em/mrf_temperature:=-1'),
            ('mrf_temperature', '_offline_em/mrf_temperature:=abc'),
            # The MRF smooths the two transition maps separately: no single change probability.
            ('symmetric', '_offline_em/mrf_temperature:=50 _offline_em/symmetric:=true'),
            ('time_jump_threshold', '_time_jump_threshold:=-1'),
            ('model_file', '_model_file:=/nonexistent/model.dogm'),
            ('map_topic/layer', '_map_topic/layer:=p_occ_given_free'),
            ('map_topic/mode', '_map_topic/mode:=binary'),
            ('map_topic/free_thresh', '_map_topic/free_thresh:=0.8'),
            ('diagnostics/max_scan_rate_hz', '_diagnostics/min_scan_rate_hz:=20 _diagnostics/max_scan_rate_hz:=10'),
            ('diagnostics/period', '_diagnostics/period:=0'),
            # The learners' options (core::MapperConfig, core::OnlineEmConfig).
            (('online_em/schedule', '"harmonic" or "robbins_monro", got "cappe"'), '_online_em/schedule:=cappe'),
            (('online_em/schedule', 'must be a string'), '_online_em/schedule:=1'),
            (('online_em/step_size_exponent', '(0.5, 1]'), '_online_em/step_size_exponent:=0.5'),
            (('online_em/step_size_exponent', '(0.5, 1]'), '_online_em/step_size_exponent:=1.5'),
            (('online_em/step_size_offset', '>= 0'), '_online_em/step_size_offset:=-1'),
            (('online_em/averaging_start', 'must be in [0, '), '_online_em/averaging_start:=-1'),
            (('online_em/averaging_start', 'must be an integer'), '_online_em/averaging_start:=2.5'),
            (('learn_prior', 'true or false'), '_learn_prior:=maybe'),
            (('prior_population_weight', '> 0'), '_prior_population_weight:=0'),
            (('learn_sensor_model', 'true or false'), '_learn_sensor_model:=maybe'),
            (('sensor_model/prior_weight', '> 0'), '_sensor_model/prior_weight:=0'),
            (('sensor_model/prior_weight', 'must be a number'), '_sensor_model/prior_weight:=abc'),
            (('sensor_model/p_min', '(0, 0.4]'), '_sensor_model/p_min:=0.5'),
            (('sensor_model/p_min', '(0, 0.4]'), '_sensor_model/p_min:=0'),
        ]
        wall_scene.assert_bad_parameters_stop_node(self, cases, 'bad_parameter')
        # The node under test is not disturbed.
        self.alive()

    def test_01b_learner_parameters_are_read(self):
        """Good values of the learners' options start the node, none is taken for a typo, and
        the start-up lines report them; by default the node learns the sensor model."""
        arguments = ['_online_em/schedule:=robbins_monro', '_online_em/step_size_exponent:=0.75',
                     '_online_em/step_size_offset:=5', '_online_em/averaging_start:=20', '_learn_prior:=true',
                     '_prior_population_weight:=25', '_learn_sensor_model:=true', '_sensor_model/prior_weight:=400',
                     '_sensor_model/p_min:=0.02', '_online_em/learning_rate_floor:=0.002']
        output = ''.join(wall_scene.node_startup_output(self, 'good_learner_parameters', arguments,
                                                        'online learning of the sensor model'))
        self.assertNotIn('is not one of this node\'s parameters', output)
        self.assertIn('sensor model learned online', output)
        self.assertIn('schedule robbins_monro (step sizes max(0.002, (n + 5)^-0.75))', output)
        self.assertIn('averaging from observed step 20', output)
        self.assertIn('prior learned from the map (prior_population_weight 25)', output)
        self.assertIn('from p_hit_given_occ 0.7, p_hit_given_free 0.2, worth 400 beam ends per state', output)
        self.assertIn('within [0.02, 0.98]', output)

        # The defaults: the harmonic schedule, no averaging, a fixed prior, the sensor model learned.
        output = ''.join(wall_scene.node_startup_output(self, 'default_learner_parameters', [],
                                                        'online learning of the sensor model'))
        self.assertIn('transitions learned online, sensor model learned online', output)
        self.assertIn('schedule harmonic (prior weight 10, learning rate floor 0.001), averaging off, '
                      'prior fixed (0.01 / 0.01)', output)
        self.assertIn('worth 1000 beam ends per state', output)
        self.assertIn('within [0.01, 0.99]', output)

        # learn_sensor_model off: the fixed sensor model, and no line on its learning.
        output = ''.join(wall_scene.node_startup_output(self, 'fixed_sensor_model', ['_learn_sensor_model:=false'],
                                                        'online EM of the transitions'))
        self.assertIn('sensor model fixed (in use: p_hit_given_occ 0.700, p_hit_given_free 0.200)', output)
        self.assertNotIn('online learning of the sensor model', output)
        self.alive()

    # --- scans ------------------------------------------------------------------------------------------
    def test_02_scan_before_tf(self):
        self.assertFalse(self.alive().observed)
        # Stamped as the first scan of the sequence: it waits in the node's tf2
        # MessageFilter, and is mapped when the transform comes (or dropped).
        self.scene.start_sequence(self.scene.clock.now)
        self.scene.publish(self.scene.make_scan(self.scene.origin))
        self.scene.broadcast_tf()
        self.scene.first_scan()
        self.map_wall(check_behind=True)

    def test_03_malformed_scans(self):
        before = self.alive()
        self.assertTrue(before.observed)
        ranges = wall_ranges()
        mixed = list(ranges)
        for i, value in enumerate([NAN, INF, -INF, 0.0, -1.0, 1e30, 1e-30, -0.0, NAN]):
            mixed[i * 9] = value
        bad_scans = [
            dict(ranges=[NAN] * BEAMS),
            dict(ranges=[INF] * BEAMS),
            dict(ranges=[0.0] * BEAMS),
            dict(ranges=[-2.0] * BEAMS),
            dict(ranges=[-INF] * BEAMS),
            dict(ranges=mixed),
            dict(ranges=[]),
            dict(ranges=ranges[:40]),                        # fewer ranges than angles
            dict(ranges=ranges + ranges),                    # more ranges than angles
            dict(angle_increment=0.0),
            dict(angle_increment=NAN),
            dict(angle_increment=-ANGLE_INCREMENT),          # inconsistent sign
            dict(angle_min=NAN),
            dict(angle_max=INF),
            dict(range_min=5.0, range_max=1.0),
            dict(range_min=NAN),
            dict(range_max=NAN),
            dict(range_min=-1.0),
            dict(range_max=0.0),
            dict(range_min=INF, range_max=INF),
            dict(ranges=[1e30] * BEAMS, range_max=1e31),     # huge: clipped at the map's limits
            dict(ranges=[1e30] * BEAMS, range_max=3.0e38),
            dict(ranges=[2.0] * BEAMS, range_max=INF),
            dict(frame_id='no_such_frame'),
            dict(frame_id=''),
            dict(frame_id='/'),
            dict(ranges=[2.03], angle_increment=0.0, angle_max=ANGLE_MIN),  # one beam: valid
            dict(ranges=list(reversed(ranges)), angle_min=ANGLE_MAX, angle_max=ANGLE_MIN,
                 angle_increment=-ANGLE_INCREMENT),       # counter-clockwise order: valid
        ]
        step = self.scene.feed_steps(1)
        for fields in bad_scans:
            # Inside the step being gathered, after the normal scans.
            stamp = self.scene.step_stamps(step)[1] + 0.05
            self.scene.publish(self.scene.make_scan(stamp, **fields))
        self.alive()
        grid = self.map_wall()
        # The huge ranges mapped at most up to max_map_size / 2 from the origin.
        self.assertLessEqual(grid.info.width * grid.info.resolution, MAX_MAP_SIZE + 64 * RESOLUTION)
        self.assertLessEqual(grid.info.height * grid.info.resolution, MAX_MAP_SIZE + 64 * RESOLUTION)
        self.assertGreaterEqual(grid.info.origin.position.x, -MAX_MAP_SIZE / 2 - 64 * RESOLUTION)

    def test_04_time_jumps_back(self):
        before = self.alive()
        self.assertTrue(before.observed)
        old_stamp = self.scene.last_stamp
        self.assertIsNotNone(old_stamp)
        # A bag played again: clock and stamps restart 100 s earlier.
        restart = old_stamp - 100.0
        self.scene.clock.set(restart)
        self.scene.start_sequence(restart)
        after = self.scene.first_scan()
        # The map kept its content and went on after its last step.
        self.assertGreater(after.last_observed_step, before.last_observed_step)
        self.assertGreater(after.observed_steps, before.observed_steps)
        self.assertGreater(after.belief, 0.65)
        grid = self.map_wall(steps=4)
        self.assertLess(grid.header.stamp.to_sec(), old_stamp - 90.0, 'maps are stamped with the new time')
        # Once more, and a jump smaller than time_jump_threshold: those scans are late
        # (their steps are applied) and dropped, the map goes on.
        restart = self.scene.last_stamp - 0.5 * TIME_JUMP_THRESHOLD
        self.scene.publish(self.scene.make_scan(restart, ranges=[INF] * BEAMS))
        self.alive()
        self.map_wall(steps=2)

    def test_05_wall_still_mapped(self):
        grid = self.map_wall(steps=6)
        for x, y in WALL_POINTS:
            self.assertGreater(grid_value(grid, x, y), 65)
        self.assertTrue(math.isfinite(self.alive().belief))

    def test_06_upside_down_laser(self):
        """A laser mounted upside down (rolled by pi) sees the world mirrored: its beams at
        positive angles go to the right (negative y)."""
        reset = rospy.ServiceProxy(NODE + '/reset', Trigger)()
        self.assertTrue(reset.success, reset.message)
        self.assertFalse(self.alive().observed)
        self.scene.broadcast_tf(child='laser_upside_down', roll=math.pi)
        # Only the beams at angles >= 0 (in the laser's frame) return.
        ranges = [r if ANGLE_MIN + i * ANGLE_INCREMENT >= -1e-6 else NAN for i, r in enumerate(wall_ranges())]
        self.scene.start_sequence(self.scene.clock.now)
        self.scene.first_scan(frame_id='laser_upside_down', ranges=ranges)
        last = self.scene.feed_steps(6, frame_id='laser_upside_down', ranges=ranges)
        self.scene.finish()
        self.scene.wait_for_cell_step(last)
        right = self.scene.get_cell(WALL_X, 1.85)
        left = self.scene.get_cell(WALL_X, 2.25)
        self.assertTrue(right.observed, 'the wall right of an upside-down laser was not seen')
        self.assertGreater(right.belief, 0.65)
        self.assertFalse(left.observed, 'an upside-down laser mapped its beams mirrored: %s' % left)

    def test_07_zero_stamp(self):
        """A scan with an unset (zero) stamp carries no time (tf2 reads it as "latest"). It
        must not count as time jumping back to 0: the node restarted its clock at 0 and the
        next scans landed ~2000 steps after the map's last one, every belief predicted
        across that gap (mapping_node.cpp scanCallback; drop such scans)."""
        self.scene.start_sequence(self.scene.clock.now)
        self.scene.first_scan()
        last = self.scene.feed_steps(3)
        self.scene.finish()
        before = self.scene.wait_for_cell_step(last)
        self.scene.publish(self.scene.make_scan(0.0))
        self.alive()
        last = self.scene.feed_steps(2)
        self.scene.finish()
        after = self.scene.wait_for_cell_step(last)
        self.assertTrue(after.observed)
        # The two steps fed (one skipped by finish() between): at most 4 steps later.
        self.assertLessEqual(after.last_observed_step - before.last_observed_step, 4,
                             'one zero-stamped scan moved the map %d steps ahead (%s -> %s)' % (
                                 after.last_observed_step - before.last_observed_step,
                                 before.last_observed_step, after.last_observed_step))


if __name__ == '__main__':
    rostest.rosrun(wall_scene.PKG, 'test_robustness', TestRobustness)
