"""What the domains share: dm_control's model files and the Control Suite task base."""

from __future__ import annotations

import pathlib
import xml.etree.ElementTree as ET

from mjx_form.sim import env

ASSET_DIR = pathlib.Path(__file__).parent / "assets"
# The XMLs in assets/ are dm_control 1.0.50's suite models, unchanged (Apache-2.0, see
# assets/LICENSE); tests/test_model_parity.py checks that they compile to dm_control's models.
ASSETS = {f"./common/{p.name}": p.read_bytes() for p in sorted((ASSET_DIR / "common").glob("*.xml"))}


def read_model(filename: str) -> ET.Element:
  """Parses one of the domain XMLs in assets/."""
  return ET.fromstring((ASSET_DIR / filename).read_text())


class ControlSuiteTask(env.Task):
  """A task whose model is one of dm_control's suite XMLs."""

  xml_file: str = ""

  def model_xml(self) -> ET.Element:
    return read_model(self.xml_file)

  def model_assets(self) -> dict[str, bytes]:
    return ASSETS
