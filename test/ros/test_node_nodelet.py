#!/usr/bin/env python3
"""dynamic_occupancy_grid/MappingNodelet in a nodelet manager maps the wall scene as
mapping_node does (same topics, services and parameters), and, as mapping_node, maps on
while a request is stuck (its services have a queue and threads of their own)."""

import os
import shutil
import sys
import tempfile
import unittest

import dynamic_reconfigure.client
import rospy
import rostest
from diagnostic_msgs.msg import DiagnosticArray
from nav_msgs.msg import OccupancyGrid

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import wall_scene  # noqa: E402
from wall_scene import WALL_POINTS, same_geometry_problems, wall_problems  # noqa: E402

NODE = '/mapper'


class TestNodelet(unittest.TestCase):

    def test_nodelet_maps_wall(self):
        scene = wall_scene.WallScene(NODE)
        diagnostics = wall_scene.TopicRecorder('/diagnostics', DiagnosticArray)
        belief = wall_scene.TopicRecorder(NODE + '/belief', OccupancyGrid)
        static_map = wall_scene.TopicRecorder(NODE + '/static_map', OccupancyGrid)
        scene.wait_for_node()
        scene.broadcast_tf()
        scene.first_scan()
        last = scene.feed_steps(7)
        scene.finish()
        cell = scene.wait_for_cell_step(last)
        self.assertTrue(cell.observed)
        self.assertGreater(cell.belief, 0.65)
        stamp = scene.step_end(last)
        problems = {}

        def mapped(layer):
            def check(msg):
                if abs(msg.header.stamp.to_sec() - stamp) > 1e-3 or msg.info.width == 0:
                    return False
                problems[layer] = wall_problems(msg)
                return not problems[layer]
            return check

        grid = belief.wait_for(mapped('belief'), clock=scene.clock)
        self.assertIsNotNone(grid, 'belief does not show the wall: %s' % problems.get('belief', 'no grid'))
        self.assertEqual(grid.header.frame_id, 'map')
        baseline = static_map.wait_for(mapped('static_map'), clock=scene.clock)
        self.assertIsNotNone(baseline, 'static_map does not show the wall: %s' % problems.get('static_map'))
        self.assertEqual(same_geometry_problems(baseline, grid), [])
        now = scene.service('predict_map')(horizon=0.0)
        self.assertTrue(now.success, now.message)
        self.assertEqual(list(now.map.data), list(grid.data))
        self.assertTrue(scene.get_cell(*WALL_POINTS[0]).observed)

        # /diagnostics under the nodelet's name, with the map it made.
        def mapping_status(array):
            return any(s.name == 'mapper: map' and any(v.key == 'last applied step' and v.value != 'none'
                                                       for v in s.values) for s in array.status)

        self.assertIsNotNone(diagnostics.wait_for(mapping_status, clock=scene.clock),
                             'no /diagnostics status "mapper: map" with an applied step')
        # dynamic_reconfigure starts from the nodelet's parameters and applies a change.
        client = dynamic_reconfigure.client.Client(NODE, timeout=15.0)
        self.assertAlmostEqual(client.get_configuration(timeout=10.0)['publish_period'], 0.1)
        self.assertAlmostEqual(client.update_configuration({'publish_period': 0.2})['publish_period'], 0.2)

        # A request stuck in open() (a bag this test holds a lease on) stops neither the
        # nodelet's scans nor its other services.
        tmp = tempfile.mkdtemp(prefix='dog_nodelet_')
        try:
            wall_scene.assert_mapping_goes_on_during_stuck_request(self, scene, belief, tmp)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)


if __name__ == '__main__':
    rospy.init_node('test_nodelet')
    rostest.rosrun(wall_scene.PKG, 'test_node_nodelet', TestNodelet)
