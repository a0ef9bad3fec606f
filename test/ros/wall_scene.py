"""Shared helpers of the mapping node's rostests: one laser facing a straight wall, in
simulated time that the test drives itself.

The scene (map frame, metres): the laser at (LASER_X, LASER_Y), yaw 0, sees the wall
x = WALL_X with 81 beams over +-0.2 rad. With 0.1 m cells the wall is the cell column
[3.0, 3.1); the beams sweep the cells between laser and wall, and the cells behind the wall
are never observed. All check points are cell centres, far from cell borders.

Time: the .test files set /use_sim_time and the test publishes /clock (SimClock). Scans of a
time step are stamped well inside it (WallScene.feed_steps), so which step a scan belongs to
never depends on rounding. Waiting always advances the clock, so that the node's publish
timer keeps running while the test waits for a message or a condition.
"""

import errno
import fcntl
import functools
import math
import os
import queue
import signal
import subprocess
import threading
import time
import traceback
import unittest

import rosbag
import rospy
import tf2_ros
from geometry_msgs.msg import TransformStamped
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import LaserScan
from tf2_msgs.msg import TFMessage

import dynamic_occupancy_grid.srv as dog_srv

PKG = 'dynamic_occupancy_grid'

# Values the .test files give the node (they must agree).
RESOLUTION = 0.1
TIME_STEP = 0.5
MAX_SCAN_LATENCY = 0.2

START_TIME = 1000.0
LASER_FRAME = 'laser'
FIXED_FRAME = 'map'
LASER_X = 1.02
LASER_Y = 2.03
WALL_X = 3.05
ANGLE_MIN = -0.2
ANGLE_MAX = 0.2
ANGLE_INCREMENT = 0.005
BEAMS = 81
RANGE_MIN = 0.05
RANGE_MAX = 8.0

# Wall cells (hit by about ten beams each per scan), swept cells, never observed cells.
WALL_POINTS = [(WALL_X, y) for y in (1.85, 1.95, 2.05, 2.15, 2.25)]
FREE_POINTS = ([(x / 100.0, 2.05) for x in range(125, 286, 10)] +
               [(2.05, 1.95), (2.05, 2.15), (2.55, 1.85), (2.55, 2.25)])
BEHIND_POINTS = [(x, y) for x in (3.15, 3.35, 3.95) for y in (1.85, 2.05, 2.25)]
OUTSIDE_FAN_POINTS = [(1.05, 0.55), (2.05, 3.55), (0.35, 2.05)]
WALL_CELL = (30, 20)  # lattice cell of (WALL_X, 2.05) with origin (0, 0)

# Wall seconds; the sanitized run (test/sanitizers/run_sanitized.sh) scales it, its nodes
# being several times slower.
DEFAULT_TIMEOUT = 15.0 * float(os.environ.get('DOG_TEST_TIMEOUT_SCALE', '1'))
# Wall seconds for a node to start (subscribe, offer its services), scaled alike.
STARTUP_TIMEOUT = 30.0 * float(os.environ.get('DOG_TEST_TIMEOUT_SCALE', '1'))


def reported_set_up(set_up_class):
    """Use instead of @classmethod on a setUpClass: an error it raises reaches the JUnit file.
    rosunit writes an error raised in setUpClass as errors="1" with neither testcase nor
    message, so a CI log can say only that something failed. Decorated, the error is kept,
    tearDownClass is skipped (as unittest does after a raising setUpClass) and every test of
    the class fails with the traceback; unittest.SkipTest still skips the class."""
    @functools.wraps(set_up_class)
    def wrapper(cls):
        try:
            set_up_class(cls)
        except unittest.SkipTest:
            raise
        except Exception as exception:  # noqa: BLE001 (reported by every test below)
            error = 'setUpClass: %s\n%s' % (''.join(traceback.format_exception_only(exception)).strip(),
                                            traceback.format_exc())

            def fail(test):
                test.fail(error)
            cls.setUp = fail
            cls.tearDownClass = classmethod(lambda _: None)
    return classmethod(wrapper)


def wall_ranges():
    """Ranges of the 81 beams to the wall x = WALL_X."""
    return [(WALL_X - LASER_X) / math.cos(ANGLE_MIN + i * ANGLE_INCREMENT) for i in range(BEAMS)]


