#!/usr/bin/env python3
"""Checks scripts/pose_ate.py: the rigid 2D alignment and ATE, the pose algebra, the
interpolation of odometry, and on a small synthetic bag (written here with rosbag) the clock
offset, the dropping of map -> odom messages stamped on another clock, the jumps, the
segments and the scores against hand-computed values.

Runs with /usr/bin/python3 (numpy; rosbag for the bag tests, skipped without it):
    /usr/bin/python3 test/python/test_pose_ate.py
"""

import math
import os
import sys
import tempfile
import unittest

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), '..', '..', 'scripts'))
import pose_ate as pa  # noqa: E402

try:
    import rosbag
    import rospy
    from geometry_msgs.msg import TransformStamped
    from sensor_msgs.msg import LaserScan
    from tf2_msgs.msg import TFMessage
    HAVE_ROSBAG = True
except ImportError:  # pragma: no cover
    HAVE_ROSBAG = False


def rigid(points, yaw, tx, ty):
    c, s = math.cos(yaw), math.sin(yaw)
    p = np.asarray(points, dtype=float)
    return p @ np.array([[c, -s], [s, c]]).T + [tx, ty]


class Geometry(unittest.TestCase):
    def test_alignment_recovers_a_rigid_motion(self):
        rng = np.random.default_rng(3)
        est = rng.uniform(-5, 5, size=(50, 2))
        ref = rigid(est, 2.5, 3.0, -7.0)
        rot, t = pa.align_rigid_2d(est, ref)
        self.assertAlmostEqual(math.atan2(rot[1, 0], rot[0, 0]), 2.5, places=9)
        np.testing.assert_allclose(t, [3.0, -7.0], atol=1e-9)
        self.assertLess(pa.ate(est, ref), 1e-9)

    def test_ate_is_the_rmse_left_after_alignment(self):
        # a square against the same square with one corner moved out by d: Umeyama's RMSE
        # must be the minimum over rotations (for each, the best translation matches the
        # centroids), found here by a grid search, and below the unaligned RMSE
        est = [(0, 0), (1, 0), (1, 1), (0, 1)]
        d = 0.2
        ref = [(0, 0), (1, 0), (1 + d / math.sqrt(2), 1 + d / math.sqrt(2)), (0, 1)]
        value = pa.ate(est, ref)
        unaligned = math.sqrt(np.mean(np.sum((np.array(est) - np.array(ref)) ** 2, axis=1)))
        self.assertLess(value, unaligned)
        best = min(
            math.sqrt(np.mean(np.sum((rigid(est, a, 0, 0) + np.mean(ref, axis=0) - np.mean(rigid(est, a, 0, 0), axis=0)
                                      - np.array(ref)) ** 2, axis=1)))
            for a in np.linspace(-0.2, 0.2, 4001))
        self.assertAlmostEqual(value, best, places=5)

    def test_a_reflection_is_not_an_alignment(self):
        est = [(0, 0), (1, 0), (0, 2)]
        ref = [(0, 0), (1, 0), (0, -2)]  # mirrored: no rotation maps one onto the other
        rot, _ = pa.align_rigid_2d(est, ref)
        self.assertAlmostEqual(np.linalg.det(rot), 1.0, places=12)
        self.assertGreater(pa.ate(est, ref), 0.5)

    def test_compose_and_relative_are_inverse(self):
        a = (1.0, -2.0, 3.0)
        b = (-0.5, 4.0, -2.9)
        r = pa.relative(a, b)
        c = pa.compose(a, r)
        for x, y in zip(c, b):
            self.assertAlmostEqual(pa.wrap(x - y), 0.0, places=12)

    def test_interpolation_goes_the_short_way_round(self):
        odo = pa.Interpolated([0.0, 1.0], [(0, 0, 3.1), (1, 2, -3.1)])
        x, y, yaw = odo.at(0.5)
        self.assertAlmostEqual(x, 0.5)
        self.assertAlmostEqual(y, 1.0)
        self.assertAlmostEqual(abs(yaw), math.pi, places=6)
        self.assertEqual(odo.at(-1.0), (0, 0, 3.1))  # held at the ends
        held = pa.Held([0.0, 1.0], ['a', 'b'])
        self.assertEqual((held.at(0.99), held.at(1.0), held.at(-5)), ('a', 'b', 'a'))

    def test_path_length(self):
        self.assertAlmostEqual(pa.path_length([(0, 0), (3, 4), (3, 5)]), 6.0)


