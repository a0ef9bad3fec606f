#!/usr/bin/env python3
"""Checks of the package's rviz configuration and launch files, without the mapping node.

Used by check_rviz_config.sh (which starts roscore and rviz under Xvfb and calls the rviz
sub-commands) and check_launch_files.sh (launch sub-command). Every sub-command prints what
it found and exits 0 when the check passes, 1 when it fails; `junit` turns a results
directory into one JUnit XML file.
"""
import argparse
import glob
import math
import os
import re
import subprocess
import sys
import time
import xml.dom.minidom
import xml.etree.ElementTree as ET

import yaml

NODE_NS = "/dynamic_occupancy_grid"
# Every layer the node publishes: rviz colour scheme, enabled by default.
LAYERS = {
    "belief": ("map", True),
    "predicted": ("map", False),
    "stationary": ("map", False),
    "p_occ_given_free": ("costmap", False),
    "p_free_given_occ": ("costmap", False),
    "static_map": ("map", True),
    # The memory model's stores (~model memory or both).
    "ltm": ("map", False),
    "stm": ("map", False),
}
SCAN_TOPIC = "/scan"
FIXED_FRAME = "map"
PACKAGE_DIR = os.path.abspath(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))
# The view follows the robot's base (REP 105's base_link), so a bag whose robot drives far
# from the fixed frame's origin stays in view; rviz follows the frame's position, not its yaw.
# Where there is no base_link (the bundled example: a stationary laser), the view stays at the
# fixed frame's origin.
VIEW_TARGET_FRAME = "base_link"
# The map demo.launch builds (the bundled example in the frame map, 0.05 m cells, the laser at
# the origin): x -3.2..6.4 m, y -6.4..6.4 m. The view must show all of it in the render
# panel of rviz's default window (about 540 x 680 px, measured under Xvfb).
DEMO_MAP_BOX = (-3.2, 6.4, -6.4, 6.4)
RENDER_PANEL_PX = (540, 680)
# Panels are built into rviz, not declared as plugins.
BUILTIN_PANELS = {"rviz/Displays", "rviz/Help", "rviz/Selection", "rviz/Time",
                  "rviz/Tool Properties", "rviz/Views"}
# rviz 1.14 derives a Map display's update topic from its Topic and does not save the key;
# the configuration keeps it to document the pairing (checked against Topic below).
KEYS_RVIZ_DROPS = {("rviz/Map", "Update Topic")}
# Layout keys that depend on the (virtual) screen, not on the configuration.
LAYOUT_KEYS = {"Window Geometry", "Tree Height", "Splitter Ratio", "Help Height"}
# Lines rviz prints on every start on Debian: it asks rospack for the media_export package
# (ROS's way of adding Ogre media), which Debian does not ship. Harmless.
BENIGN_LOG_LINES = {
    "[rospack] Error: no such package media_export",
    "[librospack]: error while executing command",
}
SUSPICIOUS = re.compile(
    r"\[ *(ERROR|FATAL) *\]|\berror\b|\bfatal\b|failed|failure|exception|could not|"
    r"cannot|segmentation|abort|terminate called|traceback|yaml",
    re.IGNORECASE)
ANSI = re.compile(r"\x1b\[[0-9;]*m")


def fail(messages):
    for message in messages:
        print("FAIL:", message)
    return 1 if messages else 0


# --- rviz ------------------------------------------------------------------------------------

def load_rviz_config(path):
    with open(path) as stream:
        config = yaml.safe_load(stream)
    if not isinstance(config, dict) or not isinstance(config.get("Visualization Manager"), dict):
        raise ValueError(f"{path}: no 'Visualization Manager' mapping: not an rviz config")
    return config


def all_displays(displays):
    """Displays in order, the contents of rviz/Group displays included."""
    for display in displays or []:
        yield display
        if isinstance(display, dict) and display.get("Class") == "rviz/Group":
            yield from all_displays(display.get("Displays"))


