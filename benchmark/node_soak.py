#!/usr/bin/env python3
"""Soak of the mapping node (issue 20): the real mapping_node with its defaults, fed 40 Hz
1081-beam LaserScans of a changing hall in simulated time, faster than real time, for 30
simulated minutes (72,000 scans), with a subscriber on every layer and its updates.

It starts its own roscore (on --port, so it never meets another master), sets
/use_sim_time, starts `rosrun dynamic_occupancy_grid mapping_node` with no parameters, and
publishes per scan /clock, the robot's pose on /tf (map -> base_link; base_link -> laser
on /tf_static) and the scan, paced at --rate times real time. Every simulated minute it
samples the node's VmRSS and CPU time (/proc/PID/status, /proc/PID/stat) and the node's own
counts from /diagnostics ("scans dropped": received, integrated, dropped; "map": cells
allocated). At the end: scans published against received and integrated, drops, RSS from
the minute the map stopped growing to the end, CPU. Exit status 1 if a scan was lost or
dropped, or RSS grew more than --max-rss-growth percent after the map stopped growing.

The scene (metres): a 24 x 16 hall with a wall across it (a 1.2 m door in it that opens and
closes), two pillars, three people walking back and forth, and the robot driving a 48 m loop
at 0.5 m/s around the pillars and through the door's wall gap (always open). The laser is
a Hokuyo UTM-30LX-like fan: 1081 beams over 270 degrees, 30 m, 1 cm noise. Ranges are cast
analytically against boxes (numpy), so the publisher costs little next to the node. The
pace never catches up after a stall of the publisher (it reports the stalls).

Usage: node_soak.py [--minutes 30] [--rate 2] [--csv FILE] [--port 11611]
"""

import argparse
import csv
import math
import os
import signal
import subprocess
import sys
import threading
import time

import numpy as np

RATE_HZ = 40.0
BEAMS = 1081
ANGLE_MIN = -0.75 * math.pi
ANGLE_INCREMENT = 1.5 * math.pi / (BEAMS - 1)
RANGE_MIN = 0.05
RANGE_MAX = 30.0
NOISE_M = 0.01
LASER_OFFSET_X = 0.2  # base_link -> laser
START_S = 1000.0      # simulated time of the first scan

# Static boxes (x_min, y_min, x_max, y_max): outer walls, the cross wall at x 12 with a
# 1.5 m gap for the robot (y 3.5..5) and a 1.2 m door (y 11..12.2), two pillars.
WALLS = [
    (0.0, 0.0, 24.0, 0.2), (0.0, 15.8, 24.0, 16.0), (0.0, 0.0, 0.2, 16.0), (23.8, 0.0, 24.0, 16.0),
    (11.9, 0.2, 12.1, 3.5), (11.9, 5.0, 12.1, 11.0), (11.9, 12.2, 12.1, 15.8),
    (5.5, 7.5, 6.5, 8.5), (17.5, 7.5, 18.5, 8.5),
]
DOOR = (11.9, 11.0, 12.1, 12.2)
DOOR_P_CLOSE = 0.01  # per second while open
DOOR_P_OPEN = 0.02   # per second while shut
# People: 0.4 m squares walking back and forth between two points at a speed (m/s).
PEOPLE = [((3.0, 12.0), (9.0, 12.0), 0.8), ((15.0, 12.0), (21.0, 14.0), 1.0), ((8.0, 2.0), (8.0, 6.0), 0.6)]
PERSON_HALF = 0.2
# The robot's loop (closed): through the gap at x 12, around both pillars.
ROUTE = [(3.0, 4.25), (21.0, 4.25), (21.0, 10.0), (13.5, 10.0), (13.5, 4.25), (10.5, 4.25), (10.5, 10.0),
         (3.0, 10.0)]
SPEED = 0.5


