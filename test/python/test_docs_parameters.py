#!/usr/bin/env python3
"""Keeps the parameter documentation in step with the code.

docs/parameters.md's node table (the table under "### Parameters", rows `~name`) against:
  - config/dynamic_occupancy_grid.yaml: every key (nested keys as a/b) has a row;
  - cfg/*.cfg: every dynamic_reconfigure parameter has a row;
  - src/ros/*.cpp: every row names a key the node reads (read.number("..."), ...,
    getParam("..."), param("...")), and every key the node reads has a row;
  - README.md's "The parameters people actually set": every row is in the node table, with
    the same default.

Plain unittest with /usr/bin/python3 (PyYAML), no build needed:
    /usr/bin/python3 test/python/test_docs_parameters.py [-v]
"""

import glob
import os
import re
import unittest

import yaml

ROOT = os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))
PARAMETERS_MD = os.path.join(ROOT, "docs", "parameters.md")
README = os.path.join(ROOT, "README.md")
CONFIG = os.path.join(ROOT, "config", "dynamic_occupancy_grid.yaml")


def text(path):
    with open(path, encoding="utf-8") as f:
        return f.read()


def table_after(path, heading):
    """The rows (lists of cells) of the first markdown table after the line `heading`, the
    header and the |---| line left out."""
    lines = text(path).split("\n")
    try:
        start = lines.index(heading)
    except ValueError:
        raise AssertionError(f"{os.path.relpath(path, ROOT)} has no heading {heading!r}")
    rows, in_table = [], False
    for line in lines[start + 1:]:
        if line.startswith("|"):
            in_table = True
            rows.append([cell.strip() for cell in re.split(r"(?<!\\)\|", line.strip())[1:-1]])
        elif in_table:
            break
        elif re.match(r"#{1,6} ", line):
            break
    if len(rows) < 3:
        raise AssertionError(f"no table after {heading!r} in {os.path.relpath(path, ROOT)}")
    return rows[0], rows[2:]


def names_in(cell):
    """The parameters a first cell names: `~a`, `~b`; `~x/a1` … `~x/a4` is a1..a4."""
    names = re.findall(r"`~([^`]+)`", cell)
    if "…" in cell and len(names) == 2:
        first = re.match(r"(.*?)(\d+)$", names[0])
        last = re.match(r"(.*?)(\d+)$", names[1])
        if first and last and first.group(1) == last.group(1):
            return [f"{first.group(1)}{i}" for i in range(int(first.group(2)), int(last.group(2)) + 1)]
    return names


def node_table():
    """{name: default cell} of docs/parameters.md's node table."""
    header, rows = table_after(PARAMETERS_MD, "### Parameters")
    assert header[:3] == ["parameter", "type, unit", "default"], header
    table = {}
    for row in rows:
        names = names_in(row[0])
        assert names, f"docs/parameters.md: a node table row without a `~name`: {row[0]!r}"
        for name in names:
            table[name] = row[2] if len(names) == 1 else None
    return table


def yaml_keys(node, prefix=""):
    keys = set()
    for key, value in node.items():
        if isinstance(value, dict):
            keys |= yaml_keys(value, prefix + str(key) + "/")
        else:
            keys.add(prefix + str(key))
    return keys


def keys_the_node_reads():
    pattern = re.compile(r'(?:\bread\.(?:number|integer|boolean|text|textList)|getParam(?:Cached)?|\bparam(?:<[^>]*>)?)'
                         r'\(\s*"([^"]+)"')
    keys = set()
    for path in sorted(glob.glob(os.path.join(ROOT, "src", "ros", "*.cpp"))):
        keys |= set(pattern.findall(text(path)))
    return {key.lstrip("~") for key in keys}


class DocsParameters(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.table = node_table()
        cls.read = keys_the_node_reads()

    def test_table_is_plausible(self):
        self.assertGreater(len(self.table), 50)
        self.assertGreater(len(self.read), 50, "the pattern no longer finds the node's parameter reads")

    def test_every_yaml_key_is_documented(self):
        with open(CONFIG, encoding="utf-8") as f:
            keys = yaml_keys(yaml.safe_load(f))
        self.assertGreater(len(keys), 20)
        missing = sorted(keys - set(self.table))
        self.assertEqual(missing, [], "keys of config/dynamic_occupancy_grid.yaml without a row in docs/parameters.md")

    def test_every_reconfigure_parameter_is_documented(self):
        cfgs = sorted(glob.glob(os.path.join(ROOT, "cfg", "*.cfg")))
        self.assertTrue(cfgs)
        names = set()
        for path in cfgs:
            names |= set(re.findall(r"""\.add\(\s*['"]([^'"]+)['"]""", text(path)))
        self.assertTrue(names)
        missing = sorted(names - set(self.table))
        self.assertEqual(missing, [], "cfg/*.cfg parameters without a row in docs/parameters.md")

    def test_every_row_is_read_by_the_node(self):
        extra = sorted(set(self.table) - self.read)
        self.assertEqual(extra, [], "docs/parameters.md rows the node does not read (src/ros/*.cpp)")

    def test_every_key_the_node_reads_is_documented(self):
        missing = sorted(self.read - set(self.table))
        self.assertEqual(missing, [], "keys the node reads (src/ros/*.cpp) without a row in docs/parameters.md")

    def test_readme_rows_are_in_the_table(self):
        header, rows = table_after(README, "## The parameters people actually set")
        self.assertEqual(header[:2], ["parameter", "default"])
        self.assertGreaterEqual(len(rows), 10)
        for row in rows:
            names = names_in(row[0])
            self.assertTrue(names, f"README: a row without a `~name`: {row[0]!r}")
            for name in names:
                self.assertIn(name, self.table, f"README's ~{name} is not in docs/parameters.md")
                if len(names) == 1 and self.table[name] is not None:
                    self.assertEqual(row[1], self.table[name], f"README's default of ~{name}")


if __name__ == "__main__":
    unittest.main()