def make_scan(stamp, ranges=None, frame_id=LASER_FRAME, angle_min=ANGLE_MIN, angle_max=ANGLE_MAX,
              angle_increment=ANGLE_INCREMENT, range_min=RANGE_MIN, range_max=RANGE_MAX):
    """A LaserScan of the scene stamped `stamp` (s); the wall's ranges unless given."""
    scan = LaserScan()
    scan.header.stamp = rospy.Time.from_sec(stamp)
    scan.header.frame_id = frame_id
    scan.angle_min = angle_min
    scan.angle_max = angle_max
    scan.angle_increment = angle_increment
    scan.time_increment = 0.0
    scan.scan_time = 0.1
    scan.range_min = range_min
    scan.range_max = range_max
    scan.ranges = wall_ranges() if ranges is None else ranges
    return scan


def laser_transform(stamp, x=LASER_X, y=LASER_Y, yaw=0.0, roll=0.0, child=LASER_FRAME, parent=FIXED_FRAME):
    """The laser's pose in the fixed frame as a TransformStamped (rotation: yaw about z,
    then roll about the rotated x axis)."""
    transform = TransformStamped()
    transform.header.stamp = rospy.Time.from_sec(stamp)
    transform.header.frame_id = parent
    transform.child_frame_id = child
    transform.transform.translation.x = x
    transform.transform.translation.y = y
    cz, sz = math.cos(yaw / 2.0), math.sin(yaw / 2.0)
    cx, sx = math.cos(roll / 2.0), math.sin(roll / 2.0)
    rotation = transform.transform.rotation
    rotation.w, rotation.x, rotation.y, rotation.z = cz * cx, cz * sx, sz * sx, sz * cx
    return transform


# Bad-parameter nodes started at a time: dozens at once on two busy cores (or under the
# sanitizers) can take longer to load than any timeout; a few at a time cost the same CPU.
BAD_PARAMETER_NODES_AT_ONCE = 4


def assert_bad_parameters_stop_node(test, cases, node_prefix):
    """Starts mapping_node once per (name, arguments) of `cases`, a few at a time, and checks
    that each exits with 1 and names the parameter `name` in its output (`name` may also be a
    tuple of texts the output must all contain)."""
    for first in range(0, len(cases), BAD_PARAMETER_NODES_AT_ONCE):
        _check_bad_parameter_nodes(test, list(enumerate(cases))[first:first + BAD_PARAMETER_NODES_AT_ONCE],
                                   node_prefix)


def _check_bad_parameter_nodes(test, numbered_cases, node_prefix):
    processes = []
    for i, (name, argument) in numbered_cases:
        command = ['rosrun', PKG, 'mapping_node', '__name:=%s_%d' % (node_prefix, i)] + argument.split()
        processes.append((name, command, subprocess.Popen(
            command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, universal_newlines=True)))
    for name, command, process in processes:
        try:
            output, _ = process.communicate(timeout=60.0)
        except subprocess.TimeoutExpired:
            process.kill()
            output, _ = process.communicate()
            test.fail('%s did not exit: %s' % (' '.join(command), output))
        test.assertEqual(process.returncode, 1, '%s exited with %d:\n%s' % (' '.join(command), process.returncode,
                                                                          output))
        for text in (name,) if isinstance(name, str) else name:
            test.assertIn(text, output, '%s: the error does not name %s:\n%s' % (' '.join(command), text, output))


def node_startup_output(test, node_name, arguments, until, timeout=STARTUP_TIMEOUT):
    """Starts mapping_node as `node_name` with `arguments` (a list of rosrun arguments),
    reads its output (stdout and stderr, line-buffered) until a line contains `until`, stops
    it and returns all lines read; fails if it exits or `timeout` (wall s) passes first."""
    command = ['rosrun', PKG, 'mapping_node', '__name:=' + node_name] + list(arguments)
    env = dict(os.environ, ROSCONSOLE_STDOUT_LINE_BUFFERED='1')
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, universal_newlines=True,
                               env=env)
    lines = queue.Queue()

    def pump():
        for line in process.stdout:
            lines.put(line)
        lines.put(None)  # end of output

    reader = threading.Thread(target=pump, daemon=True)
    reader.start()
    output = []
    deadline = time.monotonic() + timeout
    try:
        while True:
            try:
                line = lines.get(timeout=max(0.0, deadline - time.monotonic()))
            except queue.Empty:
                test.fail('%s: no line with %r within %.0f s:\n%s' % (' '.join(command), until, timeout,
                                                                      ''.join(output)))
            if line is None:
                test.fail('%s exited before a line with %r:\n%s' % (' '.join(command), until, ''.join(output)))
            output.append(line)
            if until in line:
                return output
    finally:
        if process.poll() is None:
            process.send_signal(signal.SIGINT)
            try:
                process.wait(timeout=15.0)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()
        reader.join(timeout=5.0)


