#!/usr/bin/env python3
"""No function of the product's C++ runs over a line limit, except those on an allowlist that may only shrink.

Usage: check_function_length.py ROOT [--limit N] [--allow FILE] [--list]

Every function defined in ROOT's core, lab, components, recording and tools/cli sources (free, member, or inline in a
class body) is measured from the line its signature starts on to its closing brace; lambdas and local classes count in
the function that holds them. A function over the limit fails unless the allowlist names it
(`path name lines`), and then it fails if it grew past the listed length. An allowlisted function that is back within
the limit, or no longer exists, fails too: its line must leave the list, so the list only shrinks.
Exit 0 when all hold, 1 with one line per finding (path:line: ...), 2 on a usage error.
"""
import os
import re
import sys

FOLDERS = ["core", "lab", "components", "recording", os.path.join("tools", "cli")]
EXTENSIONS = (".cpp", ".hpp", ".h", ".cc")
TRANSPARENT = re.compile(r'^(?:inline\s+)?namespace\b|^extern\s+""')  # (strip() blanks the "C")
TYPE = re.compile(r"^(?:template\s*<.*>\s*)?(?:struct|class|union|enum)\b", re.S)


def strip(text):
    """Comments, string and character literals blanked, newlines kept (so line numbers hold)."""
    out, i, n = [], 0, len(text)
    while i < n:
        c = text[i]
        if text.startswith("//", i):
            j = text.find("\n", i)
            j = n if j < 0 else j
            i = j
        elif text.startswith("/*", i):
            j = text.find("*/", i + 2)
            j = n if j < 0 else j + 2
            out.append("".join(ch for ch in text[i:j] if ch == "\n"))
            i = j
        elif text.startswith('R"', i) and (i == 0 or not (text[i - 1].isalnum() or text[i - 1] == "_")):
            k = text.find("(", i)
            delim = ")" + text[i + 2:k] + '"'
            j = text.find(delim, k)
            j = n if j < 0 else j + len(delim)
            out.append('""' + "".join(ch for ch in text[i:j] if ch == "\n"))
            i = j
        elif c in "\"'" and not (c == "'" and i > 0 and text[i - 1].isalnum()):  # 1'000 digit separators
            j = i + 1
            while j < n and text[j] != c and text[j] != "\n":
                j += 2 if text[j] == "\\" else 1
            out.append(c + c)
            i = j + 1
        else:
            out.append(c)
            i += 1
    return "".join(out)


def functions(path):
    """(name, first line, last line) of each function defined in the file, outside other functions."""
    text = strip(open(path, encoding="utf-8", errors="replace").read())
    line_at = []  # the line of each offset
    line = 1
    for ch in text:
        line_at.append(line)
        line += ch == "\n"
    found = []
    stack = []  # per open brace: "transparent" (namespace, extern "C"), "function", "type" or "other"
    head_start = 0  # where the text before the next brace began (after the last ; { } or preprocessor line)
    current = None  # [name, first line, depth] while inside a function
    for i, ch in enumerate(text):
        if ch == "{":
            head = text[head_start:i].strip()
            if current is not None:
                kind = "other"
            elif TRANSPARENT.match(head):
                kind = "transparent"
            elif TYPE.match(head):
                kind = "type"
            elif all(k in ("transparent", "type") for k in stack) and "(" in head and not head.endswith("="):
                kind = "function"
            else:
                kind = "other"
            stack.append(kind)
            if kind == "function":
                m = re.search(r"([A-Za-z_~][\w:~]*(?:\s*operator\s*(?:\(\)|[^\s(]+))?)\s*\(", head)
                lead = len(text[head_start:i]) - len(text[head_start:i].lstrip())
                current = [m.group(1).replace(" ", "") if m else "(lambda)", line_at[head_start + lead], len(stack)]
            head_start = i + 1
        elif ch == "}":
            if stack:
                stack.pop()
            if current is not None and len(stack) < current[2]:
                rest = text[i + 1:i + 200].lstrip()
                if rest[:1] in (",", "{"):  # a member initialised with braces: the constructor's body is still to come
                    pass
                else:
                    found.append((current[0], current[1], line_at[i]))
                    current = None
            head_start = i + 1
        elif ch == ";":
            head_start = i + 1
        elif ch == "\n" and text[head_start:i].lstrip().startswith("#"):
            head_start = i + 1
    return found


def main(argv):
    args = argv[1:]
    if not args or args[0].startswith("-"):
        print(__doc__, file=sys.stderr)
        return 2
    root = args[0]
    limit = 120
    allow_file = None
    list_all = False
    k = 1
    while k < len(args):
        if args[k] == "--limit" and k + 1 < len(args):
            limit = int(args[k + 1])
            k += 2
        elif args[k] == "--allow" and k + 1 < len(args):
            allow_file = args[k + 1]
            k += 2
        elif args[k] == "--list":
            list_all = True
            k += 1
        else:
            print("check_function_length: unknown argument %s" % args[k], file=sys.stderr)
            return 2
    allowed = {}
    if allow_file:
        for n, raw in enumerate(open(allow_file, encoding="utf-8"), 1):
            line = raw.split("#", 1)[0].strip()
            if not line:
                continue
            parts = line.split()
            if len(parts) != 3 or not parts[2].isdigit():
                print("%s:%d: want `path function lines`, got %r" % (allow_file, n, raw.rstrip()), file=sys.stderr)
                return 2
            allowed[(parts[0], parts[1])] = (int(parts[2]), n)
    measured = {}
    for folder in FOLDERS:
        base = os.path.join(root, folder)
        for dirpath, dirnames, filenames in os.walk(base):
            dirnames.sort()
            for f in sorted(filenames):
                if not f.endswith(EXTENSIONS):
                    continue
                path = os.path.join(dirpath, f)
                rel = os.path.relpath(path, root)
                for name, first, last in functions(path):
                    measured.setdefault((rel, name), []).append((last - first + 1, first))
    findings = []
    for (rel, name), spans in sorted(measured.items()):
        for lines, first in spans:
            if list_all and lines > limit:
                print("%5d %s:%d %s" % (lines, rel, first, name))
            if lines <= limit:
                continue
            if (rel, name) in allowed:
                cap = allowed[(rel, name)][0]
                if lines > cap:
                    findings.append("%s:%d: %s is %d lines, more than the %d it is allowed (%s): shorten it"
                                    % (rel, first, name, lines, cap, allow_file))
            else:
                findings.append("%s:%d: %s is %d lines (limit %d): split it" % (rel, first, name, lines, limit))
    for (rel, name), (cap, n) in sorted(allowed.items()):
        spans = measured.get((rel, name), [])
        if not any(lines > limit for lines, _ in spans):
            now = max((lines for lines, _ in spans), default=0)
            why = "is %d lines now, within the limit" % now if spans else "no longer exists"
            findings.append("%s:%d: %s %s: take it off the list" % (allow_file, n, name, why))
        elif max(lines for lines, _ in spans) < cap:
            now = max(lines for lines, _ in spans)
            findings.append("%s:%d: %s is %d lines now, the list allows %d: lower it to %d"
                            % (allow_file, n, name, now, cap, now))
    for f in findings:
        print(f)
    return 1 if findings else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