def declared_rviz_classes():
    """Class names of every plugin description exported for rviz (rviz's own and others')."""
    out = subprocess.run(["rospack", "plugins", "--attrib=plugin", "rviz"], check=True,
                         capture_output=True, text=True).stdout
    classes = set()
    for line in out.splitlines():
        parts = line.split(maxsplit=1)
        if len(parts) == 2 and os.path.isfile(parts[1]):
            for element in ET.parse(parts[1]).getroot().iter("class"):
                classes.add(element.get("name") or element.get("type"))
    return classes


def static_rviz_problems(path):
    try:
        config = load_rviz_config(path)
    except (OSError, yaml.YAMLError, ValueError) as error:
        return [f"cannot read {path} as an rviz config: {error}"]
    problems = []
    manager = config["Visualization Manager"]
    frame = (manager.get("Global Options") or {}).get("Fixed Frame")
    if frame != FIXED_FRAME:
        problems.append(f"Fixed Frame is {frame!r}, expected {FIXED_FRAME!r}")
    problems += frame_and_view_problems(frame, manager.get("Views") or {})
    displays = list(all_displays(manager.get("Displays")))
    if not all(isinstance(display, dict) for display in displays):
        return problems + ["a display is not a mapping"]
    maps = [d for d in displays if d.get("Class") == "rviz/Map"]
    for layer, (scheme, enabled) in LAYERS.items():
        topic = f"{NODE_NS}/{layer}"
        found = [d for d in maps if d.get("Topic") == topic]
        if len(found) != 1:
            problems.append(f"{len(found)} rviz/Map displays on {topic}, expected 1")
            continue
        display = found[0]
        if display.get("Color Scheme") != scheme:
            problems.append(f"{topic}: Color Scheme {display.get('Color Scheme')!r}, expected {scheme!r}")
        if display.get("Update Topic") != topic + "_updates":
            problems.append(f"{topic}: Update Topic {display.get('Update Topic')!r}, "
                            f"expected {topic + '_updates'!r}")
        for key in ("Enabled", "Value"):
            if display.get(key) is not enabled:
                problems.append(f"{topic}: {key} is {display.get(key)!r}, expected {enabled}")
    for display in maps:
        topic = display.get("Topic", "")
        if topic.startswith(NODE_NS + "/") and topic[len(NODE_NS) + 1:] not in LAYERS:
            problems.append(f"rviz/Map display on {topic}: the node publishes no such layer")
    for cls, topic in (("rviz/LaserScan", SCAN_TOPIC), ("rviz/TF", None), ("rviz/Grid", None)):
        found = [d for d in displays if d.get("Class") == cls and (topic is None or d.get("Topic") == topic)]
        if not found:
            problems.append(f"no {cls} display" + (f" on {topic}" if topic else ""))
        elif not any(d.get("Enabled") for d in found):
            problems.append(f"the {cls} display is disabled")
    declared = declared_rviz_classes()
    classes = [("display", d.get("Class")) for d in displays if d.get("Class") != "rviz/Group"]
    classes += [("tool", t.get("Class")) for t in manager.get("Tools") or []]
    views = manager.get("Views") or {}
    classes += [("view", (views.get("Current") or {}).get("Class"))]
    classes += [("view", v.get("Class")) for v in views.get("Saved") or []]
    for kind, cls in classes:
        if cls not in declared:
            problems.append(f"{kind} class {cls!r} is declared by no rviz plugin description")
    for panel in config.get("Panels") or []:
        if panel.get("Class") not in BUILTIN_PANELS | declared:
            problems.append(f"panel class {panel.get('Class')!r} is unknown")
    return problems