def grid_value(grid, x, y):
    """Value of the cell of nav_msgs/OccupancyGrid `grid` holding world point (x, y); None
    outside the grid."""
    info = grid.info
    if info.width == 0 or info.height == 0:
        return None
    i = int(math.floor((x - info.origin.position.x) / info.resolution))
    j = int(math.floor((y - info.origin.position.y) / info.resolution))
    if i < 0 or j < 0 or i >= info.width or j >= info.height:
        return None
    return grid.data[j * info.width + i]


def wall_problems(grid, occupied_above=65, free_below=25, check_behind=True):
    """What is wrong with `grid` as a map of the wall scene (empty list: nothing)."""
    problems = []
    for x, y in WALL_POINTS:
        value = grid_value(grid, x, y)
        if value is None or not value > occupied_above:
            problems.append('wall (%.2f, %.2f) = %s, want > %d' % (x, y, value, occupied_above))
    for x, y in FREE_POINTS:
        value = grid_value(grid, x, y)
        if value is None or not 0 <= value < free_below:
            problems.append('swept (%.2f, %.2f) = %s, want 0..%d' % (x, y, value, free_below - 1))
    if check_behind:
        for x, y in BEHIND_POINTS + OUTSIDE_FAN_POINTS:
            value = grid_value(grid, x, y)
            if value is not None and value != -1:
                problems.append('never observed (%.2f, %.2f) = %s, want -1' % (x, y, value))
    return problems


def same_geometry_problems(grid, reference):
    """Differences of frame, resolution, origin and size between two OccupancyGrids."""
    problems = []
    a, b = grid.info, reference.info
    if grid.header.frame_id != reference.header.frame_id:
        problems.append('frame %r != %r' % (grid.header.frame_id, reference.header.frame_id))
    if abs(a.resolution - b.resolution) > 1e-6:
        problems.append('resolution %r != %r' % (a.resolution, b.resolution))
    if (abs(a.origin.position.x - b.origin.position.x) > 1e-6 or
            abs(a.origin.position.y - b.origin.position.y) > 1e-6):
        problems.append('origin (%r, %r) != (%r, %r)' % (a.origin.position.x, a.origin.position.y,
                                                         b.origin.position.x, b.origin.position.y))
    if (a.width, a.height) != (b.width, b.height):
        problems.append('size %dx%d != %dx%d' % (a.width, a.height, b.width, b.height))
    if len(grid.data) != a.width * a.height:
        problems.append('%d values for %dx%d cells' % (len(grid.data), a.width, a.height))
    return problems


class SimClock(object):
    """Publishes /clock (latched); time moves only when the test says so."""

    def __init__(self, start=START_TIME):
        self._lock = threading.Lock()
        self._publisher = rospy.Publisher('/clock', Clock, queue_size=10, latch=True)
        self.now = start
        self.set(start)

    def set(self, t):
        with self._lock:
            self.now = t
            self._publisher.publish(Clock(clock=rospy.Time.from_sec(t)))

    def advance(self, dt):
        self.set(self.now + dt)


