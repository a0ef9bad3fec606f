#!/usr/bin/env python3
"""Writes the hand-made seeds of the fuzz corpus (test/fuzz/corpus/, docs/reliability.md):
for model_reader the model process_bag maps from a tiny bag (three scans of 16 beams, /tf
and /tf_static), named by its format version (three_scans_v<N>.dogm: the seeds of older
versions stay, as files of those versions are still read), and command lines for
command_line. The rest of each corpus is what a
fuzzing run kept (libFuzzer -merge=1); scan_integrate and bag_scan_source read structured
inputs (FuzzedDataProvider) that only such runs make.

usage: make_seeds.py PROCESS_BAG   (the built tool, e.g. ~/dog_ws/devel/lib/dynamic_occupancy_grid/process_bag)
"""
import math
import os
import struct
import subprocess
import sys
import tempfile

import rosbag
import rospy
from geometry_msgs.msg import TransformStamped
from sensor_msgs.msg import LaserScan
from tf2_msgs.msg import TFMessage

CORPUS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "corpus")


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


def write_bag(path):
    with rosbag.Bag(path, "w") as bag:
        start = rospy.Time(1000)
        bag.write("/tf_static", TFMessage([transform(start, "base_link", "laser", 0.1, 0.0, 0.0)]), start)
        for k in range(3):
            stamp = start + rospy.Duration(0.5 * k)
            bag.write("/tf", TFMessage([transform(stamp, "odom", "base_link", 0.2 * k, 0.0, 0.1 * k)]), stamp)
            scan = LaserScan()
            scan.header.stamp = stamp
            scan.header.frame_id = "laser"
            scan.angle_min = -1.5
            scan.angle_increment = 0.2
            scan.angle_max = scan.angle_min + 15 * scan.angle_increment
            scan.range_min = 0.1
            scan.range_max = 5.0
            scan.ranges = [1.0 + 0.1 * i for i in range(14)] + [float("inf"), float("nan")]
            bag.write("/scan", scan, stamp)


def main():
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    with tempfile.TemporaryDirectory() as out:
        bag_path = os.path.join(out, "three_scans.bag")
        write_bag(bag_path)
        model_path = os.path.join(out, "three_scans.dogm")
        subprocess.run([sys.argv[1], bag_path, "--out", out, "--model", model_path, "--resolution", "1.0"],
                       check=True, stdout=subprocess.DEVNULL)
        with open(model_path, "rb") as model:
            data = model.read()
        (version,) = struct.unpack_from("<I", data, 8)  # docs/model_format.md
        with open(os.path.join(CORPUS, "model_reader", f"three_scans_v{version}.dogm"), "wb") as seed:
            seed.write(data)
    command_lines = {
        "process_bag": ["run.bag", "--resolution", "0.1", "--time-step", "0.5", "--laser-pose", "0,0,1.5",
                        "--em-iterations", "20", "--offline-em"],
        "time_range": ["a.bag", "b.bag", "--start-time", "1000", "--end-time", "2000", "--topic", "/front/scan",
                       "--fixed-frame", "map", "--max-range", "12"],
        "sensor_model": ["--p-hit-given-occ", "0.8", "--p-hit-given-free", "0.1", "--prior-p-occ-given-free",
                         "0.02", "--mrf-temperature", "0.5", "--threads", "2", "--em-tolerance", "1e-3"],
        "help": ["--help"],
    }
    for name, arguments in command_lines.items():
        with open(os.path.join(CORPUS, "command_line", name), "wb") as seed:
            seed.write(b"\0".join(argument.encode() for argument in arguments))


if __name__ == "__main__":
    main()