class Hall(object):
    """The changing scene and the robot; ranges cast against boxes."""

    def __init__(self, seed):
        self.rng = np.random.default_rng(seed)
        self.door_shut = False
        self.angles = ANGLE_MIN + ANGLE_INCREMENT * np.arange(BEAMS)
        self.segments = []
        for a, b in zip(ROUTE, ROUTE[1:] + ROUTE[:1]):
            self.segments.append((a, b, math.hypot(b[0] - a[0], b[1] - a[1])))
        self.loop_m = sum(length for _, _, length in self.segments)

    def step_door(self):
        """One second of the door's two-state chain."""
        if self.rng.random() < (DOOR_P_OPEN if self.door_shut else DOOR_P_CLOSE):
            self.door_shut = not self.door_shut

    def robot_pose(self, t):
        """(x, y, yaw) after t seconds on the loop."""
        along = (SPEED * t) % self.loop_m
        for (ax, ay), (bx, by), length in self.segments:
            if along <= length:
                f = along / length
                return ax + f * (bx - ax), ay + f * (by - ay), math.atan2(by - ay, bx - ax)
            along -= length
        (ax, ay), _, _ = self.segments[0]
        return ax, ay, 0.0

    def boxes(self, t):
        boxes = list(WALLS)
        if self.door_shut:
            boxes.append(DOOR)
        for (ax, ay), (bx, by), speed in PEOPLE:
            length = math.hypot(bx - ax, by - ay)
            travelled = (speed * t) % (2.0 * length)
            f = (travelled if travelled < length else 2.0 * length - travelled) / length
            x, y = ax + f * (bx - ax), ay + f * (by - ay)
            boxes.append((x - PERSON_HALF, y - PERSON_HALF, x + PERSON_HALF, y + PERSON_HALF))
        return np.array(boxes)

    def ranges(self, t, laser_x, laser_y, laser_yaw):
        """The scan's ranges: the nearest box face along each beam (slab test), plus noise;
        inf beyond RANGE_MAX."""
        boxes = self.boxes(t)
        angles = laser_yaw + self.angles
        dx = np.cos(angles)[:, None]
        dy = np.sin(angles)[:, None]
        with np.errstate(divide='ignore', invalid='ignore'):
            tx1 = (boxes[None, :, 0] - laser_x) / dx
            tx2 = (boxes[None, :, 2] - laser_x) / dx
            ty1 = (boxes[None, :, 1] - laser_y) / dy
            ty2 = (boxes[None, :, 3] - laser_y) / dy
            enter = np.maximum(np.minimum(tx1, tx2), np.minimum(ty1, ty2))
            leave = np.minimum(np.maximum(tx1, tx2), np.maximum(ty1, ty2))
        hit = (enter > 0.0) & (leave >= enter)
        distance = np.where(hit, enter, np.inf).min(axis=1)
        distance = distance + self.rng.normal(0.0, NOISE_M, BEAMS)
        return np.where(distance < RANGE_MAX, np.maximum(distance, RANGE_MIN), np.inf).astype(np.float32)


def read_rss_mb(pid):
    with open('/proc/%d/status' % pid) as status:
        for line in status:
            if line.startswith('VmRSS:'):
                return int(line.split()[1]) * 1024 / 1e6
    return float('nan')


def read_cpu_s(pid):
    with open('/proc/%d/stat' % pid) as stat:
        fields = stat.read().rsplit(')', 1)[1].split()
    # utime and stime are fields 14 and 15 of stat(5), 12 and 13 after the command's ')'.
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def wait_for_master(timeout):
    import rosgraph
    deadline = time.monotonic() + timeout
    while not rosgraph.is_master_online():
        if time.monotonic() > deadline:
            raise RuntimeError('roscore did not come up within %.0f s' % timeout)
        time.sleep(0.1)