class TopicRecorder(object):
    """Keeps every message of a topic; waits for one that satisfies a predicate."""

    def __init__(self, topic, msg_type):
        self.topic = topic
        self.messages = []
        self._condition = threading.Condition()
        self._subscriber = rospy.Subscriber(topic, msg_type, self._callback, queue_size=1000)

    def _callback(self, msg):
        with self._condition:
            self.messages.append(msg)
            self._condition.notify_all()

    def snapshot(self):
        with self._condition:
            return list(self.messages)

    def latest(self):
        with self._condition:
            return self.messages[-1] if self.messages else None

    def wait_for(self, predicate=lambda msg: True, timeout=DEFAULT_TIMEOUT, clock=None, tick=0.02):
        """The newest message satisfying `predicate`, waiting up to `timeout` wall seconds
        (advancing `clock` by `tick` every 20 ms meanwhile); None if none came."""
        deadline = time.time() + timeout
        with self._condition:
            while True:
                for msg in reversed(self.messages):
                    if predicate(msg):
                        return msg
                if time.time() >= deadline or rospy.is_shutdown():
                    return None
                if clock is not None:
                    self._condition.release()
                    try:
                        clock.advance(tick)
                    finally:
                        self._condition.acquire()
                self._condition.wait(0.02)

    def unregister(self):
        """Stops recording. rospy shares one connection among the subscribers of a topic in
        a process: a topic is only subscribed anew (the node sees a new subscriber) once
        every earlier subscriber to it is unregistered."""
        if self._subscriber is not None:
            self._subscriber.unregister()
            self._subscriber = None


