#!/usr/bin/env python3
"""The wheels a GPU sitting carries, without what it never imports.

The tree that travels to the GPU machine (tracked files, untracked ones and what `carry` names)
must stay under 64 MiB, and ../shared/gpu/wheels.sh's wheels take 34 MB of it: the repository
(~32 MB) left no room for a run's checkpoint to come back in. Most of those bytes are never
imported by a training run: MuJoCo's `experimental/` folder (the Studio app and its GUI
libraries, ~16 MB compressed; `import mujoco` does not load it), its Filament renderer and
interactive viewer extensions (2.2 MB) and MJX's `test_data/` (test models, 6.5 MB). This
writes copies of the four wheels a sitting installs into `.whl-gpu/` (ignored by git) with
those files left out and their lines dropped from the wheel's RECORD, so pip installs them as
it installs the originals (10.2 MB in all):

  python scripts/gpu_wheels.py            # reads .whl/, writes .whl-gpu/
  # on the GPU machine (carry .whl-gpu):
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \\
      --target /tmp/site .whl-gpu/*.whl
"""

from __future__ import annotations

import argparse
import fnmatch
import os
import sys
import zipfile

# wheel file pattern -> prefixes of the members (folders, files) a sitting never imports
WHEELS = {
    # experimental/: the Studio app; _render_filament / _simulate: the Filament renderer
    # (mujoco.mjrf) and the interactive viewer (mujoco.viewer), which a run never imports
    "mujoco-3.17.*-cp312-*.whl": ("mujoco/experimental/", "mujoco/_render_filament.",
                                  "mujoco/_simulate."),
    "mujoco_mjx-3.17.*.whl": ("mujoco/mjx/test_data/",),
    "trimesh-*.whl": (),
    "tensorboardx-*.whl": (),
}


def slim(source: str, target: str, drop: tuple[str, ...]) -> tuple[int, int]:
  """Copies the wheel `source` to `target` without the members whose names start with one of
  `drop` (and their RECORD lines). Returns (members kept, members dropped)."""
  kept = dropped = 0
  with zipfile.ZipFile(source) as src, zipfile.ZipFile(target + ".tmp", "w",
                                                       zipfile.ZIP_DEFLATED) as dst:
    for info in src.infolist():
      name = info.filename
      if name.startswith(drop):  # (never, for drop == ())
        dropped += 1
        continue
      data = src.read(info)
      if name.endswith(".dist-info/RECORD"):
        lines = data.decode().splitlines(keepends=True)
        data = "".join(l for l in lines if not l.split(",", 1)[0].startswith(drop)).encode()
      dst.writestr(info, data)
      kept += 1
  os.replace(target + ".tmp", target)
  return kept, dropped


def main(argv=None) -> int:
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--source", default=".whl")
  parser.add_argument("--out", default=".whl-gpu")
  args = parser.parse_args(argv)
  names = sorted(os.listdir(args.source)) if os.path.isdir(args.source) else []
  os.makedirs(args.out, exist_ok=True)
  for pattern, drop in WHEELS.items():
    found = [n for n in names if fnmatch.fnmatch(n.lower(), pattern)]
    if len(found) != 1:
      print(f"error: {args.source}/ holds {len(found)} wheels matching {pattern} (need one; "
            "run bash ../shared/gpu/wheels.sh)", file=sys.stderr)
      return 2
    source, target = os.path.join(args.source, found[0]), os.path.join(args.out, found[0])
    kept, dropped = slim(source, target, drop)
    print(f"{target}: {os.path.getsize(source) / 1e6:.1f} MB -> "
          f"{os.path.getsize(target) / 1e6:.1f} MB ({dropped} files left out, {kept} kept)")
  return 0


if __name__ == "__main__":
  sys.exit(main())
