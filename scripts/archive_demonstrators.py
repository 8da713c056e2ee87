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

FOLDER = "benchmarks/demonstrators"  # (in the repository at `root`)
INDEX = "archived.json"  # (in FOLDER)


def read_index(root: str = ROOT) -> list[dict]:
  """The archived demonstrators' entries of the repository at `root` ([] where none were)."""
  path = os.path.join(root, FOLDER, INDEX)
  if not os.path.exists(path):
    return []
  with open(path) as f:
    return json.load(f)


def main(argv=None, root: str = ROOT) -> int:
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("files", nargs="+", help="file names in benchmarks/demonstrators/")
  args = parser.parse_args(argv)
  git = lambda *a: subprocess.run(["git", *a], cwd=root, capture_output=True, text=True)
  commit = git("rev-parse", "HEAD").stdout.strip()
  entries = read_index(root)
  names = list(dict.fromkeys(os.path.basename(name) for name in args.files))
  archived = {e["file"] for e in entries}
  if archived & set(names):
    print(f"error: already archived: {', '.join(sorted(archived & set(names)))}",
          file=sys.stderr)
    return 2
  for name in names:
    relative = f"{FOLDER}/{name}"
    path = os.path.join(root, relative)
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
        "file": name, "task": meta["task"], "sha256": meta["sha256"],
        "demonstrations_mean_return": meta["demonstrations"].get("expert", {}).get("mean_return"),
        "bytes": os.path.getsize(path), "commit": commit,
        "restore": f"git show {commit}:{relative} > {relative}"})
  index = os.path.join(root, FOLDER, INDEX)
  with open(index + ".tmp", "w") as f:
    json.dump(entries, f, indent=1)
    f.write("\n")
  os.replace(index + ".tmp", index)
  for name in names:
    os.remove(os.path.join(root, FOLDER, name))
  print(f"{len(names)} demonstrators archived in {FOLDER}/{INDEX} "
        f"({sum(e['bytes'] for e in entries[-len(names):]) / 1e6:.1f} MB)")
  return 0


if __name__ == "__main__":
  sys.exit(main())
