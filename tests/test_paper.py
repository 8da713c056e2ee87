"""mjx_form/paper.py's returns are the paper's Table 1 as ../shared/DESIGN.md gives it."""

import os

import pytest

from mjx_form import paper

DESIGN = os.path.join(os.path.dirname(__file__), "..", "..", "shared", "DESIGN.md")
COLUMNS = ["expert", "bc", "bco", "gaifo", "gaifo_gp", "vaifo", "vaifo_gp", "form"]


def _design_table() -> dict[str, dict[str, float]]:
  """{column: {task: return}} of DESIGN.md's Table 1 (its header row starts `| task | expert`)."""
  with open(DESIGN) as f:
    lines = f.read().splitlines()
  start = next(i for i, line in enumerate(lines) if line.startswith("| task | expert | BC"))
  table = {c: {} for c in COLUMNS}
  for line in lines[start + 2:]:
    if not line.startswith("|"):
      break
    cells = [c.strip() for c in line.strip("|").split("|")]
    for column, value in zip(COLUMNS, cells[1:]):
      table[column][cells[0].replace(" ", "_")] = float(value)
  return table


@pytest.mark.skipif(not os.path.exists(DESIGN), reason="../shared/DESIGN.md is not beside the "
                    "repository")
def test_paper_constants_are_design_tables():
  table = _design_table()
  assert len(table["expert"]) == 13
  assert paper.EXPERT == table["expert"]
  assert paper.FORM == table["form"]
  assert set(paper.BASELINES) == set(COLUMNS[1:-1]) == set(paper.BASELINE_NAMES)
  for method, returns in paper.BASELINES.items():
    assert returns == table[method], method
