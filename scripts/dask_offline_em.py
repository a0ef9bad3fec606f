#!/usr/bin/env python3
"""Offline EM over many bags on a Dask cluster: the model file offline_em writes for the same
bags in the same order, bit for bit (docs/sharded_em.md).

    dask_offline_em.py BAG [BAG ...] --out MODEL [--scheduler ADDRESS | --workers N]
                       [--work-dir DIR] [-- sharded_em options]

The work is sharded_em's steps as Dask tasks: one extraction per bag (the per-cell
observations of each map block), the plan (where each bag's steps fall on the timeline), one
EM task per block (with --em-learn-sensor-model: per block and round, each round ended by
the reduce of the blocks' sensor-model sums; with --mrf-temperature: an E-step per block and
iteration, each iteration ended by the MRF's joint M-step over all cells), and the assembly
of the model. Without --scheduler a LocalCluster of
--workers processes runs here. On a real cluster every worker needs the package built and a
file system shared with the others at --work-dir (NFS or similar); the bags and the work
directory must be at the same paths on every worker and on the machine running this script.

Tasks are idempotent (each writes its files atomically, and a step a dead worker started is
killed with it), so a worker that dies mid-run is harmless: Dask runs its tasks again elsewhere (its ``distributed.scheduler.allowed-failures``,
3 by default), and the model is the same. Options after ``--`` go to every sharded_em step
(mapping and EM options: sharded_em --help); they must be the ones offline_em would get.
"""

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
import uuid

EXIT_REDO = 3  # sharded_em plan: bags to extract again (plan.redo)


def find_sharded_em():
    """sharded_em beside this script (an installed package), else in the catkin workspaces."""
    here = os.path.join(os.path.dirname(os.path.abspath(__file__)), 'sharded_em')
    if os.access(here, os.X_OK):
        return here
    try:
        from catkin.find_in_workspaces import find_in_workspaces
        found = find_in_workspaces(['libexec'], project='dynamic_occupancy_grid', path='sharded_em',
                                   first_match_only=True)
        if found:
            return found[0]
    except ImportError:
        pass
    raise SystemExit('dask_offline_em: sharded_em not found (build the package and source its setup.bash, or '
                     'pass --sharded-em)')


def die_with_parent():
    """In the child: SIGKILL when the worker that started it dies (Linux prctl
    PR_SET_PDEATHSIG), so that a killed worker leaves no step running on its own."""
    import ctypes
    import signal
    ctypes.CDLL('libc.so.6', use_errno=True).prctl(1, signal.SIGKILL)


def run_step(command):
    """Runs one sharded_em step (a Dask task); its stdout, or an error with its stderr."""
    result = subprocess.run(command, capture_output=True, text=True, errors='replace', preexec_fn=die_with_parent)
    if result.returncode != 0:
        raise RuntimeError('%s failed (exit %d): %s' % (' '.join(command[:3]), result.returncode,
                                                        result.stderr.strip() or result.stdout.strip()))
    return result.stdout


def run_plan(command):
    """The plan step: ('ok', stdout) or ('redo', [(bag, anchor step), ...])."""
    result = subprocess.run(command, capture_output=True, text=True, errors='replace', preexec_fn=die_with_parent)
    if result.returncode == EXIT_REDO:
        work = command[command.index('--work') + 1]
        with open(os.path.join(work, 'plan.redo')) as redo:
            return 'redo', [tuple(int(v) for v in line.split()) for line in redo if line.strip()]
    if result.returncode != 0:
        raise RuntimeError('sharded_em plan failed (exit %d): %s' % (result.returncode, result.stderr.strip()))
    return 'ok', result.stdout


def mrf_temperature(options):
    """The --mrf-temperature among sharded_em's options (0 without)."""
    for i, option in enumerate(options):
        if option.startswith('--mrf-temperature='):
            return float(option.split('=', 1)[1])
        if option == '--mrf-temperature' and i + 1 < len(options):
            return float(options[i + 1])
    return 0.0


def blocks_of(work, bags):
    """The blocks any bag has observations in (from the bags' metas)."""
    names = set()
    for index in range(bags):
        with open(os.path.join(work, 'bags', str(index), 'meta')) as meta:
            names.update(line.split()[1] for line in meta if line.startswith('block '))
    return sorted(names)


