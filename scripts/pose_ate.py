#!/usr/bin/env python3
"""ATE of odometry and of the pose filter on the Hokuyo office recordings, scored between
the localizer's jumps (docs/pose_correction_real.md).

    pose_ate.py BAG [BAG ...] [--process-bag PATH] [--out DIR] [--trajectory FILE]
                [--filter-log FILE] [--jump-m M] [--jump-rad RAD] [--min-segment-m M]
                [--min-poses N] [--offset S] [--segments] [--no-header]
                [-- PROCESS_BAG_OPTIONS ...]

For each bag of ../shared/data/real/hokuyo_office_*.bag (see its README.md):

* the reference: map -> odom (from the localizer that ran when the recording was replayed)
  composed with odom -> base_link (odometry) at each pose's stamp. The localizer's stamps
  are on the replay's clock: the offset is measured per bag as the median of (time the bag
  recorded a scan - the scan's header stamp), which the map -> odom stamps follow (they are
  the replay's time plus the localizer's 0.05 s transform tolerance); --offset overrides
  it. Only the map -> odom messages stamped on the replay's clock are read (the may16 bags
  also hold a second map -> odom stream stamped 22 s before the scans' clock: dropped and
  counted). map -> odom is held from one message to the next (it changes in steps);
  odom -> base_link is interpolated linearly (yaw on the circle);
* the localizer's jumps: consecutive map -> odom messages that differ by more than
  --jump-m (default 0.5 m) or --jump-rad (default 0.3 rad). The poses between two jumps
  (and the bag's ends) form a segment; a segment is scored when its reference path is at
  least --min-segment-m long (default 1 m) and it has at least --min-poses poses (default 3);
* per scored segment, the ATE of each estimate: the RMSE of its positions after the best
  rigid 2D alignment (rotation and translation, no scale: Umeyama/Horn, as evo_ape --align)
  onto the reference, at the estimate's stamps. The bag's total is the mean of the
  segments' ATEs weighted by their reference path lengths.

Estimates:

* `odometry`: odom -> base_link at the filter's stamps (so that both are scored on the same
  poses); without a filter trajectory, at every scan;
* `filter`: the trajectory process_bag --pose-correction rbpf writes (trajectory.tum: the
  best particle's poses at the filter's updates, the laser being at base_link in these
  bags). Given --trajectory FILE it is read from there; else process_bag is run on the bag
  with `--fixed-frame odom --pose-correction rbpf --out DIR/<bag name>` plus the options
  after `--`, and its summary lines (updates, resamplings; N_eff's median, min and max and
  the filter's ms per update from its `pose filter:` line) and run time are read;
* `filter online` (only with --filter-log): the pose the filter gave each scan as it came
  (map -> odom of that moment times odometry), from a per-scan log of an instrumented build
  (docs/pose_correction_real.md, "Instrumentation": rows `S,stamp,odom x,y,yaw,corrected
  x,y,yaw` and `U,...` per update). The log's update rows also give N_eff, the spread of the
  particles' log-likelihoods and the time per update. A file DIR/<bag name>/filter_log.csv
  is read when it exists.

Prints one Markdown row per bag (--segments: also one per segment). Standard library and
numpy; reads bags with the python rosbag module: run with /usr/bin/python3 after sourcing
the workspace. Exit status 0 when every bag was scored, 1 when one failed, 2 on bad
arguments.
"""

import argparse
import bisect
import math
import os
import re
import shlex
import shutil
import subprocess
import sys
import time

import numpy as np

PROCESS_BAG_DEFAULTS = ['--fixed-frame', 'odom', '--pose-correction', 'rbpf']


# ----------------------------------------------------------------------------- geometry

def wrap(angle):
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