def frame_and_view_problems(frame, views):
    """The fixed frame is the default ~fixed_frame of the config and of replay.launch; the
    view is top-down, follows base_link and fits the map demo.launch builds."""
    problems = []
    defaults = {}
    for arg in ET.parse(os.path.join(PACKAGE_DIR, "launch", "replay.launch")).getroot().findall("arg"):
        if arg.get("name") == "fixed_frame":
            defaults["launch/replay.launch fixed_frame"] = arg.get("default")
    with open(os.path.join(PACKAGE_DIR, "config", "dynamic_occupancy_grid.yaml")) as file:
        defaults["config/dynamic_occupancy_grid.yaml fixed_frame"] = (yaml.safe_load(file) or {}).get("fixed_frame")
    for where, default in defaults.items():
        if default != frame:
            problems.append(f"Fixed Frame is {frame!r}, but the default of {where} is {default!r}")
    current = views.get("Current") or {}
    if current.get("Class") != "rviz/TopDownOrtho":
        return problems + [f"the view is {current.get('Class')!r}, expected rviz/TopDownOrtho"]
    if current.get("Target Frame") != VIEW_TARGET_FRAME:
        problems.append(f"the view's Target Frame is {current.get('Target Frame')!r}, expected "
                        f"{VIEW_TARGET_FRAME!r} (the view follows the robot)")
    try:
        scale, x, y = (float(current.get(key)) for key in ("Scale", "X", "Y"))
    except (TypeError, ValueError):
        return problems + ["the view has no numeric Scale, X, Y"]
    min_x, max_x, min_y, max_y = DEMO_MAP_BOX
    half_width, half_height = (px / 2.0 / scale if scale > 0 else 0.0 for px in RENDER_PANEL_PX)
    if not (x - half_width <= min_x and max_x <= x + half_width and
            y - half_height <= min_y and max_y <= y + half_height):
        problems.append(f"the view (centre {x}, {y}, {scale} px/m) does not show the demo map "
                        f"x {min_x}..{max_x}, y {min_y}..{max_y} in {RENDER_PANEL_PX[0]} x {RENDER_PANEL_PX[1]} px")
    elif scale < 0.7 * min(RENDER_PANEL_PX[0] / (max_x - min_x), RENDER_PANEL_PX[1] / (max_y - min_y)):
        problems.append(f"the view ({scale} px/m) shows the demo map smaller than 70 % of the panel")
    return problems


def cmd_static_rviz(args):
    problems = static_rviz_problems(args.config)
    if not problems:
        print(f"{args.config}: fixed frame {FIXED_FRAME}, a Map display for each of the "
              f"{len(LAYERS)} layers, LaserScan {SCAN_TOPIC}, TF, Grid; every class is declared")
    return fail(problems)


def expected_subscriptions():
    """Topics rviz must subscribe to with the config: those of the layers enabled by
    default (and their _updates), the scan, tf."""
    topics = {SCAN_TOPIC, "/tf", "/tf_static"}
    for layer, (_, enabled) in LAYERS.items():
        if enabled:
            topics |= {f"{NODE_NS}/{layer}", f"{NODE_NS}/{layer}_updates"}
    return topics


def send_file_path_service():
    """rviz/SendFilePath (rviz's save_config service) without rviz's Python messages, which
    Debian does not package: the two messages built from their definitions."""
    import genpy.dynamic
    request = genpy.dynamic.generate_dynamic(
        "rviz/SendFilePathRequest",
        "std_msgs/String path\n" + "=" * 80 + "\nMSG: std_msgs/String\nstring data\n",
    )["rviz/SendFilePathRequest"]
    response = genpy.dynamic.generate_dynamic(
        "rviz/SendFilePathResponse", "bool success\n")["rviz/SendFilePathResponse"]

    class SendFilePath:
        _type = "rviz/SendFilePath"
        _md5sum = "92f17244ff295b327b62c307fafe751b"  # of rviz 1.14's srv/SendFilePath.srv
        _request_class = request
        _response_class = response

    return SendFilePath