class WallScene(object):
    """The laser, its transform, its scans and the clock, for a node named `node`."""

    def __init__(self, node='/mapper', start=START_TIME):
        self.node = node.rstrip('/')
        self.clock = SimClock(start)
        self.scan_publisher = rospy.Publisher('/scan', LaserScan, queue_size=1000)
        self._tf_broadcaster = None
        self._static_transforms = {}
        self.origin = None       # stamp of step 0 of the current sequence (the first scan)
        self.next_step = 0       # first step feed_steps may use
        self.last_stamp = None   # newest scan stamp published
        self.last_step = None    # step of the newest scan of the sequence
        self.step_offset = 0     # the node's number of step 0 of the sequence
        self._services = {}
        # Scans published, by frame: those whose transform the scene has broadcast must have
        # gone through the node (mapped or dropped) before the clock moves on (sync).
        self._published_by_frame = {}
        self._processed_base = None  # the node's processed count before the first scan
        self._processed = 0          # the node's processed count, as last read

    # --- tf and the node ---------------------------------------------------------------
    def broadcast_tf(self, **pose):
        """Publishes the laser's pose (keyword arguments of laser_transform) on /tf_static,
        with every transform broadcast before (the latched message holds them all)."""
        if self._tf_broadcaster is None:
            self._tf_broadcaster = tf2_ros.StaticTransformBroadcaster()
        transform = laser_transform(self.clock.now, **pose)
        self._static_transforms[transform.child_frame_id] = transform
        self._tf_broadcaster.sendTransform(list(self._static_transforms.values()))

    def wait_for_node(self, timeout=STARTUP_TIMEOUT):
        """Waits until the node subscribes to the scans and offers its services."""
        deadline = time.time() + timeout
        while self.scan_publisher.get_num_connections() == 0:
            if time.time() > deadline:
                raise AssertionError('%s never subscribed to /scan' % self.node)
            threading.Event().wait(0.05)
        rospy.wait_for_service(self.node + '/get_cell', max(1.0, deadline - time.time()))
        self._processed_base = self._processed = self._node_processed()

    def service(self, name, srv_type=None):
        if name not in self._services:
            if srv_type is None:
                srv_type = {
                    'get_cell': dog_srv.GetCell, 'predict_map': dog_srv.PredictMap,
                    'save_model': dog_srv.SaveModel, 'load_model': dog_srv.LoadModel,
                    'export_layers': dog_srv.ExportLayers, 'run_offline_em': dog_srv.RunOfflineEm,
                    'get_status': dog_srv.GetStatus,
                }[name]
            full_name = self.node + '/' + name
            rospy.wait_for_service(full_name, 10.0)
            self._services[name] = rospy.ServiceProxy(full_name, srv_type)
        return self._services[name]

    def get_cell(self, x, y):
        return self.service('get_cell')(x=x, y=y)

    # --- scans ----------------------------------------------------------------------------
    @staticmethod
    def make_scan(stamp, **fields):
        return make_scan(stamp, **fields)

    def publish(self, scan):
        """Publishes a scan, the clock first moved up to its stamp (never back, and only once
        the node has taken every scan before it: sync)."""
        stamp = scan.header.stamp.to_sec()
        if stamp > self.clock.now:
            self.sync()
            self.clock.set(stamp)
        self.scan_publisher.publish(scan)
        frame = scan.header.frame_id
        self._published_by_frame[frame] = self._published_by_frame.get(frame, 0) + 1

    def rebase_after_untracked(self):
        """After scans published past publish() (a frame without a transform, which the tf
        filter drops when its queue overflows): the node's processed count then includes those
        drops, and sync would count them for scans it should still wait for (a later step's
        scan then dropped as late, seen under the sanitizers). Re-reads the count as the
        base of the scans publish() counted so far."""
        self.sync()
        tracked = sum(count for frame, count in self._published_by_frame.items() if frame in self._static_transforms)
        self._processed = self._node_processed()
        self._processed_base = self._processed - tracked

    def _node_processed(self):
        status = self.service('get_status')()
        return (status.scans_integrated + status.scans_dropped_tf + status.scans_dropped_invalid +
                status.scans_dropped_late + status.scans_refused_by_memory)

    def sync(self, timeout=DEFAULT_TIMEOUT):
        """Waits (wall time, the clock standing still) until the node has mapped or dropped
        every scan published whose frame's transform the scene has broadcast. The scans and
        /clock reach the node on separate connections, and a scan goes through its queue
        twice (the tf filter's subscriber, then the filter's callback): a clock moved past a
        step's end + max_scan_latency right after its scans were published can close that
        step before its last scan is taken, which the node then drops as late."""
        if self._processed_base is None:
            return
        expected = self._processed_base + sum(count for frame, count in self._published_by_frame.items()
                                              if frame in self._static_transforms)
        if self._processed >= expected:
            return
        deadline = time.time() + timeout
        event = threading.Event()
        while True:
            self._processed = self._node_processed()
            if self._processed >= expected:
                return
            if time.time() >= deadline or rospy.is_shutdown():
                raise AssertionError('%s took %d of %d scans published within %.0f s: %s' % (
                    self.node, self._processed - self._processed_base, expected - self._processed_base, timeout,
                    self.service('get_status')()))
            event.wait(0.005)

    def start_sequence(self, base):
        """Scans restart at `base` (a new map, or time jumping back): the next scan published
        by feed_steps is stamped `base` and becomes step 0 of the node's clock."""
        self.origin = base
        self.next_step = 0
        self.last_step = None

    def step_stamps(self, step):
        """Two stamps well inside `step` of the current sequence."""
        start = self.origin + step * TIME_STEP
        return [start + 0.3 * TIME_STEP, start + 0.7 * TIME_STEP]

    def feed_steps(self, count, **scan_fields):
        """Publishes scans (the wall's, unless `scan_fields` say otherwise) in `count` steps
        after the last one published and not before the clock. Returns the last step."""
        if self.origin is None:
            self.start_sequence(self.clock.now)
        stamps = []
        if self.last_step is None:
            # The first scan of a sequence starts step 0 (the node's clock starts at it).
            stamps.append(self.origin)
            first = 0
        else:
            # Never a step the node may already have closed (the clock went past it).
            first = max(self.next_step, int(math.floor((self.clock.now - self.origin) / TIME_STEP)) + 1)
        for step in range(first, first + count):
            stamps.extend(self.step_stamps(step))
        for stamp in stamps:
            self.publish(self.make_scan(stamp, **scan_fields))
        self.last_step = first + count - 1
        self.next_step = self.last_step + 1
        self.last_stamp = stamps[-1]
        return self.last_step

    def first_scan(self, timeout=DEFAULT_TIMEOUT, **scan_fields):
        """Starts a sequence with one scan and waits until the node has applied it (its step
        0, closed by the publish timer). Until then the node may lack the transform: scans
        waiting for it in the tf2 MessageFilter can be released after later ones, so a
        burst of scans published before this handshake could reach the node out of order.
        Returns the GetCell response of the wall cell."""
        if self.origin is None or self.last_step is not None:
            self.start_sequence(max(self.clock.now, self.last_stamp or 0.0))
        before = self.get_cell(*WALL_POINTS[2])
        previous = before.last_observed_step if before.observed else -1
        self.publish(self.make_scan(self.origin, **scan_fields))
        self.last_step = 0
        self.next_step = 1
        self.last_stamp = self.origin
        self.finish()
        response = self.wait_for_cell_step(previous + 1, timeout=timeout, relative=False)
        if response is None or not response.observed or response.last_observed_step <= previous:
            raise AssertionError('the node did not map the first scan of the sequence at %.3f: %s'
                                 % (self.origin, response))
        self.step_offset = response.last_observed_step
        return response

    def step_end(self, step):
        """Stamp of the maps after `step` was applied (the node stamps them with the end of
        the last applied step)."""
        return self.origin + (step + 1) * TIME_STEP

    def finish(self):
        """Moves the clock past the last step's end + max_scan_latency, so that the node's
        publish timer applies it without waiting for a later scan."""
        end = self.step_end(self.last_step) + MAX_SCAN_LATENCY + 0.05
        if end > self.clock.now:
            self.sync()
            self.clock.set(end)

    def wait_until(self, predicate, timeout=DEFAULT_TIMEOUT, tick=0.02):
        """Polls `predicate` every 20 ms wall time, advancing the clock by `tick` each time;
        returns its last value (falsy on time out)."""
        deadline = time.time() + timeout
        event = threading.Event()
        while True:
            value = predicate()
            if value or time.time() >= deadline or rospy.is_shutdown():
                return value
            self.clock.advance(tick)
            event.wait(0.02)

    def wait_for_cell_step(self, step, point=None, timeout=DEFAULT_TIMEOUT, relative=True):
        """Waits until the node has applied `step` (of this sequence; with relative=False
        the node's own step number) to the cell at `point` (default: a wall cell); returns
        the last GetCell response."""
        x, y = point or WALL_POINTS[2]
        node_step = step + self.step_offset if relative else step
        result = {}

        def applied():
            response = self.get_cell(x, y)
            result['response'] = response
            return response.observed and response.last_observed_step >= node_step

        self.wait_until(applied, timeout)
        return result.get('response')


