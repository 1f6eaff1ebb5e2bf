#!/usr/bin/python3
"""Checks that every link to an anchor of a Markdown file (FILE.md#ANCHOR or
#ANCHOR within the file) names a heading of that file, with GitHub's rule
for heading anchors: lower case; letters, marks, numbers (⁶ too), '_',
'-' and spaces kept, everything else dropped; spaces become '-'; the k-th
repeat of a heading gets '-k'.  Headings inside ``` fences do not count.

Usage: doc_anchors.py FILE.md...   Prints each broken link as
'FILE: TARGET' and the count; exits 1 if there is one."""
import os
import re
import sys
import unicodedata


def slug(text):
    text = re.sub(r"\[([^]]*)\]\([^)]*\)", r"\1", text)  # [text](link)
    out = [c for c in text.strip().lower()
           if c in " -_" or unicodedata.category(c)[0] in "LM"
           or unicodedata.category(c)[0] == "N"]
    return "".join(out).replace(" ", "-")


def anchors(path, cache={}):
    if path not in cache:
        seen, found, fence = {}, set(), False
        for line in open(path, encoding="utf-8"):
            if line.startswith("```"):
                fence = not fence
            m = None if fence else re.match(r"^#{1,6}\s+(.*?)\s*$", line)
            if m:
                s = slug(m.group(1))
                k = seen.get(s, 0)
                seen[s] = k + 1
                found.add(s if k == 0 else "%s-%d" % (s, k))
        cache[path] = found
    return cache[path]


def main():
    bad = checked = 0
    for path in sys.argv[1:]:
        text = open(path, encoding="utf-8").read()
        for target in re.findall(r"\]\(([^) ]+)\)", text):
            if target.startswith(("http:", "https:", "mailto:")) \
                    or "#" not in target:
                continue
            file, anchor = target.split("#", 1)
            dest = os.path.join(os.path.dirname(path), file) if file else path
            if not dest.endswith(".md") or not os.path.isfile(dest):
                continue  # a missing file is the link check's to report
            checked += 1
            if anchor not in anchors(dest):
                print("%s: %s" % (path, target))
                bad += 1
    print("%d anchors checked, %d broken" % (checked, bad))
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