def yaw_of(q):
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def compose(a, b):
    """a * b for poses (x, y, yaw)."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return (a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], wrap(a[2] + b[2]))


def relative(a, b):
    """a^-1 * b."""
    c, s = math.cos(a[2]), math.sin(a[2])
    dx, dy = b[0] - a[0], b[1] - a[1]
    return (c * dx + s * dy, -s * dx + c * dy, wrap(b[2] - a[2]))


def align_rigid_2d(estimate, reference):
    """The rotation R (2x2) and translation t minimising sum |R e + t - r|^2 (Umeyama 1991
    without scale). estimate, reference: N x 2 arrays, N >= 2."""
    e = np.asarray(estimate, dtype=float)
    r = np.asarray(reference, dtype=float)
    me, mr = e.mean(axis=0), r.mean(axis=0)
    cov = (r - mr).T @ (e - me) / len(e)
    u, _, vt = np.linalg.svd(cov)
    d = np.eye(2)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        d[1, 1] = -1.0
    rot = u @ d @ vt
    return rot, mr - rot @ me


def ate(estimate, reference):
    """RMSE of the positions after align_rigid_2d (evo_ape --align's APE on translation)."""
    e = np.asarray(estimate, dtype=float)
    r = np.asarray(reference, dtype=float)
    if len(e) < 2:
        return float('nan')
    rot, t = align_rigid_2d(e, r)
    residual = (e @ rot.T + t) - r
    return float(math.sqrt(np.mean(np.sum(residual ** 2, axis=1))))


def path_length(points):
    p = np.asarray(points, dtype=float)
    if len(p) < 2:
        return 0.0
    return float(np.sum(np.hypot(np.diff(p[:, 0]), np.diff(p[:, 1]))))


# ----------------------------------------------------------------------------- time series

class Held:
    """A pose held from each message's stamp to the next (map -> odom)."""

    def __init__(self, stamps, poses):
        self.stamps = list(stamps)
        self.poses = list(poses)

    def at(self, stamp):
        i = bisect.bisect_right(self.stamps, stamp) - 1
        return self.poses[max(i, 0)]


class Interpolated:
    """A pose interpolated linearly between messages (odom -> base_link); held at the ends."""

    def __init__(self, stamps, poses):
        order = sorted(range(len(stamps)), key=lambda i: stamps[i])
        self.stamps = [stamps[i] for i in order]
        self.poses = [poses[i] for i in order]

    def at(self, stamp):
        i = bisect.bisect_right(self.stamps, stamp)
        if i == 0:
            return self.poses[0]
        if i == len(self.stamps):
            return self.poses[-1]
        t0, t1 = self.stamps[i - 1], self.stamps[i]
        a, b = self.poses[i - 1], self.poses[i]
        f = 0.0 if t1 <= t0 else (stamp - t0) / (t1 - t0)
        return (a[0] + f * (b[0] - a[0]), a[1] + f * (b[1] - a[1]), wrap(a[2] + f * wrap(b[2] - a[2])))


# ----------------------------------------------------------------------------- the bag

class BagData:
    def __init__(self):
        self.scan_stamps = []
        self.offset_s = 0.0
        self.odom = None           # Interpolated odom -> base_link, scans' clock
        self.map_odom = None       # Held map -> odom, shifted onto the scans' clock
        self.map_odom_dropped = 0  # messages not on the replay's clock
        self.jumps = []            # (stamp on the scans' clock, metres, radians)


def read_bag(path, jump_m, jump_rad, offset_s=None):
    import rosbag  # the ROS python module: /usr/bin/python3 with the workspace sourced
    data = BagData()
    receive_minus_header = []
    odom_stamps, odom_poses = [], []
    map_odom = []  # (stamp, receive time, pose)
    with rosbag.Bag(path) as bag:
        for topic, msg, t in bag.read_messages(topics=['/scan', '/tf']):
            if topic == '/scan':
                stamp = msg.header.stamp.to_sec()
                data.scan_stamps.append(stamp)
                receive_minus_header.append(t.to_sec() - stamp)
                continue
            for tr in msg.transforms:
                parent = tr.header.frame_id.lstrip('/')
                child = tr.child_frame_id.lstrip('/')
                pose = (tr.transform.translation.x, tr.transform.translation.y, yaw_of(tr.transform.rotation))
                if (parent, child) == ('odom', 'base_link'):
                    odom_stamps.append(tr.header.stamp.to_sec())
                    odom_poses.append(pose)
                elif (parent, child) == ('map', 'odom'):
                    map_odom.append((tr.header.stamp.to_sec(), t.to_sec(), pose))
    if not data.scan_stamps or not odom_stamps or not map_odom:
        raise ValueError('%s: needs /scan, odom -> base_link and map -> odom on /tf' % path)
    data.scan_stamps.sort()
    data.offset_s = float(np.median(receive_minus_header)) if offset_s is None else offset_s
    data.odom = Interpolated(odom_stamps, odom_poses)
    # The localizer's messages are stamped on the replay's clock (the time the bag recorded
    # them, plus its transform tolerance); others (may16's second stream) are dropped.
    kept = [(stamp - data.offset_s, pose) for stamp, receive, pose in map_odom if abs(stamp - receive) < 1.0]
    data.map_odom_dropped = len(map_odom) - len(kept)
    if not kept:
        raise ValueError('%s: no map -> odom message stamped on the replay clock' % path)
    kept.sort(key=lambda k: k[0])
    data.map_odom = Held([k[0] for k in kept], [k[1] for k in kept])
    for (_, a), (stamp, b) in zip(kept, kept[1:]):
        # the change measured where the robot is: its map pose before and after
        robot = data.odom.at(stamp)
        before, after = compose(a, robot), compose(b, robot)
        metres, radians = math.hypot(after[0] - before[0], after[1] - before[1]), abs(wrap(b[2] - a[2]))
        if metres > jump_m or radians > jump_rad:
            data.jumps.append((stamp, metres, radians))
    return data


def reference_at(data, stamp):
    return compose(data.map_odom.at(stamp), data.odom.at(stamp))


def segment_index(data, stamp):
    """0 before the first jump, k after the k-th."""
    return bisect.bisect_right([j[0] for j in data.jumps], stamp)


# ----------------------------------------------------------------------------- estimates

def read_tum(path):
    stamps, poses = [], []
    with open(path) as f:
        for line in f:
            line = line.strip()
            if not line or line.startswith('#'):
                continue
            v = [float(x) for x in line.split()]
            stamps.append(v[0])
            yaw = 2.0 * math.atan2(v[6], v[7])  # a rotation about z: qz, qw
            poses.append((v[1], v[2], wrap(yaw)))
    return stamps, poses


def read_filter_log(path):
    """The instrumented build's log: per-scan corrected poses and per-update rows."""
    online_stamps, online_poses, updates = [], [], []
    with open(path) as f:
        for line in f:
            fields = line.strip().split(',')
            if fields[0] == 'S':
                v = [float(x) for x in fields[1:]]
                online_stamps.append(v[0])
                online_poses.append((v[4], v[5], v[6]))
            elif fields[0] == 'U':
                v = [float(x) for x in fields[1:]]
                online_stamps.append(v[0])
                online_poses.append((v[4], v[5], v[6]))
                updates.append({
                    'stamp': v[0], 'n_eff': v[7], 'resampled': v[8] > 0.5, 'll_max': v[9], 'll_second': v[10],
                    'll_min': v[11], 'll_best': v[12], 'matched': v[13], 'match_shift_m': v[14],
                    'match_turn_rad': v[15], 'match_beams': v[16], 'cells': v[17], 'unseen': v[18],
                    'hits': v[19], 'best_match_dx': v[20], 'best_match_dy': v[21], 'best_match_dyaw': v[22],
                    'corr_dx': v[23], 'corr_dy': v[24], 'corr_dyaw': v[25], 'ms': v[26],
                    'odo_dx': v[27], 'odo_dy': v[28], 'odo_dyaw': v[29]})
    return online_stamps, online_poses, updates


def run_process_bag(command, bag, out_dir, extra):
    args = command + [bag] + PROCESS_BAG_DEFAULTS + ['--out', out_dir] + extra
    start = time.monotonic()
    proc = subprocess.run(args, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, universal_newlines=True)
    seconds = time.monotonic() - start
    with open(os.path.join(out_dir, 'process_bag.log') if os.path.isdir(out_dir) else os.devnull, 'w') as log:
        log.write(' '.join(shlex.quote(a) for a in args) + '\n' + proc.stdout)
    if proc.returncode != 0:
        raise RuntimeError('process_bag failed (%d): %s' % (proc.returncode, proc.stdout.strip().splitlines()[-1:]))
    info = {'seconds': seconds}
    m = re.search(r'pose correction: (\d+) particles, (\d+) updates, (\d+) resamplings', proc.stdout)
    if m:
        info.update(particles=int(m.group(1)), updates=int(m.group(2)), resamplings=int(m.group(3)))
    m = re.search(r'processed in ([0-9.]+) s', proc.stdout)
    if m:
        info['mapping_seconds'] = float(m.group(1))
    m = re.search(r'pose filter: N_eff median ([0-9.]+) \(min ([0-9.]+), max ([0-9.]+)\).*?; (\d+) particle-updates '
                  r'refused by the guard; ([0-9.]+) ms per update', proc.stdout)
    if m:
        info.update(n_eff_median=float(m.group(1)), n_eff_min=float(m.group(2)), n_eff_max=float(m.group(3)),
                    guard_refusals=int(m.group(4)), update_ms=float(m.group(5)))
    path = os.path.join(out_dir, 'trajectory.tum')
    return path, info


# ----------------------------------------------------------------------------- scoring

def score(data, estimates, min_segment_m, min_poses):
    """estimates: {name: (stamps, poses)}; all scored on the stamps of the first. Returns
    (segments, totals): per segment its index, time span, length, poses and ATE per name."""
    first = next(iter(estimates))
    stamps = estimates[first][0]
    lookups = {}
    for name, (st, po) in estimates.items():
        lookups[name] = dict(zip(st, po)) if name == first else Interpolated(st, po)
    by_segment = {}
    for stamp in stamps:
        by_segment.setdefault(segment_index(data, stamp), []).append(stamp)
    segments = []
    for index in sorted(by_segment):
        seg = by_segment[index]
        reference = [reference_at(data, s)[:2] for s in seg]
        length = path_length(reference)
        row = {'index': index, 'start': seg[0], 'end': seg[-1], 'poses': len(seg), 'length_m': length,
               'scored': length >= min_segment_m and len(seg) >= min_poses, 'ate': {}}
        if row['scored']:
            for name in estimates:
                look = lookups[name]
                est = [(look[s] if isinstance(look, dict) else look.at(s))[:2] for s in seg]
                row['ate'][name] = ate(est, reference)
        segments.append(row)
    scored = [s for s in segments if s['scored']]
    total_length = sum(s['length_m'] for s in scored)
    totals = {}
    for name in estimates:
        totals[name] = (sum(s['length_m'] * s['ate'][name] for s in scored) / total_length
                        if total_length > 0 else float('nan'))
    return segments, totals, total_length


def fmt(value, digits=3):
    return '–' if value is None or (isinstance(value, float) and math.isnan(value)) else '%.*f' % (digits, value)


def filter_columns(info, updates):
    """N_eff, resamplings, log-likelihood spread, ms per update as table text."""
    cols = {}
    if updates:
        n_eff = np.array([u['n_eff'] for u in updates])
        spread = np.array([u['ll_max'] - u['ll_min'] for u in updates])
        gap = np.array([u['ll_max'] - u['ll_second'] for u in updates])
        cols['n_eff'] = '%.1f (%.1f–%.1f)' % (np.median(n_eff), n_eff.min(), n_eff.max())
        cols['spread'] = '%.0f / %.0f' % (np.median(spread), np.median(gap))
        cols['ms'] = '%.0f' % np.median([u['ms'] for u in updates])
        cols['resamplings'] = '%d / %d' % (sum(u['resampled'] for u in updates), len(updates))
    elif info.get('updates'):
        cols['resamplings'] = '%d / %d' % (info['resamplings'], info['updates'] - 1)
        if 'update_ms' in info:
            cols['ms'] = '%.0f' % info['update_ms']
        elif info.get('mapping_seconds'):
            cols['ms'] = '≤ %.0f' % (1000.0 * info['mapping_seconds'] / info['updates'])
        if 'n_eff_median' in info:
            cols['n_eff'] = '%.1f (%.1f–%.1f)' % (info['n_eff_median'], info['n_eff_min'], info['n_eff_max'])
    return cols


def main(argv=None):
    argv = list(sys.argv[1:] if argv is None else argv)
    extra = []
    if '--' in argv:
        cut = argv.index('--')
        argv, extra = argv[:cut], argv[cut + 1:]
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('bags', nargs='+', metavar='BAG')
    parser.add_argument('--process-bag', help='the process_bag binary (default: on PATH, else rosrun)')
    parser.add_argument('--out', default='pose_ate_output', help='process_bag output directories (DIR/<bag name>)')
    parser.add_argument('--trajectory', help="the filter's TUM trajectory (one bag only): process_bag is not run")
    parser.add_argument('--filter-log', help="an instrumented build's per-scan log (one bag only)")
    parser.add_argument('--no-filter', action='store_true', help='odometry only, at every scan')
    parser.add_argument('--jump-m', type=float, default=0.5)
    parser.add_argument('--jump-rad', type=float, default=0.3)
    parser.add_argument('--min-segment-m', type=float, default=1.0)
    parser.add_argument('--min-poses', type=int, default=3)
    parser.add_argument('--offset', type=float, help='replay clock minus the scans\' clock, s (default: measured)')
    parser.add_argument('--segments', action='store_true', help='also one row per segment')
    parser.add_argument('--no-header', action='store_true')
    args = parser.parse_args(argv)
    if (args.trajectory or args.filter_log) and len(args.bags) != 1:
        parser.error('--trajectory and --filter-log take one bag')
    command = None
    if not args.no_filter and not args.trajectory:
        if args.process_bag:
            command = [args.process_bag]
        elif shutil.which('process_bag'):
            command = [shutil.which('process_bag')]
        elif shutil.which('rosrun'):
            command = ['rosrun', 'dynamic_occupancy_grid', 'process_bag']
        else:
            parser.error('no process_bag: give --process-bag PATH or source the workspace')

    if not args.no_header:
        print('| bag | segments scored / all | length scored (m) | ATE odometry (m) | ATE filter (m) |'
              ' ATE filter online (m) | filter updates, resampled | N_eff median (min–max) |'
              ' log-lik. spread / gap to 2nd (nats, median) | ms per update |')
        print('|---|---|---|---|---|---|---|---|---|---|')
    failed = False
    for bag in args.bags:
        name = os.path.splitext(os.path.basename(bag))[0]
        try:
            data = read_bag(bag, args.jump_m, args.jump_rad, args.offset)
            info, estimates, updates = {}, {}, []
            trajectory = args.trajectory
            out_dir = os.path.join(args.out, name)
            if command is not None:
                os.makedirs(out_dir, exist_ok=True)
                trajectory, info = run_process_bag(command, bag, out_dir, extra)
            log_path = args.filter_log or os.path.join(out_dir, 'filter_log.csv')
            if trajectory:
                stamps, poses = read_tum(trajectory)
                estimates['filter'] = (stamps, poses)
                estimates['odometry'] = (stamps, [data.odom.at(s) for s in stamps])
            else:
                stamps = data.scan_stamps
                estimates['odometry'] = (stamps, [data.odom.at(s) for s in stamps])
            online = None
            if not args.no_filter and os.path.exists(log_path):
                o_stamps, o_poses, updates = read_filter_log(log_path)
                online = (o_stamps, o_poses)
            segments, totals, length = score(data, estimates, args.min_segment_m, args.min_poses)
            online_total = float('nan')
            if online:
                # per scan: odometry and the online estimate on every scan the filter saw
                o_est = {'filter online': online, 'odometry at scans': (online[0], [data.odom.at(s) for s in online[0]])}
                o_segments, o_totals, _ = score(data, o_est, args.min_segment_m, args.min_poses)
                online_total = o_totals['filter online']
                info['odometry_at_scans'] = o_totals['odometry at scans']
            cols = filter_columns(info, updates)
            scored = [s for s in segments if s['scored']]
            print('| %s | %d / %d | %.1f | %s | %s | %s | %s | %s | %s | %s |' % (
                name, len(scored), len(segments), length, fmt(totals.get('odometry')), fmt(totals.get('filter')),
                fmt(online_total) + ((' (odometry %s)' % fmt(info['odometry_at_scans'])) if online else ''),
                cols.get('resamplings', '–'), cols.get('n_eff', '–'), cols.get('spread', '–'), cols.get('ms', '–')))
            if args.segments:
                for s in segments:
                    print('|   segment %d (%.1f–%.1f s, %d poses) | %s | %.1f | %s | %s | | | | | |' % (
                        s['index'], s['start'] - data.scan_stamps[0], s['end'] - data.scan_stamps[0], s['poses'],
                        'scored' if s['scored'] else 'not scored', s['length_m'], fmt(s['ate'].get('odometry')),
                        fmt(s['ate'].get('filter'))))
            sys.stderr.write('%s: offset %.3f s, %d map -> odom messages dropped (other clock), %d jumps: %s\n' % (
                name, data.offset_s, data.map_odom_dropped, len(data.jumps),
                ', '.join('%.1f s %.2f m %.2f rad' % (j[0] - data.scan_stamps[0], j[1], j[2]) for j in data.jumps)))
        except Exception as e:  # noqa: BLE001 (rosbag raises its own kinds): the row says why
            failed = True
            print('| %s | failed: %s | | | | | | | | |' % (name, str(e).replace('|', '/')))
    return 1 if failed else 0


if __name__ == '__main__':
    sys.exit(main())