# --- files and requests that block ----------------------------------------------------------
# fcntl's lease commands (Linux; Python's fcntl module has them from 3.12).
F_SETLEASE = getattr(fcntl, 'F_SETLEASE', 1024)
F_GETLEASE = getattr(fcntl, 'F_GETLEASE', 1025)


def write_bag_without_scans(path):
    """A valid bag with one message on /other and no LaserScan topic."""
    with rosbag.Bag(path, 'w') as bag:
        bag.write('/other', TFMessage(), rospy.Time(1))


class LeasedFile(object):
    """A write lease (fcntl F_SETLEASE, F_WRLCK) held by this process on the file `path` it
    owns: another process's open() of the file waits until the lease is released, or
    /proc/sys/fs/lease-break-time (45 s) has passed -- a real "blocked file" (Samba holds such
    leases), one this test can release when it likes. Use as a context manager, in the main
    thread (it handles SIGIO, the kernel's notice that an open is waiting)."""

    def __init__(self, path):
        self.path = path
        self._fd = None
        self._previous_handler = None

    def __enter__(self):
        # The kernel tells the holder with SIGIO, whose default action ends the process.
        self._previous_handler = signal.signal(signal.SIGIO, lambda signum, frame: None)
        self._fd = os.open(self.path, os.O_RDONLY)
        try:
            fcntl.fcntl(self._fd, F_SETLEASE, fcntl.F_WRLCK)
        except OSError:
            self.release()
            raise
        return self

    def opener_waits(self):
        """True while another process's open() for reading waits for the lease: the kernel
        asks for the lease to drop to a read lease, and F_GETLEASE says F_RDLCK (F_UNLCK once
        the kernel gave up waiting for it, after lease-break-time)."""
        return self._fd is not None and fcntl.fcntl(self._fd, F_GETLEASE) == fcntl.F_RDLCK

    def release(self):
        if self._fd is not None:
            try:
                fcntl.fcntl(self._fd, F_SETLEASE, fcntl.F_UNLCK)
            except OSError as error:
                if error.errno != errno.EBADF:
                    raise
            os.close(self._fd)
            self._fd = None
        if self._previous_handler is not None:
            signal.signal(signal.SIGIO, self._previous_handler)
            self._previous_handler = None

    def __exit__(self, *exc):
        self.release()
        return False


