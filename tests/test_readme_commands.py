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


def test_ci_runs_the_readmes_test_command_and_it_keeps_the_main_path():
  """.ci/run's pytest line is the README's test command; that command deselects the tests
  marked slow, and the test that runs the README's main command is not one of them."""
  from test_form import test_form_command_line_runs_every_stage as main_command
  root = os.path.dirname(README)
  readme = [line for line in open(README).read().splitlines() if "-m pytest" in line]
  assert len(readme) == 1, readme
  command = readme[0][readme[0].index(".venv/bin/python -m pytest"):]
  ci = [line for line in open(os.path.join(root, ".ci", "run")).read().splitlines()
        if "-m pytest" in line and not line.startswith("#")]
  assert ci == [command]
  words = shlex.split(command)
  assert words[words.index("-m", words.index("pytest")) + 1] == "not slow"
  assert "slow" not in [m.name for m in getattr(main_command, "pytestmark", [])]