@unittest.skipUnless(HAVE_ROSBAG, 'needs the ROS python rosbag module')
class SyntheticBag(unittest.TestCase):
    """30 s at 10 Hz: the robot drives along x at 0.5 m/s, odometry exact. The localizer
    publishes on the replay's clock (the scans' clock + 1000 s, received 2 ms later; stamped
    0.05 s ahead as a transform tolerance): identity, a jump of 3 m at t = 10 s, a 0.2 m step
    (under the threshold) at t = 20 s. A second map -> odom stream on another clock, 7 m off,
    must be dropped. The filter's trajectory (every 5th scan) is exact before the jump,
    0.1 m to either side alternately after it, and 5 % long after the step."""

    OFFSET = 1000.0
    T0 = 100.0

    def write(self, path, filter_path):
        def tf(parent, child, stamp, x, y, yaw):
            m = TransformStamped()
            m.header.frame_id, m.child_frame_id = parent, child
            m.header.stamp = rospy.Time.from_sec(stamp)
            m.transform.translation.x, m.transform.translation.y = x, y
            m.transform.rotation.z, m.transform.rotation.w = math.sin(yaw / 2), math.cos(yaw / 2)
            return TFMessage(transforms=[m])

        with rosbag.Bag(path, 'w') as bag, open(filter_path, 'w') as tum:
            tum.write('# test\n')
            for k in range(300):
                t = self.T0 + 0.1 * k
                receive = rospy.Time.from_sec(t + self.OFFSET + 0.002)
                x = 0.05 * k
                bag.write('/tf', tf('odom', 'base_link', t, x, 0.0, 0.0), receive)
                scan = LaserScan()
                scan.header.stamp = rospy.Time.from_sec(t)
                scan.header.frame_id = 'base_link'
                bag.write('/scan', scan, receive)
                if k < 100:
                    mo = (0.0, 0.0, 0.0)
                elif k < 200:
                    mo = (3.0, 0.0, 0.0)   # the jump
                else:
                    mo = (3.2, 0.0, 0.0)   # a step under the threshold
                if k % 2 == 0:
                    bag.write('/tf', tf('map', 'odom', t + self.OFFSET + 0.05, *mo), receive)
                    # another localizer, stamped on another clock: 7 m off, to be dropped
                    bag.write('/tf', tf('map', 'odom', t - 22.0, mo[0] + 7.0, 0.0, 0.0), receive)
                # the filter: exact in the first segment, 0.1 m off sideways on every other
                # pose of the second, and in the third a path 5 % long
                if k % 5 == 0:
                    if k <= 100:  # the jump is stamped 0.048 s after scan 100
                        fx, fy = x, 0.0
                    elif k <= 200:
                        fx, fy = x + 3.0, 0.1 if (k // 5) % 2 else -0.1
                    else:
                        fx, fy = 3.2 + 1.05 * x, 0.0
                    tum.write('%.9f %.6f %.6f 0 0 0 0 1\n' % (t, fx, fy))

    def setUp(self):
        self.dir = tempfile.TemporaryDirectory()
        self.bag = os.path.join(self.dir.name, 'synthetic.bag')
        self.tum = os.path.join(self.dir.name, 'trajectory.tum')
        self.write(self.bag, self.tum)

    def tearDown(self):
        self.dir.cleanup()

    def test_offset_streams_and_jumps(self):
        data = pa.read_bag(self.bag, 0.5, 0.3)
        self.assertAlmostEqual(data.offset_s, self.OFFSET + 0.002, places=4)
        self.assertEqual(data.map_odom_dropped, 150)
        self.assertEqual(len(data.jumps), 1)
        stamp, metres, radians = data.jumps[0]
        self.assertAlmostEqual(stamp, self.T0 + 10.0 + 0.048, places=3)
        self.assertAlmostEqual(metres, 3.0, places=6)
        self.assertAlmostEqual(radians, 0.0)
        ref = pa.reference_at(data, self.T0 + 15.0)
        self.assertAlmostEqual(ref[0], 3.0 + 0.05 * 150, places=6)

    def test_scores(self):
        data = pa.read_bag(self.bag, 0.5, 0.3)
        stamps, poses = pa.read_tum(self.tum)
        estimates = {'filter': (stamps, poses), 'odometry': (stamps, [data.odom.at(s) for s in stamps])}
        segments, totals, length = pa.score(data, estimates, 1.0, 3)
        self.assertEqual(len(segments), 2)
        first, second = segments
        self.assertTrue(first['scored'] and second['scored'])
        self.assertEqual(first['poses'], 21)  # k = 0, 5, ..., 100 (the jump is stamped after t = 10 s)
        self.assertAlmostEqual(first['ate']['odometry'], 0.0, places=6)
        self.assertAlmostEqual(first['ate']['filter'], 0.0, places=6)
        # segment 1 holds the 0.2 m step: odometry is off by a step, which alignment spreads
        self.assertGreater(second['ate']['odometry'], 0.05)
        # the total is the length-weighted mean
        expected = (first['length_m'] * first['ate']['filter'] + second['length_m'] * second['ate']['filter']) / length
        self.assertAlmostEqual(totals['filter'], expected, places=12)
        self.assertAlmostEqual(length, first['length_m'] + second['length_m'])

    def test_zigzag_costs_its_amplitude(self):
        # only the second segment's first half (k = 105..195, before the step at 20 s) with
        # the filter 0.1 m sideways, alternating: ATE 0.1 after alignment (the mean is 0 or
        # near it; the odd count leaves a small bias, hence the tolerance)
        data = pa.read_bag(self.bag, 0.5, 0.3)
        stamps, poses = pa.read_tum(self.tum)
        sel = [i for i, s in enumerate(stamps) if self.T0 + 10.2 < s < self.T0 + 19.9]
        est = [poses[i][:2] for i in sel]
        ref = [pa.reference_at(data, stamps[i])[:2] for i in sel]
        self.assertAlmostEqual(pa.ate(est, ref), 0.1, delta=0.003)

    def test_main_prints_a_row(self):
        import io
        import contextlib
        out = io.StringIO()
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()):
            status = pa.main([self.bag, '--trajectory', self.tum, '--no-header'])
        self.assertEqual(status, 0)
        row = out.getvalue().strip().split('|')
        self.assertEqual(row[1].strip(), 'synthetic')
        self.assertEqual(row[2].strip(), '2 / 2')


if __name__ == '__main__':
    unittest.main()
