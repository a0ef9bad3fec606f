#!/usr/bin/env python3
"""The report on the real recordings: check_bag on every bag of ../shared/data/real (and any
bag named on the command line), with the defaults and with online learning off, one Markdown
row per bag and variant (docs/real_recordings.md#the-report).

    real_recordings_report.py [--data-dir DIR] [--out FILE] [--jobs N] [--check-bag PATH]
                              [BAG[:OPTIONS] ...] [-- CHECK_BAG_OPTIONS ...]

For each bag and variant (default; --no-learning) it runs check_bag once with --horizon 1,
5 and 30 and --csv, and reads the numbers from the CSV:

* at the end of the bag, of the cells the static map classifies occupied / free, the share
  the belief classifies the same way, and the share of the occupied ones whose learned
  p_free_given_occ exceeds 0.05 (learned as changing); the same on the cells last observed
  at least 10 s before the end;
* the dynamic model's Brier score and accuracy on occupied labels 1, 5 and 30 s ahead (the
  static map's of the same run in parentheses).

A second table gives how many of the static map's occupied / free cells the `stationary`
and `predicted` layers classify the same way. Exit status 0 when every run worked, 1 when a
check_bag run failed (its row says why), 2 on bad arguments, a missing data directory, no
bag or an unwritable --out directory.

Bags: every *.bag in --data-dir (default ../shared/data/real next to the package's checkout),
then those named on the command line. A bag's check_bag options (how to get its poses) come
from its name for the recordings of ../shared/data/real (KNOWN_BAGS below), or follow it
after a colon, as one shell word: 'my.bag:--fixed-frame odom' (the colon that ends an
existing file's name; a bag named with ':' alone gets no options). Options after `--` go to
every run (e.g. `-- --learner cell_em` to compare learners); they follow the bag's own and
the variant's.

Standard library only; run with /usr/bin/python3 (or rosrun dynamic_occupancy_grid
real_recordings_report.py) after building the package.
"""

import argparse
import concurrent.futures
import csv
import fnmatch
import glob
import math
import os
import shlex
import subprocess
import sys
import tempfile

PKG = 'dynamic_occupancy_grid'
SCRIPT_NAME = 'real_recordings_report'
# How the recordings of ../shared/data/real get their poses (its README.md): the Hokuyo
# office bags and the Neato bag in their odom frame, the stationary laser (no tf) at a fixed
# pose. Matched on the bag's file name; a bag named on the command line may override.
KNOWN_BAGS = [
    ('hokuyo_office_*.bag', ['--fixed-frame', 'odom']),
    ('neato_person_follower.bag', ['--fixed-frame', 'odom']),
    ('stationary_laser_people.bag', ['--laser-pose', '0,0,0']),
]
VARIANTS = [('default', []), ('`--no-learning`', ['--no-learning'])]
HORIZONS_S = [1.0, 5.0, 30.0]
# The columns of check_bag's CSV the tables read (an older check_bag lacks some).
CSV_COLUMNS = ['horizon_s', 'labels', 'unseen', 'occupied_labels', 'dynamic_brier', 'static_brier',
               'dynamic_occupied_accuracy', 'static_occupied_accuracy',
               'end_retention_after_s', 'end_static_free', 'end_static_occupied', 'end_kept_free', 'end_kept_occupied',
               'end_left_static_free', 'end_left_static_occupied', 'end_left_kept_free', 'end_left_kept_occupied',
               'end_occupied_changing', 'end_left_occupied_changing', 'end_stationary_kept_free',
               'end_stationary_kept_occupied', 'end_prediction_horizon_s', 'end_predicted_kept_free',
               'end_predicted_kept_occupied']
TIMEOUT_S = 600


def package_dirs():
    """The package's checkout: the script's parent directory, with symlinks resolved (a
    workspace links to the checkout) and as named."""
    here = os.path.abspath(__file__)
    dirs = []
    for path in (os.path.realpath(here), here):
        package = os.path.dirname(os.path.dirname(path))
        if package not in dirs:
            dirs.append(package)
    return dirs


def default_data_dir():
    """../shared/data/real next to the package's checkout (the first that exists)."""
    candidates = [os.path.normpath(os.path.join(package, '..', 'shared', 'data', 'real')) for package in package_dirs()]
    for candidate in candidates:
        if os.path.isdir(candidate):
            return candidate
    return candidates[0]


