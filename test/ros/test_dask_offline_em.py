#!/usr/bin/env python3
"""Sharded offline EM on Dask (sharded_em, scripts/dask_offline_em.py) against offline_em.

The model file the sharded run writes must be offline_em's for the same bags, byte for byte:
on the package's two real recordings (each bag given more than once: one timeline), on a
patrol simulated as several bags, with the sensor model learned in rounds over the blocks,
with the MRF (E-steps per block, the joint M-step over all cells),
on bags whose stamps fall on step borders so that a bag must be extracted again (plan.redo),
and with one of the two workers killed while it runs EM tasks. Also: the errors of bad
options, a missing plan and a corrupt shard.
"""

import math
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
import unittest

import rosbag
import rospkg
import rospy
import rostest
from sensor_msgs.msg import LaserScan

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from test_bag_tools import NEATO_ARGS, NEATO_BAG, STATIONARY_ARGS, STATIONARY_BAG, executable  # noqa: E402
import wall_scene  # noqa: E402

PKG = 'dynamic_occupancy_grid'
PACKAGE_DIR = rospkg.RosPack().get_path(PKG)
sys.path.insert(0, os.path.join(PACKAGE_DIR, 'scripts'))
import dask_offline_em  # noqa: E402

TIMEOUT_S = 300


def offline_em(bags, out, options):
    subprocess.run([executable('offline_em')] + bags + ['--out', out] + options, check=True, capture_output=True,
                   timeout=TIMEOUT_S)
    with open(out, 'rb') as model:
        return model.read()


def write_scan_bag(path, stamps):
    """A bag of LaserScans in frame 'laser' at `stamps` ((sec, nsec) pairs): 36 beams, a wall
    at 3 m with a door (beams 10-13) that is open in every third scan."""
    with rosbag.Bag(path, 'w') as bag:
        for k, (sec, nsec) in enumerate(stamps):
            scan = LaserScan()
            scan.header.stamp = rospy.Time(sec, nsec)
            scan.header.frame_id = 'laser'
            scan.angle_min = -math.pi / 2
            scan.angle_increment = math.pi / 36
            scan.angle_max = scan.angle_min + 35 * scan.angle_increment
            scan.range_min = 0.1
            scan.range_max = 10.0
            scan.ranges = [5.0 if 10 <= i <= 13 and k % 3 == 0 else 3.0 / max(0.3, math.cos(scan.angle_min + i *
                                                                                         scan.angle_increment))
                           for i in range(36)]
            bag.write('/scan', scan, scan.header.stamp)


