#!/usr/bin/env python3
"""Turns a sanitized test run into JUnit files for scripts/test.sh's summary.

usage: collect_results.py RESULTS_IN REPORTS_DIR RESULTS_OUT

Copies every JUnit file under RESULTS_IN to RESULTS_OUT with "sanitized." before each
testcase's classname (so that a failure names the sanitized run), and writes
RESULTS_OUT/sanitizer_reports.xml: one failing testcase per report file the sanitizers left
in REPORTS_DIR (ASAN_OPTIONS / UBSAN_OPTIONS log_path), with the report as its message, or
one passing testcase when there are none. A report fails the run even when the test that
caused it passed (a node's report does not fail the Python test that launched it).
Exits 1 when there was a report.
"""
import glob
import os
import sys
import xml.etree.ElementTree as ET


def main():
    if len(sys.argv) != 4:
        sys.exit(__doc__)
    results_in, reports_dir, results_out = sys.argv[1:]
    os.makedirs(results_out, exist_ok=True)
    for path in sorted(glob.glob(os.path.join(results_in, "**", "*.xml"), recursive=True)):
        name = os.path.relpath(path, results_in).replace(os.sep, "_")
        try:
            tree = ET.parse(path)
        except ET.ParseError:
            # Left for the summary, which counts an unreadable file as a failure.
            with open(path, "rb") as source, open(os.path.join(results_out, name), "wb") as copy:
                copy.write(source.read())
            continue
        for case in tree.getroot().iter("testcase"):
            case.set("classname", "sanitized." + case.get("classname", ""))
        tree.write(os.path.join(results_out, name), encoding="utf-8", xml_declaration=True)

    reports = sorted(glob.glob(os.path.join(reports_dir, "*")))
    suite = ET.Element("testsuite", name="sanitizer_reports", tests=str(max(1, len(reports))),
                       failures=str(len(reports)))
    if not reports:
        ET.SubElement(suite, "testcase", classname="sanitized", name="no_sanitizer_reports")
    for report in reports:
        case = ET.SubElement(suite, "testcase", classname="sanitized.report", name=os.path.basename(report))
        with open(report, errors="replace") as text:
            body = text.read()
        failure = ET.SubElement(case, "failure", message=body.strip().splitlines()[0] if body.strip() else "empty")
        failure.text = body[:20000]
        print(f"sanitizer report {report}:\n{body[:4000]}", file=sys.stderr)
    ET.ElementTree(suite).write(os.path.join(results_out, "sanitizer_reports.xml"), encoding="utf-8",
                                xml_declaration=True)
    return 1 if reports else 0


if __name__ == "__main__":
    sys.exit(main())