def find_check_bag(given):
    """check_bag: --check-bag, else beside this script (an installed package), the catkin
    workspaces on the environment's paths (as rosrun finds it), ~/dog_ws."""
    if given:
        if not os.access(given, os.X_OK):
            raise SystemExit('%s: --check-bag %s is not an executable' % (SCRIPT_NAME, given))
        return given
    here = os.path.join(os.path.dirname(os.path.abspath(__file__)), 'check_bag')
    if os.access(here, os.X_OK):
        return here
    try:
        from catkin.find_in_workspaces import find_in_workspaces
        found = find_in_workspaces(['libexec'], project=PKG, path='check_bag', first_match_only=True)
        if found:
            return found[0]
    except ImportError:  # a python without catkin: look in the workspaces ourselves
        pass
    prefixes = [p for p in os.environ.get('CMAKE_PREFIX_PATH', '').split(os.pathsep) if p]
    workspace = os.environ.get('DOG_WORKSPACE', os.path.join(os.path.expanduser('~'), 'dog_ws'))
    prefixes += [os.path.join(workspace, 'devel'), os.path.join(workspace, 'install')]
    for prefix in prefixes:
        candidate = os.path.join(prefix, 'lib', PKG, 'check_bag')
        if os.access(candidate, os.X_OK):
            return candidate
    raise SystemExit('%s: check_bag not found (build the package with scripts/setup.sh and source its '
                     'devel/setup.bash, or pass --check-bag PATH)' % SCRIPT_NAME)


def known_options(path):
    """The check_bag options KNOWN_BAGS gives a bag by its file name (none if unknown)."""
    name = os.path.basename(path)
    for pattern, options in KNOWN_BAGS:
        if fnmatch.fnmatch(name, pattern):
            return list(options)
    return []


def parse_bag_argument(text):
    """'BAG' or 'BAG:OPTIONS' -> (path, options or None). The bag is the part before the
    first ':' that ends the name of an existing file; a name that exists whole has none."""
    if os.path.isfile(text) or ':' not in text:
        return text, None
    start = 0
    while True:
        colon = text.find(':', start)
        if colon < 0:
            return text, None  # no file found: check_bag says so in the row
        if os.path.isfile(text[:colon]):
            try:
                return text[:colon], shlex.split(text[colon + 1:])
            except ValueError as error:
                raise SystemExit('%s: cannot read the options of %s: %s' % (SCRIPT_NAME, text[:colon], error))
        start = colon + 1


def read_csv(path):
    """check_bag's CSV: {horizon_s: row}, values as float (nan kept)."""
    with open(path, newline='') as file:
        reader = csv.DictReader(file)
        missing = [column for column in CSV_COLUMNS if column not in (reader.fieldnames or [])]
        if missing:
            raise ValueError('no column %s (a check_bag older than this script: rebuild the package)' %
                             ', '.join(missing))
        rows = list(reader)
    if not rows:
        raise ValueError('no row')
    table = {}
    for row in rows:
        values = {key: float(value) for key, value in row.items()}
        table[values['horizon_s']] = values
    return table


def last_line(text):
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    return lines[-1] if lines else ''


def scans_note(stdout):
    """check_bag's 'scans read: ...' line (the scans it could not use), or ''."""
    for line in stdout.splitlines():
        if line.startswith('scans read:'):
            return line.strip()
    return ''


def run_check_bag(check_bag, bag, options, work_dir, index):
    """One check_bag run: {'csv': {horizon_s: row}} or {'error': message}, with its summary."""
    csv_path = os.path.join(work_dir, 'run_%d.csv' % index)
    command = [check_bag, bag] + options + ['--csv', csv_path]
    for horizon in HORIZONS_S:
        command += ['--horizon', '%g' % horizon]
    try:
        result = subprocess.run(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, universal_newlines=True,
                                errors='replace', timeout=TIMEOUT_S)
    except subprocess.TimeoutExpired:
        return {'error': 'timed out after %d s' % TIMEOUT_S, 'command': command}
    run = {'command': command, 'scans': scans_note(result.stdout), 'stderr': result.stderr.splitlines()}
    if result.returncode != 0:
        run['error'] = 'check_bag exit %d: %s' % (result.returncode,
                                                  last_line(result.stderr) or last_line(result.stdout))
        return run
    try:
        run['csv'] = read_csv(csv_path)
    except (OSError, KeyError, ValueError) as error:
        run['error'] = 'the CSV of %s: %s' % (check_bag, error)
    return run


def percent(part, whole):
    if math.isnan(part) or math.isnan(whole) or whole == 0:
        return '-'
    return '%.1f %%' % (100.0 * part / whole)


def number(value):
    return '-' if math.isnan(value) else '%.4f' % value


def with_static(row, measure):
    """'dynamic (static)' of one measure at one horizon; '-' without the horizon."""
    if row is None:
        return '-'
    return '%s (%s)' % (number(row['dynamic_' + measure]), number(row['static_' + measure]))