def cmd_probe_rviz(args):
    """Run while rviz is up: records in DIR whether its save_config service came up, which
    topics it subscribes to, and has it save its configuration to DIR/saved.rviz. Does not
    judge: rviz-loaded and rviz-subscriptions do."""
    import rosgraph.masterapi
    import rospy

    node = "/" + args.node.lstrip("/")
    service = node + "/save_config"
    master = rosgraph.masterapi.Master("/config_checks")
    expected = expected_subscriptions()
    facts = {"service_up": False, "subscribed": [], "saved": False, "notes": []}
    deadline = time.monotonic() + args.timeout
    settle_deadline = None
    while time.monotonic() < deadline:
        try:
            _, subscribers, services = master.getSystemState()
        except Exception:  # the master may still be starting
            time.sleep(0.5)
            continue
        facts["service_up"] = any(name == service for name, _ in services)
        subscribed = {topic for topic, nodes in subscribers if node in nodes}
        facts["subscribed"] = sorted(subscribed)
        if facts["service_up"]:
            # Once rviz is up, give its displays a few seconds to subscribe (a broken config
            # never does: wait no longer than that).
            settle_deadline = settle_deadline or time.monotonic() + args.settle
            if expected <= subscribed or time.monotonic() > settle_deadline:
                break
        time.sleep(0.5)
    if facts["service_up"]:
        time.sleep(1.0)  # let rviz finish creating displays before it saves
        rospy.init_node("config_checks", anonymous=True, disable_signals=True)
        SendFilePath = send_file_path_service()
        request = SendFilePath._request_class()
        saved = os.path.join(args.dir, "saved.rviz")
        request.path.data = os.path.abspath(saved)
        try:
            rospy.wait_for_service(service, timeout=5.0)
            response = rospy.ServiceProxy(service, SendFilePath)(request)
            facts["saved"] = bool(response.success) and os.path.isfile(saved)
        except (rospy.ROSException, rospy.ServiceException) as error:
            facts["notes"].append(f"calling {service}: {error}")
    with open(os.path.join(args.dir, "probe.yaml"), "w") as stream:
        yaml.safe_dump(facts, stream)
    print(yaml.safe_dump(facts))
    return 0


def cmd_rviz_loaded(args):
    """rviz came up with the config, was still running when stopped, and logged no error."""
    with open(os.path.join(args.dir, "probe.yaml")) as stream:
        facts = yaml.safe_load(stream)
    problems = []
    if not facts["service_up"]:
        problems.append("rviz's save_config service never came up: rviz did not start")
    if not os.path.isfile(os.path.join(args.dir, "alive")):
        problems.append("rviz was no longer running when the check stopped it (crashed?)")
    problems += log_problems(args.node, [os.path.join(args.dir, name) for name in
                                          ("rviz.err", "rviz.out", "rosout.log")])
    if not problems:
        print("rviz started with the config, ran until stopped, and logged no error")
    return fail(problems)


def cmd_rviz_subscriptions(args):
    """rviz subscribed to the topics of the displays enabled by default (belief, static_map
    and their _updates, the scan, tf), so they loaded, and to no topic of a disabled layer."""
    with open(os.path.join(args.dir, "probe.yaml")) as stream:
        facts = yaml.safe_load(stream)
    subscribed = set(facts["subscribed"])
    problems = []
    expected = expected_subscriptions()
    missing = sorted(expected - subscribed)
    if missing:
        problems.append(f"rviz did not subscribe to {', '.join(missing)} (displays not loaded?); "
                        f"it subscribes to {', '.join(sorted(subscribed)) or 'nothing'}")
    disabled = {f"{NODE_NS}/{layer}" for layer, (_, enabled) in LAYERS.items() if not enabled}
    extra = sorted(topic for topic in subscribed
                   if topic in disabled or topic.rsplit("_updates", 1)[0] in disabled)
    if extra:
        problems.append(f"rviz subscribes to layers that should be disabled: {', '.join(extra)}")
    if not problems:
        print(f"rviz subscribes to {', '.join(sorted(expected))}")
    return fail(problems)


