#!/usr/bin/env python3
"""mapping_node's topics: a laser facing a wall for several time steps; every layer must map
the wall where it is, with the same geometry, and the updates must patch the full grids."""

import math
import sys
import os
import unittest

import rospy
import rostest
from map_msgs.msg import OccupancyGridUpdate
from nav_msgs.msg import OccupancyGrid

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import wall_scene  # noqa: E402
from wall_scene import (BEHIND_POINTS, FREE_POINTS, OUTSIDE_FAN_POINTS, RESOLUTION, TIME_STEP,  # noqa: E402
                        WALL_POINTS, grid_value, same_geometry_problems, wall_problems)

NODE = '/mapper'
STEPS = 8
# Parameters of mapping_node.test.
PREDICTION_HORIZON = 2.0
PRIOR_CHANGE = 0.01       # prior_p_occ_given_free = prior_p_free_given_occ
TRANSITION_SCALE = 0.1


class TestMappingNode(unittest.TestCase):

    @wall_scene.reported_set_up
    def setUpClass(cls):
        rospy.init_node('test_mapping_node')
        cls.scene = wall_scene.WallScene(NODE)
        cls.full = {}
        cls.final_grids = {}
        # The other layers are first subscribed at the end (final_grid).
        for layer in ('belief', 'static_map'):
            cls.full[layer] = wall_scene.TopicRecorder(NODE + '/' + layer, OccupancyGrid)
        cls.updates = {layer: wall_scene.TopicRecorder(NODE + '/' + layer + '_updates', OccupancyGridUpdate)
                       for layer in ('belief', 'static_map')}
        cls.scene.wait_for_node()
        cls.scene.broadcast_tf()
        cls.scene.first_scan()
        # Step by step, so that the publish timer runs between steps (updates, not only
        # full grids).
        for _ in range(STEPS - 1):
            cls.scene.feed_steps(1)
            cls.scene.clock.advance(0.1)
        cls.last_step = cls.scene.last_step
        cls.scene.finish()
        cls.final_stamp = cls.scene.step_end(cls.last_step)
        # The node applies the last step at its next publish tick; a subscriber that connects
        # before it gets the step before as its full grid and then only updates (final_grid
        # waits for a full grid of the last step).
        applied = cls.scene.wait_for_cell_step(cls.last_step)
        assert applied is not None and applied.last_observed_step >= cls.scene.step_offset + cls.last_step, applied

    def final_grid(self, layer, recorder=None):
        """A full grid of `layer` showing the last step. Full grids are only sent when the
        bounds change, every full_map_period (1000 s here) and to a new subscriber: this
        subscribes anew (unless given a recorder) and waits for the grid the new subscriber
        gets at the next publish tick."""
        if recorder is None and layer in self.final_grids:
            return self.final_grids[layer]
        topic = '/map' if layer == 'map' else NODE + '/' + layer
        if recorder is None and layer in self.full:
            self.full[layer].unregister()  # else rospy would reuse its connection
        fresh = recorder or wall_scene.TopicRecorder(topic, OccupancyGrid)

        def is_final(msg):
            return abs(msg.header.stamp.to_sec() - self.final_stamp) < 1e-3 and msg.info.width > 0

        try:
            grid = fresh.wait_for(is_final, clock=self.scene.clock)
            stamps = [round(m.header.stamp.to_sec(), 3) for m in fresh.snapshot()]
        finally:
            if recorder is None:
                fresh.unregister()
        self.assertIsNotNone(grid, '%s: a new subscriber got no full grid stamped %.3f (end of the last '
                             'step); got stamps %s' % (layer, self.final_stamp, stamps))
        if recorder is None:
            self.final_grids[layer] = grid
        return grid

    def test_belief_maps_wall(self):
        grid = self.final_grid('belief')
        self.assertEqual(grid.header.frame_id, 'map')
        self.assertAlmostEqual(grid.info.resolution, RESOLUTION, places=6)
        self.assertEqual(wall_problems(grid), [])
        # The grid covers the wall and the laser.
        self.assertIsNotNone(grid_value(grid, wall_scene.LASER_X, wall_scene.LASER_Y))
        # The origin lies on the lattice of origin (0, 0) with 0.1 m cells.
        for coordinate in (grid.info.origin.position.x, grid.info.origin.position.y):
            self.assertAlmostEqual(coordinate / RESOLUTION, round(coordinate / RESOLUTION), places=4)
        self.assertAlmostEqual(grid.info.origin.orientation.w, 1.0)

    def test_static_map_maps_wall(self):
        grid = self.final_grid('static_map')
        self.assertEqual(same_geometry_problems(grid, self.final_grid('belief')), [])
        self.assertEqual(wall_problems(grid), [])

    def test_map_topic_is_trinary_belief(self):
        # map_topic's defaults: the belief, thresholded as map_server's trinary mode reads an
        # image (occupied_thresh 0.65, free_thresh 0.196), so that costmap_2d sees lethal cells.
        grid = self.final_grid('map')
        belief = self.final_grid('belief')
        self.assertEqual(same_geometry_problems(grid, belief), [])
        for value, raw in zip(grid.data, belief.data):
            if raw == -1 or 20 <= raw <= 64:
                self.assertEqual(value, -1, 'belief %d' % raw)
            elif raw >= 66:
                self.assertEqual(value, 100, 'belief %d' % raw)
            elif raw <= 19:
                self.assertEqual(value, 0, 'belief %d' % raw)
        self.assertEqual(wall_problems(grid, occupied_above=99, free_below=1), [])

    def test_stationary_and_transition_layers(self):
        belief = self.final_grid('belief')
        observed = WALL_POINTS + FREE_POINTS
        # online_em/min_observed_steps is larger than STEPS: every cell has the prior
        # transitions, so p_occ_given_free = 0.01 (10 at transition_scale 0.1) and the
        # stationary p(occ) is 0.01 / (0.01 + 0.01) = 0.5.
        expected = {'stationary': 50, 'p_occ_given_free': int(round(100 * PRIOR_CHANGE / TRANSITION_SCALE))}
        for layer, value in expected.items():
            grid = self.final_grid(layer)
            self.assertEqual(same_geometry_problems(grid, belief), [], layer)
            for x, y in observed:
                self.assertEqual(grid_value(grid, x, y), value, '%s at (%.2f, %.2f)' % (layer, x, y))
            for x, y in BEHIND_POINTS + OUTSIDE_FAN_POINTS:
                self.assertIn(grid_value(grid, x, y), (None, -1), '%s at (%.2f, %.2f)' % (layer, x, y))

    def test_predicted_is_belief_moved_toward_stationary(self):
        belief = self.final_grid('belief')
        grid = self.final_grid('predicted')
        self.assertEqual(same_geometry_problems(grid, belief), [])
        # Two-state chain with both change probabilities c: p(occ) after n steps is
        # 0.5 + (p - 0.5) (1 - 2c)^n.
        factor = (1.0 - 2.0 * PRIOR_CHANGE) ** round(PREDICTION_HORIZON / TIME_STEP)
        for x, y in WALL_POINTS + FREE_POINTS:
            now = grid_value(belief, x, y)
            ahead = grid_value(grid, x, y)
            want = 50.0 + (now - 50.0) * factor
            self.assertLessEqual(abs(ahead - want), 1.0,
                                 'predicted at (%.2f, %.2f) = %d, belief %d: want %.1f' % (x, y, ahead, now, want))
            self.assertLessEqual(abs(ahead - 50), abs(now - 50))
        for x, y in BEHIND_POINTS:
            self.assertIn(grid_value(grid, x, y), (None, -1))

    def check_updates(self, layer):
        full = self.full[layer]
        updates = self.updates[layer]
        final = self.final_grid(layer)
        width, height = final.info.width, final.info.height
        first_full = full.wait_for(lambda m: m.info.width > 0)
        self.assertIsNotNone(first_full)
        start = first_full.header.stamp.to_sec()

        def patched():
            """The first full grid with every later update applied, as the map would be
            shown by a client of <layer> + <layer>_updates."""
            data = list(first_full.data)
            for update in updates.snapshot():
                if update.header.stamp.to_sec() <= start:
                    continue
                for row in range(update.height):
                    for column in range(update.width):
                        data[(update.y + row) * width + update.x + column] = \
                            update.data[row * update.width + column]
            return data

        def patched_matches():
            if not updates.snapshot():
                return False
            data = patched()
            return all(data[self.index(final, x, y)] == grid_value(final, x, y) for x, y in WALL_POINTS + FREE_POINTS)

        self.scene.wait_until(patched_matches)
        received = updates.snapshot()
        self.assertTrue(received, 'no message on %s_updates' % layer)
        self.assertEqual((first_full.info.width, first_full.info.height), (width, height),
                         'the grid kept its size in this scene')
        for update in received:
            self.assertEqual(update.header.frame_id, 'map')
            self.assertGreater(update.width * update.height, 0)
            self.assertEqual(len(update.data), update.width * update.height)
            self.assertGreaterEqual(update.x, 0)
            self.assertGreaterEqual(update.y, 0)
            self.assertLessEqual(update.x + update.width, width)
            self.assertLessEqual(update.y + update.height, height)
            self.assertTrue(all(-1 <= v <= 100 for v in update.data))
            # The changed cells are the swept fan: the updates are smaller than the grid.
            self.assertLess(update.width * update.height, width * height)
        data = patched()
        for x, y in WALL_POINTS + FREE_POINTS:
            self.assertEqual(data[self.index(final, x, y)], grid_value(final, x, y),
                             '%s + updates differs from the full grid at (%.2f, %.2f)' % (layer, x, y))

    @staticmethod
    def index(grid, x, y):
        i = int(math.floor((x - grid.info.origin.position.x) / grid.info.resolution))
        j = int(math.floor((y - grid.info.origin.position.y) / grid.info.resolution))
        return j * grid.info.width + i

    def test_belief_updates(self):
        self.check_updates('belief')

    def test_static_map_updates(self):
        self.check_updates('static_map')

    def test_late_subscriber_gets_full_grid(self):
        # Nobody subscribed to p_free_given_occ so far: it is evaluated for this subscriber.
        belief = self.final_grid('belief')
        late = wall_scene.TopicRecorder(NODE + '/p_free_given_occ', OccupancyGrid)
        try:
            grid = self.final_grid('p_free_given_occ', late)
            # Evaluated for this subscriber: nothing was published (latched) before.
            first = late.snapshot()[0]
            self.assertAlmostEqual(first.header.stamp.to_sec(), self.final_stamp, places=3)
            self.assertEqual(same_geometry_problems(grid, belief), [])
            for x, y in WALL_POINTS + FREE_POINTS:
                self.assertEqual(grid_value(grid, x, y), int(round(100 * PRIOR_CHANGE / TRANSITION_SCALE)))
            for x, y in BEHIND_POINTS:
                self.assertIn(grid_value(grid, x, y), (None, -1))
        finally:
            late.unregister()
        # The layers are latched: a late subscriber gets the last full grid at once, without
        # waiting for a publish tick (the clock stands still here).
        again = wall_scene.TopicRecorder(NODE + '/belief', OccupancyGrid)
        try:
            grid = again.wait_for(lambda m: m.info.width > 0, timeout=5.0)
            self.assertIsNotNone(grid, 'a late subscriber to belief got no latched full grid')
            self.assertEqual(same_geometry_problems(grid, belief), [])
            self.assertEqual(list(grid.data), list(belief.data))
        finally:
            again.unregister()


if __name__ == '__main__':
    rostest.rosrun(wall_scene.PKG, 'test_mapping_node', TestMappingNode)
