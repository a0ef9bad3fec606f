#!/usr/bin/env python3
"""Throughput of sharded offline EM on Dask against offline_em in the same run (BENCHMARKS.md,
"Sharded offline EM on Dask").

    dask_offline_em_bench.py [--bags N] [--steps N] [--block-cells N] [--dir DIR]

Simulates a patrol of the office as N bags (simulate patrol_office, seeds 1..N), then times
offline_em (1 and 2 threads) and dask_offline_em.py's phases with LocalClusters of 1 and 2
workers, checks that every model is byte for byte offline_em's, and prints the shard files'
size and the per-task costs the projection in BENCHMARKS.md starts from. Needs the package
built and its setup.bash sourced.
"""

import argparse
import glob
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time

from catkin.find_in_workspaces import find_in_workspaces


def executable(name):
    found = find_in_workspaces(['libexec'], project='dynamic_occupancy_grid', path=name, first_match_only=True)
    if not found:
        raise SystemExit('%s not found (build the package, source its setup.bash)' % name)
    return found[0]


def timed(command):
    start = time.time()
    result = subprocess.run(command, capture_output=True, text=True, check=True)
    return time.time() - start, result.stdout


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--bags', type=int, default=6)
    parser.add_argument('--steps', type=int, default=600, help='steps per bag (two scans a step)')
    parser.add_argument('--block-cells', type=int, default=128)
    parser.add_argument('--dir', help='work directory (default: a temporary one, removed)')
    args = parser.parse_args()
    here = os.path.dirname(os.path.abspath(__file__))
    sys.path.insert(0, os.path.join(here, '..', 'scripts'))
    import dask_offline_em
    from distributed import Client, LocalCluster

    tmp = args.dir or tempfile.mkdtemp(prefix='dog_dask_bench_')
    os.makedirs(tmp, exist_ok=True)
    bags = []
    for seed in range(1, args.bags + 1):
        path = os.path.join(tmp, 'patrol_%d.bag' % seed)
        if not os.path.exists(path):
            subprocess.run([executable('simulate'), '--scenario', 'patrol_office', '--steps', str(args.steps),
                            '--seed', str(seed), '--out', path], check=True, capture_output=True)
        bags.append(path)
    print('%d bags of patrol_office, %d steps each, %.0f MB' % (
        len(bags), args.steps, sum(os.path.getsize(b) for b in bags) / 1e6))

    single = {}
    for threads in (1, 2):
        out = os.path.join(tmp, 'single_%d.dogm' % threads)
        seconds, stdout = timed([executable('offline_em')] + bags + ['--out', out, '--threads', str(threads)])
        reading = float(re.search(r'read in ([0-9.]+) s', stdout).group(1))
        em = float(re.search(r'converged, objective .* ([0-9.]+) s\n', stdout).group(1))
        observed = int(re.search(r'cells, ([0-9]+) observed cell steps', stdout).group(1))
        single[threads] = (seconds, reading, em)
        print('offline_em --threads %d: %.2f s (reading %.2f s, EM %.2f s), %d observed cell steps' % (
            threads, seconds, reading, em, observed))
    with open(os.path.join(tmp, 'single_1.dogm'), 'rb') as f:
        reference = f.read()

    for workers in (1, 2):
        start = time.time()
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None)
        client = Client(cluster)
        startup = time.time() - start
        work = os.path.join(tmp, 'work_%d' % workers)
        shutil.rmtree(work, ignore_errors=True)
        out = os.path.join(tmp, 'dask_%d.dogm' % workers)
        start = time.time()
        timing = dask_offline_em.sharded_offline_em(client, bags, out, work, ['--block-cells', str(args.block_cells),
                                                                               '--threads', '1'],
                                                    executable('sharded_em'), log=lambda line: None)
        total = time.time() - start
        client.close()
        cluster.close()
        with open(out, 'rb') as f:
            same = f.read() == reference
        shards = glob.glob(os.path.join(work, 'bags', '*', '*.obs'))
        shard_bytes = sum(os.path.getsize(p) for p in shards)
        print('dask, %d worker(s): %.2f s (cluster start %.2f s not counted); %s; model %s offline_em\'s' % (
            workers, total, startup,
            ', '.join('%s %.2f s (%d tasks)' % (phase, s, n) for phase, (s, n) in timing.items()),
            'equals' if same else 'DIFFERS FROM'))
        print('  shards: %d files, %.1f MB (%.2f bytes per observed cell step)' % (
            len(shards), shard_bytes / 1e6, shard_bytes / observed))
        if not same:
            return 1
    if not args.dir:
        shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