def compare_values(original, saved, path, context_class, problems):
    if isinstance(original, dict):
        if not isinstance(saved, dict):
            problems.append(f"{path}: rviz saved {saved!r} where the config has a mapping")
            return
        context_class = original.get("Class", context_class)
        for key, value in original.items():
            if key in LAYOUT_KEYS:
                continue
            if key not in saved:
                if (context_class, key) not in KEYS_RVIZ_DROPS:
                    problems.append(f"{path}/{key}: rviz does not know this key (dropped on save)")
                continue
            compare_values(value, saved[key], f"{path}/{key}", context_class, problems)
    elif isinstance(original, list):
        if not isinstance(saved, list) or len(saved) != len(original):
            problems.append(f"{path}: {len(original)} entries, rviz saved "
                            f"{len(saved) if isinstance(saved, list) else saved!r}")
            return
        for index, (a, b) in enumerate(zip(original, saved)):
            name = a.get("Name", index) if isinstance(a, dict) else index
            compare_values(a, b, f"{path}[{name}]", context_class, problems)
    elif isinstance(original, (int, float)) and not isinstance(original, bool) \
            and isinstance(saved, (int, float)) and not isinstance(saved, bool):
        if not math.isclose(original, saved, rel_tol=1e-6, abs_tol=1e-9):
            problems.append(f"{path}: {original!r} became {saved!r}")
    elif original != saved and not (original is None and saved in ({}, [], "")):
        problems.append(f"{path}: {original!r} became {saved!r}")


def cmd_compare_rviz(args):
    """Every key of the config is one rviz knows (it saves every property it has, and
    silently ignores unknown ones), and rviz kept every value."""
    try:
        original = load_rviz_config(args.config)
    except (OSError, yaml.YAMLError, ValueError) as error:
        return fail([f"cannot read {args.config}: {error}"])
    try:
        with open(args.saved) as stream:
            saved = yaml.safe_load(stream)
    except (OSError, yaml.YAMLError) as error:
        return fail([f"cannot read what rviz saved ({args.saved}): {error}"])
    problems = []
    compare_values(original, saved, "", None, problems)
    if not problems:
        print(f"rviz saved the configuration back with every key and value of {args.config}")
    return fail(problems)


def log_problems(node, paths):
    """Lines that look like errors in rviz's output and in rosout's log of the rviz node."""
    problems = []
    for path in paths:
        if not os.path.isfile(path):
            continue
        with open(path, errors="replace") as stream:
            for number, line in enumerate(stream, 1):
                line = ANSI.sub("", line).strip()
                if path.endswith("rosout.log") and f" /{node} " not in line:
                    continue
                if line in BENIGN_LOG_LINES or not SUSPICIOUS.search(line):
                    continue
                problems.append(f"{os.path.basename(path)}:{number}: {line[:600]}")
    return problems


# --- launch files ----------------------------------------------------------------------------

SUBSTITUTION = re.compile(r"\$\((\w+)\s*([^)]*)\)")


def launch_args_problems(path, package_dir):
    """Lint that roslaunch does not do for branches it skips: every $(arg X) / arg('X') is
    declared in the file, every declared arg is used and documented, every <include> passes
    only args the included file declares, every $(find pkg) names a package the package
    depends on and a file that exists."""
    problems = []
    document = xml.dom.minidom.parse(path)
    declared = {}
    for element in document.getElementsByTagName("arg"):
        if element.parentNode.tagName == "include":
            continue
        name = element.getAttribute("name")
        if name in declared:
            problems.append(f"arg {name!r} declared twice")
        declared[name] = element
        if not element.getAttribute("doc"):
            problems.append(f"arg {name!r} has no doc")
    used = set()
    with open(path) as stream:
        text = stream.read()
    for kind, rest in SUBSTITUTION.findall(text):
        if kind == "arg":
            used.add(rest.strip())
    used |= set(re.findall(r"\barg\('(\w+)'\)", text))
    for name in sorted(used - set(declared)):
        problems.append(f"$(arg {name}) is used but not declared")
    for name in sorted(set(declared) - used):
        problems.append(f"arg {name!r} is declared but never used")
    dependencies = package_dependencies(package_dir)
    package = package_name(package_dir)
    for kind, rest in SUBSTITUTION.findall(text):
        if kind != "find":
            continue
        pkg = rest.strip()
        if pkg != package and pkg not in dependencies:
            problems.append(f"$(find {pkg}): {pkg} is not a dependency in package.xml")
    for match in re.finditer(r"\$\(find " + re.escape(package) + r"\)(/[^\s\"'<>)]*)", text):
        if not os.path.exists(package_dir + match.group(1)):
            problems.append(f"$(find {package}){match.group(1)} does not exist")
    for include in document.getElementsByTagName("include"):
        target = include.getAttribute("file")
        prefix = f"$(find {package})"
        if not target.startswith(prefix):
            continue
        target_path = package_dir + target[len(prefix):]
        if not os.path.isfile(target_path):
            continue  # reported above
        included = {a.getAttribute("name") for a in xml.dom.minidom.parse(target_path)
                    .getElementsByTagName("arg") if a.parentNode.tagName != "include"}
        for passed in include.getElementsByTagName("arg"):
            if passed.getAttribute("name") not in included:
                problems.append(f"<include {os.path.basename(target_path)}> passes arg "
                                f"{passed.getAttribute('name')!r}, which it does not declare")
    return problems


