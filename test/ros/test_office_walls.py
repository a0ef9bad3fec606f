#!/usr/bin/env python3
"""Walls stay walls: check_bag with the node's defaults on one of the office recordings in
../shared/data/real (a small robot driving through an office floor, mapped in its odom frame)
and the map at the end against the package's own clamped log-odds static map. Fails when the
belief, the stationary or the 60 s predicted layer keeps less than min_kept of the static map's
occupied or free cells (also on the cells last seen >= 10 s before the end), or when more than
max_walls_changing of its occupied cells are learned as changing (p_free_given_occ > 0.05).
The bag is read from ../shared next to the package's checkout, which CI has; without it the
test fails and says where it looked.
"""

import csv
import os
import subprocess
import tempfile
import unittest

import rospkg
import rospy
import rostest
from catkin.find_in_workspaces import find_in_workspaces

import wall_scene

PKG = "dynamic_occupancy_grid"


def data_dirs():
    """../shared/data/real next to the checkout: the package's path with symlinks resolved (a
    workspace links to the checkout) and as named."""
    package = rospkg.RosPack().get_path(PKG)
    dirs = []
    for path in (os.path.realpath(package), package):
        candidate = os.path.normpath(os.path.join(path, "..", "shared", "data", "real"))
        if candidate not in dirs:
            dirs.append(candidate)
    return dirs


class OfficeWalls(unittest.TestCase):
    @wall_scene.reported_set_up
    def setUpClass(cls):
        rospy.init_node("test_office_walls", anonymous=True)
        name = rospy.get_param("~bag")
        cls.min_kept = float(rospy.get_param("~min_kept"))
        cls.max_changing = float(rospy.get_param("~max_walls_changing"))
        bags = [os.path.join(d, name) for d in data_dirs()]
        bag = next((b for b in bags if os.path.isfile(b)), None)
        if bag is None:
            raise RuntimeError(f"{name} not found; looked in {', '.join(data_dirs())}")
        check_bag = find_in_workspaces(["libexec"], project=PKG, path="check_bag", first_match_only=True)
        if not check_bag:
            raise RuntimeError("check_bag not found in the catkin workspaces (built?)")
        with tempfile.TemporaryDirectory() as tmp:
            table = os.path.join(tmp, "check.csv")
            result = subprocess.run([check_bag[0], bag, "--fixed-frame", "odom", "--csv", table],
                                    capture_output=True, text=True, errors="replace", timeout=100)
            if result.returncode != 0:
                raise RuntimeError(f"check_bag failed ({result.returncode}): {result.stderr[-2000:]}")
            with open(table, newline="") as f:
                cls.end = {k: float(v) for k, v in next(csv.DictReader(f)).items() if k.startswith("end_")}
        cls.stdout = result.stdout

    def kept(self, kept, whole):
        self.assertGreater(self.end[whole], 100, whole)  # a real map, not an empty one
        return self.end[kept] / self.end[whole]

    def test_belief_keeps_walls_and_free_space(self):
        for kept, whole in (("end_kept_occupied", "end_static_occupied"), ("end_kept_free", "end_static_free")):
            self.assertGreaterEqual(self.kept(kept, whole), self.min_kept, f"{kept} / {whole}\n{self.stdout}")

    def test_belief_keeps_what_the_robot_left(self):
        for kept, whole in (("end_left_kept_occupied", "end_left_static_occupied"),
                            ("end_left_kept_free", "end_left_static_free")):
            self.assertGreaterEqual(self.kept(kept, whole), self.min_kept, f"{kept} / {whole}\n{self.stdout}")

    def test_stationary_and_predicted_layers_keep_them(self):
        for layer in ("stationary", "predicted"):
            for state in ("occupied", "free"):
                kept = f"end_{layer}_kept_{state}"
                self.assertGreaterEqual(self.kept(kept, f"end_static_{state}"), self.min_kept, f"{kept}\n{self.stdout}")

    def test_walls_are_not_learned_as_changing(self):
        share = self.end["end_occupied_changing"] / self.end["end_static_occupied"]
        self.assertLessEqual(share, self.max_changing, self.stdout)


if __name__ == "__main__":
    rostest.rosrun(PKG, "office_walls", OfficeWalls)
