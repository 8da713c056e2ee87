"""The README's `scripts/run.py` command lines parse, and their training settings pass the
config checks (a renamed or removed flag breaks this test, not a reader's first run). The main
command itself runs in tests/test_form.py."""

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
    if "scripts/run.py" not in line:  # (other lines may hold unbalanced quotes: don't split them)
      continue
    words = shlex.split(line.split("#", 1)[0])
    if "scripts/run.py" in words:
      commands.append(words[words.index("scripts/run.py") + 1:])
  return commands


def test_readme_run_commands_parse_and_pass_the_checks():
  run = load_script("run")
  commands = run_commands()
  assert len(commands) >= 7, commands
  for method in run.METHODS:  # every method is shown with its name written out
    assert any(c[c.index("--method") + 1] == method for c in commands if "--method" in c), method
  parsed = [run.parse_args(argv) for argv in commands]
  # The first command (the README's main job) is the FORM pipeline, ending with evaluations.
  assert parsed[0].method == "form" and parsed[0].final_eval_envs > 0, commands[0]
  for args in parsed:
    if args.method in ("expert", "form"):
      run.train_config(args).check(1)