def package_name(package_dir):
    return ET.parse(os.path.join(package_dir, "package.xml")).getroot().findtext("name").strip()


def package_dependencies(package_dir):
    root = ET.parse(os.path.join(package_dir, "package.xml")).getroot()
    tags = ("depend", "exec_depend", "run_depend", "test_depend")
    return {element.text.strip() for tag in tags for element in root.iter(tag)}


def declared_nodelets(package_dir):
    """Nodelet classes the package exports (package.xml <export><nodelet plugin=...>)."""
    root = ET.parse(os.path.join(package_dir, "package.xml")).getroot()
    classes = set()
    for export in root.iter("export"):
        for element in export.iter("nodelet"):
            plugin = element.get("plugin", "").replace("${prefix}", package_dir)
            if os.path.isfile(plugin):
                classes |= {c.get("name") for c in ET.parse(plugin).getroot().iter("class")}
    return classes


def launch_variant_problems(path, argv, package_dir):
    """roslaunch's own loader with these args (parses, resolves every substitution and
    include, loads rosparam files), then what roslaunch-check checks for the nodes it
    would start (package found and declared in package.xml, executable found), every
    nodelet class of the package declared, and every file of the package a node is given."""
    import roslaunch.config
    import roslaunch.core
    import roslib.packages
    import rospkg

    try:
        config = roslaunch.config.load_config_default([(path, argv)], None, verbose=False)
    except Exception as error:  # RLException, and the loader's own bugs (TypeError, ...)
        return [f"roslaunch cannot load it: {type(error).__name__}: {error}".strip()]
    problems = []
    rospack = rospkg.RosPack()
    package = package_name(package_dir)
    dependencies = package_dependencies(package_dir) | {package}
    nodelets = None
    for node in config.nodes:
        if node.package not in dependencies:
            problems.append(f"node {node.name}: package {node.package} is not a dependency in "
                            "package.xml (exec_depend)")
        try:
            if not roslib.packages.find_node(node.package, node.type, rospack=rospack):
                problems.append(f"node {node.name}: no executable {node.type} in {node.package} "
                                "(not built, or a typo)")
        except rospkg.ResourceNotFound as error:
            problems.append(f"node {node.name}: package not found: {error}")
        words = node.args.split()
        if node.package == "nodelet" and words[:1] in (["load"], ["standalone"]):
            nodelets = declared_nodelets(package_dir) if nodelets is None else nodelets
            cls = words[1] if len(words) > 1 else ""
            if cls.startswith(package + "/") and cls not in nodelets:
                problems.append(f"node {node.name}: nodelet {cls} is not declared in the "
                                f"package's nodelet plugin description ({sorted(nodelets)})")
        for word in words:
            if word.startswith(package_dir + os.sep) and not os.path.exists(word):
                problems.append(f"node {node.name}: {word} does not exist")
    if not problems:
        nodes = ", ".join(f"{n.name} ({n.package}/{n.type})" for n in config.nodes)
        params = sorted(name for name in config.params if name.startswith(NODE_NS + "/"))
        print(f"loaded with {' '.join(argv) or 'the defaults'}: nodes {nodes}; "
              f"{len(params)} parameters of the mapper ({', '.join(params)})")
    return problems


