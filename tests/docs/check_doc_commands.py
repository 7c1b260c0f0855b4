#!/usr/bin/env python3
"""Every command the README and the doc pages show exists (issue 45).

Usage: check_doc_commands.py SOURCE_DIR BIN_DIR

Reads README.md, docs/*.md, messages/FRONTEND.md and every services/ and
tools/ README.md, and checks, in code (`...` spans and ``` blocks):
  - `tools/rekon X` and `rekon X`: X is one of tools/rekon's own commands or
    a command of the built `rekon` binary (its --help list);
  - `build/bin/NAME` and `rekon-NAME`: the program is in BIN_DIR;
  - a code block line that starts a program runs it as a user can: through
    tools/rekon, build/bin/, or a program on PATH (not a bare rekon-NAME,
    which is "command not found" until build/bin is on PATH).
  - every tools/... and tests/... script a code block runs exists.
Prints one line per problem naming the page and line, then a summary line;
exits 1 when any was found.
"""
import glob
import os
import re
import subprocess
import sys

SCRIPT_COMMANDS = {"demo", "test", "setup", "deps", "stress", "sanitize", "fuzz", "--help", "-h", "help"}


def rekon_commands(bin_dir):
    out = subprocess.run([os.path.join(bin_dir, "rekon"), "--help"], capture_output=True, text=True).stdout
    listed = out.split("commands:", 1)[1].split("\n\n", 1)[0]
    return {line.split()[0] for line in listed.splitlines() if line.strip()} | {"--version"}


def pages(src):
    found = [os.path.join(src, "README.md"), os.path.join(src, "messages", "FRONTEND.md")]
    found += sorted(glob.glob(os.path.join(src, "docs", "*.md")))
    for top in ("services", "tools"):
        found += sorted(glob.glob(os.path.join(src, top, "**", "README.md"), recursive=True))
    return [p for p in found if os.path.isfile(p)]


def code_pieces(text):
    """(line number, code, in a block) for every inline code span and every
    line of a fenced (```) or indented (4 spaces after a blank line) block."""
    in_fence = in_indented = False
    previous_blank = True
    for number, line in enumerate(text.splitlines(), 1):
        if line.lstrip().startswith("```"):
            in_fence = not in_fence
            continue
        in_indented = (not in_fence and line.startswith("    ") and (previous_blank or in_indented)
                       and not line.lstrip().startswith(("-", "*", "|")))
        previous_blank = not line.strip()
        if in_fence or in_indented:
            yield number, line, True
        else:
            for span in re.findall(r"`([^`]+)`", line):
                yield number, span, False


def problems_in(path, src, bin_dir, commands):
    text = open(path, encoding="utf-8").read()
    rel = os.path.relpath(path, src)
    for number, code, block in code_pieces(text):
        where = f"{rel}:{number}"
        for m in re.finditer(r"(?:^|[\s(|;&])((?:tools/)?rekon) +([A-Za-z-][\w-]*)", code):
            word = m.group(2)
            if word.isupper() or (m.group(1) == "tools/rekon" and word in SCRIPT_COMMANDS):
                continue  # a placeholder (COMMAND), or one of the script's own
            if word not in commands:
                yield f"{where}: '{m.group(1)} {word}' is not a rekon command (rekon --help lists them)"
        for m in re.finditer(r"build/bin/([\w.+-]+)", code):
            if m.group(1).endswith("-"):
                continue  # build/bin/rekon-$s: one of several, named by a shell variable
            if not os.path.exists(os.path.join(bin_dir, m.group(1))):
                yield f"{where}: build/bin/{m.group(1)} is not built"
        for m in re.finditer(r"(?<![\w/.-])(rekon-[\w-]+)", code):
            if not os.path.exists(os.path.join(bin_dir, m.group(1))):
                yield f"{where}: {m.group(1)} is no program in build/bin"
        if block and "─" not in code:  # a diagram's boxes and arrows name programs, not commands
            first = code.strip().split(" ")[0] if code.strip() else ""
            if first.startswith("rekon-"):
                yield f"{where}: '{first}' runs only with build/bin on PATH; write build/bin/{first}"
            for m in re.finditer(r"(?:^|\s)((?:tools|tests)/[\w./-]+\.(?:sh|py))", code):
                if not os.path.exists(os.path.join(src, m.group(1))):
                    yield f"{where}: {m.group(1)} does not exist"


def main():
    src, bin_dir = sys.argv[1], sys.argv[2]
    commands = rekon_commands(bin_dir)
    checked = pages(src)
    problems = [p for page in checked for p in problems_in(page, src, bin_dir, commands)]
    for p in problems:
        print(p)
    print(f"{len(checked)} pages checked, {len(problems)} commands that do not exist")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
