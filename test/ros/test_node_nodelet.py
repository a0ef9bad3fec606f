#!/usr/bin/env python3
"""dynamic_occupancy_grid/MappingNodelet in a nodelet manager maps the wall scene as
mapping_node does (same topics, services and parameters)."""

import os
import sys
import unittest

import rospy
import rostest
from nav_msgs.msg import OccupancyGrid

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import wall_scene  # noqa: E402
from wall_scene import WALL_POINTS, same_geometry_problems, wall_problems  # noqa: E402

NODE = '/mapper'


class TestNodelet(unittest.TestCase):

    def test_nodelet_maps_wall(self):
        scene = wall_scene.WallScene(NODE)
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


if __name__ == '__main__':
    rospy.init_node('test_nodelet')
    rostest.rosrun(wall_scene.PKG, 'test_node_nodelet', TestNodelet)