def assert_mapping_goes_on_during_stuck_request(test, scene, belief, tmp_dir, steps=3):
    """Holds a run_offline_em request stuck in the node -- rosbag's open() of the bag waits
    for a lease this test holds (LeasedFile) -- and checks that meanwhile `steps` new steps
    of scans are mapped and published on `belief` (a TopicRecorder of the node's ~belief)
    one after the other, and that get_cell still answers; then releases the lease and
    checks that the request ends with its own answer. With one spinner for scans and
    services, no scan can be mapped while a request is being served."""
    bag = os.path.join(tmp_dir, 'held_by_another_process.bag')
    write_bag_without_scans(bag)
    answered = threading.Event()
    result = {}

    def request():
        try:
            result['response'] = scene.service('run_offline_em')(bag_path=bag)
        except Exception as error:  # noqa: BLE001 - reported by the test below
            result['error'] = error
        answered.set()

    with LeasedFile(bag) as lease:
        caller = threading.Thread(target=request, daemon=True)
        caller.start()
        # The request is in the node's open() of the bag once the lease holder is told.
        deadline = time.monotonic() + DEFAULT_TIMEOUT
        while not lease.opener_waits() and not answered.is_set() and time.monotonic() < deadline:
            answered.wait(0.02)
        test.assertFalse(answered.is_set(), 'run_offline_em returned without opening the bag: %s' % result)
        test.assertTrue(lease.opener_waits(), 'the node never opened the bag')
        for _ in range(steps):
            last = scene.feed_steps(1)
            scene.finish()
            stamp = scene.step_end(last)
            grid = belief.wait_for(lambda msg: abs(msg.header.stamp.to_sec() - stamp) < 1e-3 and msg.info.width > 0,
                                   clock=scene.clock)
            test.assertIsNotNone(grid, 'step %d was not mapped and published while run_offline_em was stuck in '
                                       'open() (%s)' % (last, 'answered meanwhile' if answered.is_set() else 'still stuck'))
            test.assertFalse(answered.is_set(), 'the request was answered before the lease was released: %s' % result)
        cell = scene.get_cell(*WALL_POINTS[2])
        test.assertTrue(cell.observed)
        test.assertEqual(cell.last_observed_step, last + scene.step_offset, 'get_cell during the stuck request')
        test.assertFalse(answered.is_set())
        test.assertTrue(lease.opener_waits(), 'the node stopped waiting for the bag before the lease was released')
    # Released: the open goes on, and the request gets its answer (the bag has no scans).
    test.assertTrue(answered.wait(DEFAULT_TIMEOUT), 'run_offline_em did not answer once the bag was released')
    caller.join(1.0)
    test.assertNotIn('error', result)
    response = result['response']
    test.assertFalse(response.success, response.message)
    test.assertIn(bag, response.message)
    test.assertIn('no messages on topic', response.message)


class NodeProcess(object):
    """mapping_node started by a test (rosrun) as `name` with `arguments`; its output lines
    are collected (stdout and stderr) while it runs."""

    def __init__(self, name, arguments):
        self.name = name
        self.command = ['rosrun', PKG, 'mapping_node', '__name:=' + name] + list(arguments)
        env = dict(os.environ, ROSCONSOLE_STDOUT_LINE_BUFFERED='1')
        self.process = subprocess.Popen(self.command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                        universal_newlines=True, env=env)
        self._lines = []
        self._condition = threading.Condition()
        self._reader = threading.Thread(target=self._pump, daemon=True)
        self._reader.start()

    def _pump(self):
        for line in self.process.stdout:
            with self._condition:
                self._lines.append(line)
                self._condition.notify_all()

    def output(self):
        with self._condition:
            return ''.join(self._lines)

    def wait_for_line(self, text, timeout=STARTUP_TIMEOUT):
        """True once a line holds `text`; False if the node exits or `timeout` passes first."""
        deadline = time.monotonic() + timeout
        with self._condition:
            while not any(text in line for line in self._lines):
                left = deadline - time.monotonic()
                if left <= 0 or self.process.poll() is not None:
                    return any(text in line for line in self._lines)
                self._condition.wait(min(left, 0.1))
            return True

    def stop(self):
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
            try:
                self.process.wait(timeout=15.0)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        self._reader.join(timeout=5.0)