class DaskOfflineEmTest(unittest.TestCase):

    @wall_scene.reported_set_up
    def setUpClass(cls):
        from distributed import Client, LocalCluster
        cls.tmp = tempfile.mkdtemp(prefix='dog_dask_test_')
        cls.sharded_em = executable('sharded_em')
        cls.cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None)
        cls.client = Client(cls.cluster)
        # A patrol of the office simulated as three bags (three runs of the same world).
        cls.patrol = []
        for seed in (1, 2, 3):
            path = os.path.join(cls.tmp, 'patrol_%d.bag' % seed)
            subprocess.run([executable('simulate'), '--scenario', 'patrol_office', '--steps', '80', '--seed',
                            str(seed), '--out', path], check=True, capture_output=True, timeout=TIMEOUT_S)
            cls.patrol.append(path)

    @classmethod
    def tearDownClass(cls):
        cls.client.close()
        cls.cluster.close()
        shutil.rmtree(cls.tmp, ignore_errors=True)

    def sharded(self, name, bags, options, on_phase=dask_offline_em.Phases()):
        work = os.path.join(self.tmp, name)
        out = os.path.join(self.tmp, name + '.dogm')
        lines = []
        dask_offline_em.sharded_offline_em(self.client, bags, out, work, options, self.sharded_em,
                                           on_phase=on_phase, log=lines.append)
        with open(out, 'rb') as model:
            return model.read(), lines

    def assert_same_model(self, name, bags, options, block_cells=None, on_phase=dask_offline_em.Phases()):
        single = offline_em(bags, os.path.join(self.tmp, name + '_single.dogm'), options)
        blocks = ['--block-cells', str(block_cells)] if block_cells else []
        sharded, lines = self.sharded(name, bags, options + blocks, on_phase)
        self.assertGreater(len(single), 20403)  # cells, not only the header
        self.assertTrue(sharded == single, '%s: the sharded model differs from offline_em\'s (%d against %d bytes)'
                        % (name, len(sharded), len(single)))
        return lines

    def test_neato_bag_three_times(self):
        lines = self.assert_same_model('neato', [NEATO_BAG] * 3, NEATO_ARGS, block_cells=128)
        self.assertTrue(any(line.startswith('plan: 3 bags') for line in lines), lines)
        self.assertGreaterEqual(sum(line.startswith('block_') for line in lines), 4, lines)

    def test_stationary_bag_twice(self):
        self.assert_same_model('stationary', [STATIONARY_BAG] * 2, STATIONARY_ARGS)

    def test_simulated_patrol_in_three_bags(self):
        # A smaller block, MAP EM options and the cell_em learner, as a user may set them.
        self.assert_same_model('patrol', self.patrol, ['--em-prior-weight', '5', '--em-iterations', '40', '--learner',
                                                       'cell_em'], block_cells=256)

    def test_sensor_model_learned_in_rounds_over_blocks(self):
        # The emission M-step between rounds adds the blocks' exact sums (core::FixedPointSum).
        lines = self.assert_same_model('sensor', [NEATO_BAG] * 2, NEATO_ARGS + ['--em-learn-sensor-model'],
                                       block_cells=128)
        self.assertGreaterEqual(sum(line.startswith('continue: round') for line in lines), 2, lines)
        self.assertTrue(any(line.startswith('done: ') for line in lines), lines)
        self.assert_same_model('sensor_patrol', self.patrol, ['--em-learn-sensor-model', '--p-hit-given-occ', '0.6',
                                                              '--p-hit-given-free', '0.3'], block_cells=256)

    def test_mrf_iterations_over_blocks(self):
        # The MRF couples neighbouring cells across blocks: the blocks' E-steps, then the
        # joint M-step over all cells in offline_em's cell order, every iteration.
        # Three iterations (of the 20 it takes to converge): the test is that each matches
        # offline_em's, not convergence, and each costs a round of block tasks.
        lines = self.assert_same_model('mrf', [NEATO_BAG] * 2,
                                       NEATO_ARGS + ['--mrf-temperature', '50', '--em-iterations', '3'], block_cells=64)
        self.assertGreaterEqual(sum(line.startswith('continue: iteration') for line in lines), 2, lines)
        self.assertTrue(any(line.startswith('done: ') for line in lines), lines)
        self.assert_same_model('mrf_patrol', self.patrol, ['--mrf-temperature', '20', '--em-iterations', '3'],
                               block_cells=128)

    def test_bag_whose_stamps_round_differently_is_extracted_again(self):
        # Time step 0.1 s: the first bag fills steps 0..36, so the second starts at step 37.
        # The second's scan 0.0999999 s after its first falls in step 1 counted from its own
        # start, but in step 37 (with its first) on the timeline: the clock anchored at step
        # 37 rounds differently.
        first = os.path.join(self.tmp, 'border_0.bag')
        second = os.path.join(self.tmp, 'border_1.bag')
        write_scan_bag(first, [(1000000000, 50000000)] + [(1000000000, 80000000 + 100000000 * i) for i in range(1, 10)]
                       + [(1000000003, 80000000 + 100000000 * i) for i in range(7)])
        write_scan_bag(second, [(1000000000, 300000000), (1000000000, 399999900), (1000000000, 450000000),
                                (1000000000, 700000000), (1000000001, 200000000)])
        options = ['--laser-pose', '0,0,0', '--time-step', '0.1', '--resolution', '0.1']
        lines = self.assert_same_model('border', [first, second], options)
        self.assertIn('bag 1: extracted again with --anchor-step 37', lines)

    def test_worker_killed_while_running_em_tasks(self):
        killed = {}

        def kill_a_busy_worker(phase, client, futures):
            if phase != 'em' or killed:
                return
            deadline = time.time() + 60.0
            while time.time() < deadline:
                busy = [(worker, keys) for worker, keys in client.processing().items() if keys]
                if busy:
                    break
                threading.Event().wait(0.005)
            self.assertTrue(busy, 'no worker had an EM task to lose')
            worker, keys = busy[0]
            pid = client.run(os.getpid, workers=[worker])[worker]
            os.kill(pid, signal.SIGKILL)
            killed[worker] = list(keys)

        # Many small blocks: EM tasks are still queued and running when the worker dies.
        self.assert_same_model('killed', self.patrol, [], block_cells=64, on_phase=kill_a_busy_worker)
        self.assertEqual(len(killed), 1)
        worker, keys = next(iter(killed.items()))
        self.assertTrue(keys, killed)  # it held EM tasks when it died
        self.assertNotIn(worker, self.client.scheduler_info()['workers'])  # and it is gone (its nanny started another)

    def test_work_directory_of_another_run_is_reused_safely(self):
        # Older shards and parts (other bags, other blocks) in the work directory are not read.
        work = os.path.join(self.tmp, 'reused')
        dask_offline_em.sharded_offline_em(self.client, [STATIONARY_BAG] * 2, os.path.join(self.tmp, 'first.dogm'),
                                           work, STATIONARY_ARGS + ['--block-cells', '64'], self.sharded_em,
                                           log=lambda line: None)
        out = os.path.join(self.tmp, 'reused.dogm')
        dask_offline_em.sharded_offline_em(self.client, [NEATO_BAG] * 2, out, work,
                                           NEATO_ARGS + ['--block-cells', '64'], self.sharded_em, log=lambda line: None)
        with open(out, 'rb') as model:
            self.assertTrue(model.read() == offline_em([NEATO_BAG] * 2, out + '.single', NEATO_ARGS))
        # A block whose part is missing fails the assembly, naming it.
        with open(os.path.join(work, 'bags', '0', 'meta')) as meta:
            block = next(line.split()[1] for line in meta if line.startswith('block '))
        os.remove(os.path.join(work, 'parts', block + '.dogm'))
        result = subprocess.run([self.sharded_em, 'assemble', '--work', work, '--out', out, '--block-cells', '64'] +
                                NEATO_ARGS, capture_output=True, text=True)
        self.assertEqual(result.returncode, 1)
        self.assertIn('no part of ' + block, result.stderr)

    def test_shard_a_bag_does_not_list_is_not_read(self):
        # The steps by hand: the second bag is the Neato's first 8 s only, so it sees fewer
        # blocks than the first; a stale shard planted in its directory for a block only the
        # first bag saw must change nothing.
        options = NEATO_ARGS + ['--block-cells', '64']
        models = []
        for name in ('clean', 'planted'):
            work = os.path.join(self.tmp, 'listed_' + name)
            run = lambda *args: subprocess.run([self.sharded_em] + list(args) + ['--work', work] + options,
                                               capture_output=True, text=True, check=True, timeout=TIMEOUT_S)
            run('extract', NEATO_BAG, '--index', '0')
            with rosbag.Bag(NEATO_BAG) as bag:
                start = bag.get_start_time()
            run('extract', NEATO_BAG, '--index', '1', '--end-time', str(start + 8.0))
            blocks = []
            for index in (0, 1):
                with open(os.path.join(work, 'bags', str(index), 'meta')) as meta:
                    blocks.append({line.split()[1] for line in meta if line.startswith('block ')})
            only_first = sorted(blocks[0] - blocks[1])
            self.assertTrue(only_first, blocks)
            if name == 'planted':
                shutil.copy(os.path.join(work, 'bags', '0', only_first[0] + '.obs'),
                            os.path.join(work, 'bags', '1', only_first[0] + '.obs'))
            run('plan', '--bags', '2')
            for block in sorted(blocks[0] | blocks[1]):
                run('em', '--block', block)
            run('assemble', '--out', os.path.join(work, 'model.dogm'))
            with open(os.path.join(work, 'model.dogm'), 'rb') as model:
                models.append(model.read())
        self.assertTrue(models[0] == models[1])

    def test_errors(self):
        work = os.path.join(self.tmp, 'errors')
        os.makedirs(work)
        run = lambda *args: subprocess.run([self.sharded_em] + list(args), capture_output=True, text=True)
        result = run('plan', '--work', work, '--bags', '1')
        self.assertEqual(result.returncode, 1)
        self.assertIn('shard meta (extracted?)', result.stderr)
        for bad in (['check', '--mrf-temperature', '-1'], ['check', '--block-cells', '100'],
                    ['check', '--block-cells', '4'], ['frobnicate'], ['reduce', '--round', '0'],
                    ['em', '--block', 'block_0_0', '--em-learn-sensor-model'],
                    ['em', '--block', 'block_0_0', '--round', '0'], ['mrf-step', '--iteration', '0'],
                    ['em', '--block', 'block_0_0', '--mrf-temperature', '5']):
            result = run(bad[0], '--work', work, *bad[1:])
            self.assertEqual(result.returncode, 2, bad)
            self.assertIn('sharded_em:', result.stderr)
        # The driver refuses them before any task runs.
        driver = subprocess.run([sys.executable, os.path.join(PACKAGE_DIR, 'scripts', 'dask_offline_em.py'),
                                 NEATO_BAG, '--out', os.path.join(work, 'm.dogm'), '--sharded-em', self.sharded_em,
                                 '--', '--mrf-temperature', '50', '--em-learn-sensor-model'], capture_output=True,
                                text=True, timeout=TIMEOUT_S)
        self.assertEqual(driver.returncode, 2)
        self.assertIn('learn_sensor_model does not combine with mrf_temperature', driver.stderr)
        self.assertFalse(os.path.exists(os.path.join(work, 'm.dogm')))
        # A valid shard that is not the one the bag's meta lists (another extraction's) is refused.
        self.sharded('swapped', [NEATO_BAG], NEATO_ARGS + ['--block-cells', '128'])
        swapped = os.path.join(self.tmp, 'swapped')
        names = sorted(name for name in os.listdir(os.path.join(swapped, 'bags', '0')) if name.endswith('.obs'))
        shutil.copy(os.path.join(swapped, 'bags', '0', names[0]), os.path.join(swapped, 'bags', '0', names[1]))
        result = run('em', '--work', swapped, '--block', names[1][:-4], '--block-cells', '128', *NEATO_ARGS)
        self.assertEqual(result.returncode, 1)
        self.assertIn('not the shard its bag\'s meta lists', result.stderr)
        # Other offline EM options than the plan's are refused.
        result = run('em', '--work', swapped, '--block', names[0][:-4], '--block-cells', '128', '--em-iterations', '7',
                     *NEATO_ARGS)
        self.assertEqual(result.returncode, 1)
        self.assertIn('planned with other offline EM options', result.stderr)
        # So is another mixed-step probability (the model file, whose header the mapping
        # configuration's fingerprint is made of, does not hold it).
        result = run('em', '--work', swapped, '--block', names[0][:-4], '--block-cells', '128',
                     '--mixed-step-probability', '0.01', *NEATO_ARGS)
        self.assertEqual(result.returncode, 1)
        self.assertIn('planned with another mapping configuration', result.stderr)
        # A corrupt shard is named, and no part is written.
        self.sharded('corrupt', [NEATO_BAG], NEATO_ARGS)
        shard_dir = os.path.join(self.tmp, 'corrupt', 'bags', '0')
        shard = sorted(name for name in os.listdir(shard_dir) if name.endswith('.obs'))[0]
        with open(os.path.join(shard_dir, shard), 'r+b') as f:
            f.seek(40)
            f.write(b'\xff\xff')
        os.remove(os.path.join(self.tmp, 'corrupt', 'parts', shard.replace('.obs', '.dogm')))
        result = run('em', '--work', os.path.join(self.tmp, 'corrupt'), '--block', shard[:-4], *NEATO_ARGS)
        self.assertEqual(result.returncode, 1)
        self.assertIn('checksum mismatch', result.stderr)
        self.assertFalse(os.path.exists(os.path.join(self.tmp, 'corrupt', 'parts', shard.replace('.obs', '.dogm'))))

    def test_driver_command_line_end_to_end(self):
        out = os.path.join(self.tmp, 'cli.dogm')
        driver = subprocess.run([sys.executable, os.path.join(PACKAGE_DIR, 'scripts', 'dask_offline_em.py'),
                                 NEATO_BAG, NEATO_BAG, '--out', out, '--workers', '1', '--sharded-em', self.sharded_em,
                                 '--'] + NEATO_ARGS, capture_output=True, text=True, timeout=TIMEOUT_S)
        self.assertEqual(driver.returncode, 0, driver.stderr)
        self.assertIn('model -> ' + out, driver.stdout)
        with open(out, 'rb') as model:
            self.assertEqual(model.read(), offline_em([NEATO_BAG] * 2, out + '.single', NEATO_ARGS))


if __name__ == '__main__':
    rostest.rosrun(PKG, 'dask_offline_em', DaskOfflineEmTest)
