"""The README's `scripts/run.py` command lines parse, and their training settings pass the
config checks (a renamed or removed flag breaks this test, not a reader's first run)."""

import os
import shlex

from conftest import load_script

README = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "README.md")


def run_commands() -> list[list[str]]:
  """Arguments of every `scripts/run.py` line in the README's code blocks (continuations joined,
  comments dropped)."""
  inside, code = False, []
  for line in open(README).read().splitlines():
    if line.startswith("```"):
      inside = not inside
    elif inside:
      code.append(line)
  commands = []
  for line in "\n".join(code).replace("\\\n", " ").splitlines():
    words = shlex.split(line.split("#", 1)[0])
    if "scripts/run.py" in words:
      commands.append(words[words.index("scripts/run.py") + 1:])
  return commands


def test_readme_run_commands_parse_and_pass_the_checks():
  run = load_script("run")
  commands = run_commands()
  assert len(commands) >= 7 and any("--method" in c for c in commands), commands
  for argv in commands:
    args = run.parse_args(argv)
    if args.method == "expert":
      run.train_config(args).check(1)
