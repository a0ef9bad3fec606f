#!/usr/bin/env python3
"""Checks every relative link (and #anchor) in the given markdown files.

    python3 docs/check_links.py README.md docs/*.md BENCHMARKS.md

A link is relative to the file it is in; an anchor must be a heading of the target (GitHub's
slug: lower case, punctuation dropped, spaces to hyphens). Exit status 1 if one is broken."""
import os, re, sys

def slug(heading):
    s = heading.strip().lower()
    s = re.sub(r'[^\w\- ]', '', s)   # keeps letters, digits, _, -, space (GitHub)
    return s.replace(' ', '-')

def anchors(path):
    out, fence = set(), False
    for line in open(path, encoding='utf-8'):
        if line.startswith('```'):
            fence = not fence
        if not fence and re.match(r'#{1,6} ', line):
            out.add(slug(line.lstrip('#')))
    return out

bad = 0
for md in sys.argv[1:]:
    text = open(md, encoding="utf-8").read()
    text = re.sub(r'```.*?```', '', text, flags=re.S)      # no links in code blocks
    text = re.sub(r'`[^`\n]*`', lambda m: m.group(0) if '](' not in m.group(0) else '', text)
    for target in re.findall(r'\]\(([^)\s]+)\)', text):
        if re.match(r'[a-z]+://', target) or target.startswith('mailto:'):
            continue
        path, _, anchor = target.partition('#')
        full = os.path.normpath(os.path.join(os.path.dirname(md), path)) if path else md
        ok = os.path.exists(full)
        if ok and anchor and full.endswith('.md'):
            ok = anchor in anchors(full)
        print(('ok   ' if ok else 'BAD  ') + md + ': ' + target)
        bad += not ok
print(f'{bad} broken')
sys.exit(1 if bad else 0)