class Phases(object):
    """Hook for tests: called with (phase name, client, futures) once a phase's tasks are
    submitted."""

    def __call__(self, phase, client, futures):
        pass


def sharded_offline_em(client, bags, out, work, options, sharded_em, retries=3, on_phase=Phases(), log=print):
    """Runs the steps on `client`; writes the model to `out`. Returns the per-phase wall times
    (s) and task counts."""
    from distributed import progress
    base = [sharded_em]
    common = ['--work', work] + list(options)
    token = uuid.uuid4().hex[:8]
    timing = {}

    def wait(phase, futures):
        on_phase(phase, client, futures)
        if sys.stderr.isatty():
            progress(futures)
        results = client.gather(futures)
        return results

    start = time.time()
    extract = [client.submit(run_step, base + ['extract', bag, '--index', str(i)] + common,
                             key='extract-%d-%s' % (i, token), retries=retries, pure=False)
               for i, bag in enumerate(bags)]
    for line in wait('extract', extract):
        log(line.strip())
    # Each meta must be this run's bag (a work directory may hold another run's).
    for index, bag in enumerate(bags):
        with open(os.path.join(work, 'bags', str(index), 'meta')) as meta:
            listed = next((line[4:].rstrip('\n') for line in meta if line.startswith('bag ')), None)
        if listed != bag:
            raise RuntimeError('bags/%d/meta is of %s, not of %s' % (index, listed, bag))
    timing['extract'] = (time.time() - start, len(bags))

    start = time.time()
    attempt = 0
    while True:
        attempt += 1
        status, value = client.submit(run_plan, base + ['plan', '--bags', str(len(bags))] + common,
                                      key='plan-%d-%s' % (attempt, token), retries=retries, pure=False).result()
        if status == 'ok':
            log(value.strip())
            break
        # A bag whose stamps fall on step borders differently on the timeline: again, with
        # its first scan at the step the timeline gives it.
        for bag, anchor in value:
            log('bag %d: extracted again with --anchor-step %d' % (bag, anchor))
            client.submit(run_step, base + ['extract', bags[bag], '--index', str(bag), '--anchor-step', str(anchor)]
                          + common, key='extract-%d-%d-%s' % (bag, anchor, token), retries=retries,
                          pure=False).result()
    timing['plan'] = (time.time() - start, attempt)

    start = time.time()
    blocks = blocks_of(work, len(bags))
    # Learning the sensor model: rounds of EM over every block, each followed by the reduce
    # of the blocks' sums (the emission M-step). The MRF: iterations of the blocks' E-steps,
    # each followed by the joint M-step over all cells. Both until that step says done.
    if '--em-learn-sensor-model' in options:
        loop, step = '--round', 'reduce'
    elif mrf_temperature(options) > 0.0:
        loop, step = '--iteration', 'mrf-step'
    else:
        loop, step = None, None
    index = 0
    while True:
        loop_option = [loop, str(index)] if loop else []
        em = [client.submit(run_step, base + ['em', '--block', block] + loop_option + common,
                            key='em-%s-%d-%s' % (block, index, token), retries=retries, pure=False)
              for block in blocks]
        for line in wait('em', em):
            log(line.strip())
        if not loop:
            break
        reduced = client.submit(run_step, base + [step, loop, str(index)] + common,
                                key='%s-%d-%s' % (step, index, token), retries=retries, pure=False).result()
        log(reduced.strip())
        if reduced.startswith('done'):
            break
        index += 1
    tasks = len(blocks) * (index + 1)
    if step == 'mrf-step':
        # The parts, from the last iteration's E-steps.
        finish = [client.submit(run_step, base + ['em', '--block', block, loop, str(index), '--finish'] + common,
                                key='finish-%s-%s' % (block, token), retries=retries, pure=False)
                  for block in blocks]
        for line in wait('em', finish):
            log(line.strip())
        tasks += len(blocks)
    timing['em'] = (time.time() - start, tasks)

    start = time.time()
    log(client.submit(run_step, base + ['assemble', '--out', out] + common, key='assemble-' + token,
                      retries=retries, pure=False).result().strip())
    timing['assemble'] = (time.time() - start, 1)
    return timing


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    tool_options = []
    if '--' in argv:
        split = argv.index('--')
        argv, tool_options = argv[:split], argv[split + 1:]
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0],
                                     epilog='Options after -- go to every sharded_em step (sharded_em --help).')
    parser.add_argument('bags', nargs='+', metavar='BAG', help='bags, in timeline order (as offline_em takes them)')
    parser.add_argument('--out', required=True, metavar='MODEL', help='model file to write')
    parser.add_argument('--scheduler', metavar='ADDRESS', help='a running dask-scheduler (tcp://host:8786); '
                        'default: a LocalCluster here')
    parser.add_argument('--workers', type=int, default=2, metavar='N',
                        help='LocalCluster worker processes (default 2; one thread each)')
    parser.add_argument('--work-dir', metavar='DIR', help='shared work directory (default: a temporary one, '
                        'removed at the end; on a real cluster it must be on a file system every worker sees)')
    parser.add_argument('--keep-work', action='store_true', help='keep the work directory')
    parser.add_argument('--retries', type=int, default=3, metavar='N',
                        help='times a failed task is tried again (default 3)')
    parser.add_argument('--sharded-em', metavar='PATH', help='the sharded_em executable (default: found in the '
                        'catkin workspaces)')
    args = parser.parse_args(argv)
    if args.workers < 1:
        parser.error('--workers must be at least 1')
    bags = [os.path.abspath(bag) for bag in args.bags]
    for bag in bags:
        if not os.path.isfile(bag):
            parser.error('%s is not a file' % bag)
    sharded_em = os.path.abspath(args.sharded_em) if args.sharded_em else find_sharded_em()
    # One EM thread per task: a worker runs one task per thread it has (dask-worker --nthreads).
    if not any(option == '--threads' or option.startswith('--threads=') for option in tool_options):
        tool_options = tool_options + ['--threads', '1']
    if any(option in ('--work', '--index', '--anchor-step', '--bags', '--block', '--round', '--iteration', '--out')
           for option in tool_options):
        parser.error('--work, --index, --anchor-step, --bags, --block, --round, --iteration and --out are set by '
                     'this script')
    # Every tool option is checked once, here, before any task runs.
    check = subprocess.run([sharded_em, 'check', '--work', '.'] + tool_options, capture_output=True, text=True)
    if check.returncode != 0:
        parser.error(check.stderr.strip().splitlines()[0] if check.stderr.strip() else 'bad sharded_em options')
    work = os.path.abspath(args.work_dir) if args.work_dir else tempfile.mkdtemp(prefix='dog_sharded_em_')
    os.makedirs(work, exist_ok=True)

    from distributed import Client, LocalCluster
    cluster = None
    if args.scheduler:
        client = Client(args.scheduler)
    else:
        cluster = LocalCluster(n_workers=args.workers, threads_per_worker=1, processes=True,
                               dashboard_address=':0')
        client = Client(cluster)
    # The dashboard is served by the scheduler, and only where bokeh is installed (Debian 12
    # does not package it: pip install 'bokeh>=2.4.2,<3').
    import importlib.util
    dashboard = client.dashboard_link if args.scheduler or importlib.util.find_spec('bokeh') else \
        'none (needs bokeh)'
    print('dask_offline_em: %d bags, %d workers, dashboard %s, work %s' % (
        len(bags), len(client.scheduler_info()['workers']), dashboard, work))
    try:
        timing = sharded_offline_em(client, bags, os.path.abspath(args.out), work, tool_options, sharded_em,
                                    retries=args.retries)
        for phase, (seconds, tasks) in timing.items():
            print('dask_offline_em: %-8s %3d task(s) %8.2f s' % (phase, tasks, seconds))
    except Exception as error:  # a task that failed for good (its error, or Dask's KilledWorker), a file
        print('dask_offline_em: %s: %s' % (type(error).__name__, error), file=sys.stderr)
        return 1
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
        if not args.work_dir and not args.keep_work:
            shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