def report_rows(bag_name, variant, run):
    """(main row, layers row) of one run, as lists of cells."""
    if 'error' in run:
        message = run['error'].replace('|', '/')
        return ([bag_name, variant, 'failed: ' + message] + [''] * 11,
                [bag_name, variant, 'failed'] + [''] * 5)
    rows = run['csv']
    end = next(iter(rows.values()))
    main = [bag_name, variant,
            percent(end['end_kept_occupied'], end['end_static_occupied']),
            percent(end['end_kept_free'], end['end_static_free']),
            percent(end['end_occupied_changing'], end['end_static_occupied']),
            percent(end['end_left_kept_occupied'], end['end_left_static_occupied']),
            percent(end['end_left_kept_free'], end['end_left_static_free']),
            percent(end['end_left_occupied_changing'], end['end_left_static_occupied'])]
    for measure in ('brier', 'occupied_accuracy'):
        for horizon in HORIZONS_S:
            main.append(with_static(rows.get(horizon), measure))
    layers = [bag_name, variant,
              '%d / %d' % (end['end_static_occupied'], end['end_static_free']),
              percent(end['end_stationary_kept_occupied'], end['end_static_occupied']),
              percent(end['end_stationary_kept_free'], end['end_static_free']),
              '%g s' % end['end_prediction_horizon_s'],
              percent(end['end_predicted_kept_occupied'], end['end_static_occupied']),
              percent(end['end_predicted_kept_free'], end['end_static_free'])]
    return main, layers


def main_header(left):
    """The main table's header; `left` names the cells left before the end ('≥ 10 s')."""
    return (['bag', 'variant', 'belief keeps occupied', 'keeps free', 'occupied learned as changing',
             'left %s: keeps occupied' % left, 'keeps free', 'occupied learned as changing'] +
            ['Brier %g s' % h for h in HORIZONS_S] + ['occ.acc %g s' % h for h in HORIZONS_S])


LAYERS_HEADER = ['bag', 'variant', 'static occupied / free', 'stationary keeps occupied', 'keeps free',
                 'predicted ahead', 'predicted keeps occupied', 'keeps free']


def markdown(header, rows):
    lines = ['| ' + ' | '.join(header) + ' |', '|' + '---|' * len(header)]
    lines += ['| ' + ' | '.join(row) + ' |' for row in rows]
    return '\n'.join(lines)


def parse_arguments(argv):
    if '--' in argv:
        split = argv.index('--')
        argv, extra = argv[:split], argv[split + 1:]
    else:
        extra = []
    parser = argparse.ArgumentParser(
        prog='real_recordings_report.py',
        description='check_bag on every bag of the real recordings (and any named here), default and '
                    '--no-learning: one Markdown row per bag and variant (docs/real_recordings.md).',
        epilog='Options after -- go to every check_bag run, e.g. -- --learner cell_em.')
    parser.add_argument('bags', nargs='*', metavar='BAG[:OPTIONS]',
                        help="more bags; OPTIONS (one shell word after the bag's name and a colon, e.g. "
                             "'my.bag:--fixed-frame odom') are that bag's check_bag options (default: by its name "
                             'for the recordings of the data directory, none otherwise)')
    parser.add_argument('--data-dir', metavar='DIR',
                        help='the recordings, every *.bag in it (default ../shared/data/real next to the '
                             'package: %s)' %
                             default_data_dir())
    parser.add_argument('--out', metavar='FILE', help='also write the tables to FILE')
    parser.add_argument('--jobs', type=int, default=2, metavar='N',
                        help='check_bag runs at a time (default 2)')
    parser.add_argument('--check-bag', metavar='PATH', help='the check_bag executable (default: found in the '
                                                            'catkin workspaces)')
    options = parser.parse_args(argv)
    if options.jobs < 1:
        parser.error('--jobs needs at least 1')
    options.extra = extra
    return options


class SystemExit2(Exception):
    """A usage error: message, exit status 2."""


def collect_bags(options):
    """[(path, check_bag options)]: the data directory's bags, then the named ones."""
    bags = []
    data_dir = options.data_dir or default_data_dir()
    if os.path.isdir(data_dir):
        for path in sorted(glob.glob(os.path.join(data_dir, '*.bag'))):
            bags.append((path, known_options(path)))
    elif options.bags and not options.data_dir:
        print('%s: no data directory %s: only the bags named on the command line' % (SCRIPT_NAME, data_dir),
              file=sys.stderr)
    else:
        raise SystemExit2('%s: data directory %s not found (the real recordings live in ../shared/data/real '
                          'next to the package; give --data-dir DIR, or name bags on the command line)' %
                          (SCRIPT_NAME, data_dir))
    for text in options.bags:
        path, bag_options = parse_bag_argument(text)
        bags.append((path, known_options(path) if bag_options is None else bag_options))
    if not bags:
        raise SystemExit2('%s: no bag in %s and none named on the command line' % (SCRIPT_NAME, data_dir))
    return bags


