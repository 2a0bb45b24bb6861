"""The README's two set-up commands are exactly what CI runs."""

import os
import re

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def test_ci_runs_the_readme_commands():
    readme = open(os.path.join(ROOT, "README.md")).read()
    ci = open(os.path.join(ROOT, ".ci", "run")).read()
    setup = readme.split("## Set up", 1)[1].split("##", 1)[0]
    commands = re.findall(r"```bash\n(.*?)\n```", setup, re.S)
    assert len(commands) == 2, "the README's set-up section has exactly two commands"
    ci_lines = [line.strip() for line in ci.splitlines()]
    for cmd in commands:
        assert cmd.strip() in ci_lines, f"CI does not run the README command: {cmd}"
