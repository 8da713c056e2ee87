#!/usr/bin/env python3
"""Moves former demonstrators out of the tree, into git history: each file named is removed
from benchmarks/demonstrators/ and listed in `benchmarks/demonstrators/archived.json` with its
task, checksum, the mean return of the demonstrations it learned (what `scripts/report.py`
reads of it), its size and the commit that holds it, with the command that brings it back.

The tree that travels to the GPU machine (tracked files) has a size limit; a former
demonstrator that no test, default or command refers to is only kept for the record, and git
keeps it there. Run it on a clean tree (the commit named must hold the files), then commit:

  python scripts/archive_demonstrators.py reacher_hard_expert_64be96_48k.npz ...
  git show <commit>:benchmarks/demonstrators/<file> > benchmarks/demonstrators/<file>  # back
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

from mjx_form.files import effect_models  # noqa: E402

FOLDER = os.path.join(ROOT, "benchmarks", "demonstrators")
INDEX = os.path.join(FOLDER, "archived.json")


def read_index(path: str | None = None) -> list[dict]:
  """The archived demonstrators' entries (default: INDEX's; [] where none were archived)."""
  path = path or INDEX
  if not os.path.exists(path):
    return []
  with open(path) as f:
    return json.load(f)


def main(argv=None) -> int:
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("files", nargs="+", help="file names in benchmarks/demonstrators/")
  args = parser.parse_args(argv)
  git = lambda *a: subprocess.run(["git", *a], cwd=ROOT, capture_output=True, text=True)
  commit = git("rev-parse", "HEAD").stdout.strip()
  entries = read_index()
  for name in args.files:
    relative = f"benchmarks/demonstrators/{os.path.basename(name)}"
    path = os.path.join(ROOT, relative)
    try:
      meta = effect_models.load_effect_model(path).metadata
    except (OSError, ValueError) as e:
      print(f"error: {e}", file=sys.stderr)
      return 2
    if git("diff", "--quiet", commit, "--", relative).returncode != 0 or git(
        "cat-file", "-e", f"{commit}:{relative}").returncode != 0:
      print(f"error: {relative} differs from commit {commit[:12]} or is not in it: commit it "
            "first", file=sys.stderr)
      return 2
    entries.append({
        "file": os.path.basename(name), "task": meta["task"], "sha256": meta["sha256"],
        "demonstrations_mean_return": meta["demonstrations"].get("expert", {}).get("mean_return"),
        "bytes": os.path.getsize(path), "commit": commit,
        "restore": f"git show {commit}:{relative} > {relative}"})
  with open(INDEX + ".tmp", "w") as f:
    json.dump(entries, f, indent=1)
    f.write("\n")
  os.replace(INDEX + ".tmp", INDEX)
  for name in args.files:
    os.remove(os.path.join(FOLDER, os.path.basename(name)))
  print(f"{len(args.files)} demonstrators archived in {os.path.relpath(INDEX, ROOT)} "
        f"({sum(e['bytes'] for e in entries[-len(args.files):]) / 1e6:.1f} MB)")
  return 0


if __name__ == "__main__":
  sys.exit(main())