def main(argv):
    options = parse_arguments(argv)
    try:
        bags = collect_bags(options)
        if options.out:
            directory = os.path.dirname(os.path.abspath(options.out))
            if not os.access(directory, os.W_OK):
                raise SystemExit2('%s: cannot write %s (no writable directory %s)' % (SCRIPT_NAME, options.out,
                                                                                     directory))
    except SystemExit2 as error:
        print(error, file=sys.stderr)
        return 2
    check_bag = find_check_bag(options.check_bag)
    jobs = [(bag, bag_options, variant, variant_options)
            for bag, bag_options in bags for variant, variant_options in VARIANTS]
    with tempfile.TemporaryDirectory(prefix='dog_real_report_') as work_dir:
        with concurrent.futures.ThreadPoolExecutor(max_workers=options.jobs) as pool:
            futures = [pool.submit(run_check_bag, check_bag, bag, bag_options + variant_options + options.extra,
                                   work_dir, index)
                       for index, (bag, bag_options, _, variant_options) in enumerate(jobs)]
            runs = [future.result() for future in futures]
    main_rows, layer_rows, notes = [], [], []
    names = [os.path.basename(bag) for bag, _ in bags]
    for (bag, bag_options, variant, _), run in zip(jobs, runs):
        # The file name, unless two bags share it.
        name = os.path.basename(bag) if names.count(os.path.basename(bag)) == 1 else bag
        row, layers = report_rows(name, variant, run)
        main_rows.append(row)
        layer_rows.append(layers)
        if variant == VARIANTS[0][0]:
            note = '%s (`%s`): %s' % (name, ' '.join(shlex.quote(o) for o in bag_options + options.extra) or
                                      'no options', run.get('scans') or run.get('error', ''))
            if 'csv' in run:
                scored = [run['csv'].get(h) for h in HORIZONS_S]
                note += '; scored labels %s s: %s (occupied %s)' % (
                    ' / '.join('%g' % h for h in HORIZONS_S),
                    ' / '.join('-' if r is None else '%d' % (r['labels'] - r['unseen']) for r in scored),
                    ' / '.join('-' if r is None else '%d' % r['occupied_labels'] for r in scored))
            stderr = run.get('stderr', [])
            if stderr and 'error' not in run:
                note += '; %d lines on stderr, the first: "%s"' % (len(stderr), stderr[0].strip()[:100])
            notes.append(note)
    # The cells left before the end: check_bag's --retention-after (10 s unless changed).
    left_s = sorted({run['csv'][next(iter(run['csv']))]['end_retention_after_s'] for run in runs if 'csv' in run})
    left = '≥ %g s' % left_s[0] if len(left_s) == 1 else '≥ --retention-after'
    extra = ' with `%s` on every run' % ' '.join(shlex.quote(o) for o in options.extra) if options.extra else ''
    text = '\n'.join([
        'check_bag on %d bag%s%s: at the end, of the static map\'s occupied / free cells the share the belief '
        'classifies the same way, and of its occupied cells the share learned as changing (p_free_given_occ > '
        '0.05); the same on the cells last observed %s before the end; the dynamic model\'s Brier score and '
        'accuracy on occupied labels (the static map\'s in parentheses).' % (len(bags), '' if len(bags) == 1 else 's',
                                                                              extra, left),
        '',
        markdown(main_header(left), main_rows),
        '',
        'The stationary and predicted layers at the end: of the static map\'s occupied / free cells, the share '
        'each classifies the same way (occupied > 0.65, free < 0.196).',
        '',
        markdown(LAYERS_HEADER, layer_rows),
        '',
        'Scans and scored labels per bag (default run; few occupied labels make occ.acc coarse):',
        '',
    ] + ['- ' + note for note in notes]) + '\n'
    sys.stdout.write(text)
    if options.out:
        try:
            with open(options.out, 'w') as file:
                file.write(text)
        except OSError as error:
            print('%s: cannot write %s: %s' % (SCRIPT_NAME, options.out, error), file=sys.stderr)
            return 1
    failed = sum(1 for run in runs if 'error' in run)
    if failed:
        print('%s: %d of %d check_bag runs failed' % (SCRIPT_NAME, failed, len(runs)), file=sys.stderr)
        return 1
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
