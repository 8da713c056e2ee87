#!/usr/bin/env python3
"""Packs result files' FORM learning curves: their `learning_curve` rows move to a
gzip-compressed companion, `<name>.curve.jsonl.gz`, and the other rows (final returns, effect
models) stay in `<name>.jsonl` (mjx_form/files/results.py, "Packed curves"). Run it on a
sitting's result files when they are copied to benchmarks/results/: the tree that travels to
the GPU machine stays small, and `scripts/report.py --check` refuses unpacked ones.

  python scripts/pack_results.py                       # every benchmarks/results/*.jsonl
  python scripts/pack_results.py benchmarks/results/X.jsonl
"""

from __future__ import annotations

import argparse
import glob
import os
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

from mjx_form.files import results  # noqa: E402

RESULTS = os.path.join(ROOT, "benchmarks", "results")


def main(argv=None) -> int:
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("files", nargs="*", help="result files (default: every .jsonl of "
                      "benchmarks/results/)")
  args = parser.parse_args(argv)
  paths = args.files or sorted(glob.glob(os.path.join(RESULTS, "*.jsonl")))
  before = after = moved_files = 0
  for path in paths:
    curve = results.curve_path(path)
    sizes = lambda: sum(os.path.getsize(p) for p in (path, curve) if os.path.exists(p))
    try:
      size = sizes()
      moved = results.pack_curve(path)
    except (OSError, results.ResultFileError) as e:
      print(f"error: {e}", file=sys.stderr)
      return 2
    if moved:
      before, after, moved_files = before + size, after + sizes(), moved_files + 1
      print(f"{os.path.basename(path)}: {moved} learning-curve rows to "
            f"{os.path.basename(curve)}; {size / 1e6:.2f} MB -> {sizes() / 1e6:.2f} MB")
  print(f"{moved_files} of {len(paths)} files packed"
        + (f": {before / 1e6:.1f} MB -> {after / 1e6:.1f} MB" if moved_files else ""))
  return 0


if __name__ == "__main__":
  sys.exit(main())