def stop(process):
    if process is not None and process.poll() is None:
        process.send_signal(signal.SIGINT)
        try:
            process.wait(timeout=20.0)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--minutes', type=float, default=30.0, help='simulated minutes (default 30)')
    parser.add_argument('--rate', type=float, default=2.0,
                        help='times real time (default 2; at 4 the node dropped late scans on a loaded 2-core machine)')
    parser.add_argument('--csv', help='write the per-minute samples here')
    parser.add_argument('--port', type=int, default=11611, help="the soak's own roscore port (default 11611)")
    parser.add_argument('--max-rss-growth', type=float, default=2.0,
                        help='bound on RSS growth after the map stopped growing, percent (default 2)')
    parser.add_argument('--seed', type=int, default=1)
    args = parser.parse_args()

    os.environ['ROS_MASTER_URI'] = 'http://localhost:%d' % args.port
    env = dict(os.environ, ROSCONSOLE_STDOUT_LINE_BUFFERED='1')
    log_dir = os.environ.get('ROS_LOG_DIR', '/tmp/node_soak_logs')
    env['ROS_LOG_DIR'] = log_dir
    roscore = subprocess.Popen(['roscore', '-p', str(args.port)], env=env, stdout=subprocess.DEVNULL,
                               stderr=subprocess.STDOUT)
    node = None
    try:
        wait_for_master(30.0)
        import rospy
        import tf2_ros
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import TransformStamped
        from rosgraph_msgs.msg import Clock
        from sensor_msgs.msg import LaserScan
        from tf2_msgs.msg import TFMessage

        rospy.set_param('/use_sim_time', True)
        node_log = open(os.path.join(log_dir, 'node_soak_mapping_node.log'), 'w')
        node = subprocess.Popen(['rosrun', 'dynamic_occupancy_grid', 'mapping_node', '__name:=dynamic_occupancy_grid'],
                                env=env, stdout=node_log, stderr=subprocess.STDOUT)
        rospy.init_node('node_soak', disable_signals=True)

        lock = threading.Lock()
        counts = {}   # the node's "scans dropped" values, latest
        cells = {'allocated': 0}
        layer_messages = {'count': 0, 'bytes': 0}

        def diagnostics(msg):
            with lock:
                for status in msg.status:
                    values = {kv.key: kv.value for kv in status.values}
                    if status.name.endswith('scans dropped'):
                        counts.clear()
                        counts.update(values)
                    elif status.name.endswith(': map') and 'cells allocated' in values:
                        cells['allocated'] = int(values['cells allocated'])

        def layer(msg):
            with lock:
                layer_messages['count'] += 1
                layer_messages['bytes'] += len(msg._buff)

        rospy.Subscriber('/diagnostics', DiagnosticArray, diagnostics, queue_size=100)
        for name in ('belief', 'predicted', 'stationary', 'p_occ_given_free', 'p_free_given_occ', 'static_map'):
            for topic in (name, name + '_updates'):
                rospy.Subscriber('/dynamic_occupancy_grid/' + topic, rospy.AnyMsg, layer, queue_size=10)
        clock = rospy.Publisher('/clock', Clock, queue_size=100)
        tf = rospy.Publisher('/tf', TFMessage, queue_size=1000)
        scans = rospy.Publisher('/scan', LaserScan, queue_size=1000)
        static_tf = tf2_ros.StaticTransformBroadcaster()

        def transform(stamp, parent, child, x, y, yaw):
            t = TransformStamped()
            t.header.stamp = stamp
            t.header.frame_id = parent
            t.child_frame_id = child
            t.transform.translation.x = x
            t.transform.translation.y = y
            t.transform.rotation.z = math.sin(yaw / 2.0)
            t.transform.rotation.w = math.cos(yaw / 2.0)
            return t

        clock.publish(Clock(clock=rospy.Time.from_sec(START_S)))
        static_tf.sendTransform(transform(rospy.Time.from_sec(START_S), 'base_link', 'laser', LASER_OFFSET_X, 0.0, 0.0))
        deadline = time.monotonic() + 60.0
        while scans.get_num_connections() == 0:
            if time.monotonic() > deadline or node.poll() is not None:
                raise RuntimeError('mapping_node never subscribed to /scan (see %s)' % node_log.name)
            time.sleep(0.05)
        time.sleep(2.0)  # the subscribers' connections to the layers settle

        hall = Hall(args.seed)
        total = int(round(args.minutes * 60.0 * RATE_HZ))
        per_minute = int(RATE_HZ * 60.0)
        scan = LaserScan()
        scan.header.frame_id = 'laser'
        scan.angle_min = ANGLE_MIN
        scan.angle_max = ANGLE_MIN + ANGLE_INCREMENT * (BEAMS - 1)
        scan.angle_increment = ANGLE_INCREMENT
        scan.scan_time = 1.0 / RATE_HZ
        scan.range_min = RANGE_MIN
        scan.range_max = RANGE_MAX
        rows = []
        header = ['sim_minute', 'scans_published', 'received', 'integrated', 'dropped', 'cells_allocated', 'rss_mb',
                  'cpu_percent', 'wall_s', 'layer_messages', 'loadavg_1min', 'publisher_stalls']
        print(' '.join('%s' % h for h in header), flush=True)
        start_wall = time.monotonic()
        schedule_origin = start_wall
        stalls = {'count': 0, 'longest_s': 0.0}
        last_wall = start_wall
        last_cpu = read_cpu_s(node.pid)
        first_rss = read_rss_mb(node.pid)

        def sample(minute, published):
            nonlocal last_wall, last_cpu
            now = time.monotonic()
            cpu = read_cpu_s(node.pid)
            with lock:
                c = dict(counts)
                allocated = cells['allocated']
                messages = layer_messages['count']
            dropped = sum(int(c.get(k, 0)) for k in ('dropped: no transform (tf)',
                                                     'dropped: invalid (stamp, shape, laser pose)',
                                                     'dropped: late (step already applied)'))
            with open('/proc/loadavg') as load:
                loadavg = float(load.read().split()[0])
            row = [minute, published, int(c.get('received', 0)), int(c.get('integrated', 0)), dropped, allocated,
                   round(read_rss_mb(node.pid), 2), round(100.0 * (cpu - last_cpu) / (now - last_wall), 1),
                   round(now - start_wall, 1), messages, loadavg, stalls['count']]
            last_wall, last_cpu = now, cpu
            rows.append(row)
            print(' '.join(str(v) for v in row), flush=True)

        for i in range(total):
            t = START_S + i / RATE_HZ
            # Paced at --rate; after a stall of this process the schedule moves on instead of
            # catching up, so simulated time never runs faster than --rate (a burst would
            # move /clock past scans the node has not read yet).
            delay = schedule_origin + i / (RATE_HZ * args.rate) - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            elif delay < -1.0 / (RATE_HZ * args.rate):
                schedule_origin -= delay
                stalls['count'] += 1
                stalls['longest_s'] = max(stalls['longest_s'], -delay)
            if i % int(RATE_HZ) == 0 and i > 0:
                hall.step_door()
            stamp = rospy.Time.from_sec(t)
            x, y, yaw = hall.robot_pose(t - START_S)
            clock.publish(Clock(clock=stamp))
            tf.publish(TFMessage(transforms=[transform(stamp, 'map', 'base_link', x, y, yaw)]))
            scan.header.stamp = stamp
            scan.ranges = hall.ranges(t - START_S, x + LASER_OFFSET_X * math.cos(yaw),
                                      y + LASER_OFFSET_X * math.sin(yaw), yaw).tolist()
            scans.publish(scan)
            if (i + 1) % per_minute == 0:
                sample((i + 1) // per_minute, i + 1)
            if node.poll() is not None:
                raise RuntimeError('mapping_node exited with %s (see %s)' % (node.returncode, node_log.name))
        publish_wall = time.monotonic() - start_wall
        # Let the node take in the last scans: move the clock on (the publish timer applies the
        # last step) until its diagnostics count every scan, or 30 s of wall time.
        t = START_S + total / RATE_HZ
        deadline = time.monotonic() + 30.0
        while time.monotonic() < deadline:
            t += 0.1
            clock.publish(Clock(clock=rospy.Time.from_sec(t)))
            time.sleep(0.025)
            with lock:
                received = int(counts.get('received', 0))
            if received >= total and t > START_S + total / RATE_HZ + 3.0:
                break
        sample(round(args.minutes), total)
        final = rows[-1]
        print('published %d scans in %.1f s of wall time (%.2fx real time)' % (total, publish_wall,
                                                                             total / RATE_HZ / publish_wall))
        print('publisher stalls (late by more than a scan period, schedule moved on): %d, longest %.3f s'
              % (stalls['count'], stalls['longest_s']))
        print('node: received %d, integrated %d, dropped %d; lost before the node (published - received): %d'
              % (final[2], final[3], final[4], total - final[2]))
        # The map stopped growing after the last minute in which cells were allocated.
        grown = 0
        for k in range(1, len(rows)):
            if rows[k][5] != rows[k - 1][5]:
                grown = k
        rss_start, rss_end = rows[grown][6], final[6]
        growth = 100.0 * (rss_end - rss_start) / rss_start
        cpu = [r[7] for r in rows[1:-1]]
        print('RSS: %.2f MB at start, %.2f MB when the map stopped growing (minute %s, %d cells), %.2f MB at the '
              'end (max %.2f): %+.2f MB, %+.2f %% (bound %.1f %%)'
              % (first_rss, rss_start, rows[grown][0], rows[grown][5], rss_end, max(r[6] for r in rows[grown:]),
                 rss_end - rss_start, growth, args.max_rss_growth))
        if cpu:
            print('CPU of the node: median %.1f %% of one core per minute sample (min %.1f, max %.1f)'
                  % (sorted(cpu)[len(cpu) // 2], min(cpu), max(cpu)))
        print('layer messages received: %d' % layer_messages['count'])
        if args.csv:
            with open(args.csv, 'w', newline='') as out:
                writer = csv.writer(out)
                writer.writerow(header)
                writer.writerows(rows)
        ok = final[2] == total and final[3] == total and final[4] == 0 and growth <= args.max_rss_growth
        print('verdict: %s' % ('PASS (no scan lost or dropped, RSS flat after the map stopped growing)' if ok else
                               'FAIL'))
        return 0 if ok else 1
    finally:
        stop(node)
        stop(roscore)


if __name__ == '__main__':
    sys.exit(main())