def cmd_launch(args):
    """One sub-check of one launch file: xml, args (lint) or load (roslaunch's loader with
    the given args, then what roslaunch-check checks: packages, executables, dependencies)."""
    package_dir = os.path.realpath(args.package_dir)
    path = args.file
    if args.check == "xml":
        try:
            root = xml.dom.minidom.parse(path).documentElement
        except Exception as error:
            return fail([f"not well-formed XML: {error}"])
        if root.tagName != "launch":
            return fail([f"root element is <{root.tagName}>, not <launch>"])
        print("well-formed XML with a <launch> root")
        return 0
    if args.check == "args":
        try:
            problems = launch_args_problems(path, package_dir)
        except Exception as error:
            problems = [f"cannot read: {error}"]
        if not problems:
            print("every arg used is declared, documented and used; includes and $(find) resolve")
        return fail(problems)
    return fail(launch_variant_problems(path, args.launch_args, package_dir))


# --- JUnit -----------------------------------------------------------------------------------

def cmd_junit(args):
    """results directory: per testcase NNN.status ("pass|fail SECONDS NAME") and NNN.log."""
    cases = sorted(glob.glob(os.path.join(args.results, "*.status")))
    suite = ET.Element("testsuite", name=args.suite, tests=str(len(cases)))
    failures = 0
    for status_path in cases:
        stem = status_path[:-len(".status")]
        with open(status_path) as stream:
            status, seconds, name = stream.read().strip().split(" ", 2)
        log = ""
        if os.path.isfile(stem + ".log"):
            with open(stem + ".log", errors="replace") as stream:
                log = stream.read()[-20000:]
        case = ET.SubElement(suite, "testcase", classname=args.suite, name=name,
                             time=seconds or "0")
        if status != "pass":
            failures += 1
            failure_lines = [l for l in log.splitlines() if l.startswith("FAIL")]
            message = (failure_lines[0] if failure_lines else "failed")[:500]
            ET.SubElement(case, "failure", message=message).text = log
        else:
            ET.SubElement(case, "system-out").text = log
    if not cases:  # a run that checked nothing must not look green
        failures += 1
        case = ET.SubElement(suite, "testcase", classname=args.suite, name="checks_ran", time="0")
        ET.SubElement(case, "failure", message=f"no testcase results in {args.results}")
        suite.set("tests", "1")
    suite.set("failures", str(failures))
    suite.set("errors", "0")
    os.makedirs(os.path.dirname(os.path.abspath(args.output)), exist_ok=True)
    ET.ElementTree(suite).write(args.output, encoding="utf-8", xml_declaration=True)
    print(f"{args.suite}: {len(cases)} testcases, {failures} failing, written to {args.output}")
    return 1 if failures else 0


def main():
    parser = argparse.ArgumentParser(description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("static-rviz")
    p.add_argument("config")
    p.set_defaults(run=cmd_static_rviz)
    p = sub.add_parser("probe-rviz")
    p.add_argument("node")
    p.add_argument("dir")
    p.add_argument("--timeout", type=float, default=60.0, help="for rviz to come up (s)")
    p.add_argument("--settle", type=float, default=10.0, help="then for its subscriptions (s)")
    p.set_defaults(run=cmd_probe_rviz)
    p = sub.add_parser("rviz-loaded")
    p.add_argument("node")
    p.add_argument("dir")
    p.set_defaults(run=cmd_rviz_loaded)
    p = sub.add_parser("rviz-subscriptions")
    p.add_argument("dir")
    p.set_defaults(run=cmd_rviz_subscriptions)
    p = sub.add_parser("compare-rviz")
    p.add_argument("config")
    p.add_argument("saved")
    p.set_defaults(run=cmd_compare_rviz)
    p = sub.add_parser("launch")
    p.add_argument("check", choices=["xml", "args", "load"])
    p.add_argument("package_dir")
    p.add_argument("file")
    p.add_argument("launch_args", nargs="*", help="name:=value")
    p.set_defaults(run=cmd_launch)
    p = sub.add_parser("junit")
    p.add_argument("suite")
    p.add_argument("results")
    p.add_argument("output")
    p.set_defaults(run=cmd_junit)
    args = parser.parse_args()
    sys.exit(args.run(args))


if __name__ == "__main__":
    main()
