"""Test setup: XLA flags for MJX on the CPU (two host devices for the mesh tests), a
persistent compilation cache, and the shared, compiled-once fixtures."""

import os
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from mjx_form.cpu import configure_cpu_xla  # noqa: E402

# Two host devices for the mesh tests. XLA's newer CPU fusion emitters off for every compile
# of the session, command-line subprocesses included (they inherit XLA_FLAGS): MJX steps and
# resets compile with ~35% less CPU time and run as fast (measured on this 2-core CPU: walker's
# parity step 27 s CPU instead of 45 s, quadruped's reset 68 s instead of 100 s; the train
# tests 10-20% faster each). The results agree to rounding; every check keeps its tolerance.
# LLVM at optimisation level 1 (XLA's default is 2): the FORM command-line test took 219 s
# instead of 249 s (its training iteration compiles in 38 s instead of 53 s), and the MPO
# learning test, 100 iterations of execution, 103 s instead of 111 s (each alone, cold cache,
# session 65). (Level 0 compiled ~30% faster, but the learning and fixed-action tests ran
# 2-2.5x slower; no net gain.)
configure_cpu_xla("--xla_force_host_platform_device_count=2 --xla_cpu_use_fusion_emitters=false"
                  " --xla_backend_optimization_level=1")
os.environ.setdefault("JAX_PLATFORMS", "cpu")

import jax  # noqa: E402

_CACHE = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), ".jax_cache")
jax.config.update("jax_compilation_cache_dir", _CACHE)
jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)

import importlib.util  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402

import pytest  # noqa: E402

_PARITY_REPORT: list[dict] = []


class _ReportRows:
  """Collects a test's measured rows; they travel with its report (also from xdist workers)."""

  def __init__(self, node):
    self._node = node

  def append(self, row: dict) -> None:
    self._node.user_properties.append(("parity_row", json.dumps(row)))


def load_script(name: str, folder: str = "scripts"):
  """<folder>/<name>.py (scripts/ or benchmarks/) as a module, so its main() runs in this
  process (compiles are shared)."""
  path = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), folder,
                      f"{name}.py")
  spec = importlib.util.spec_from_file_location(f"{folder}_{name}", path)
  module = importlib.util.module_from_spec(spec)
  spec.loader.exec_module(module)
  return module


@pytest.hookimpl(trylast=True)
def pytest_collection_modifyitems(config, items):
  """Makes `--dist loadgroup` group again under pytest >= 9.2.

  xdist's workers mark a test's group by appending '@group' to `item._nodeid`; pytest 9.2
  builds node ids from a structured `item._id` instead, so the suffix is lost and every test of
  a group is scheduled on its own (pytest-dev/pytest-xdist#1386). The tests then compile the
  shared MJX functions once per worker instead of once per group. This runs after xdist's hook
  (on the workers, where `config.option.loadgroup` is set) and adds the suffix where it is
  missing, the way xdist would.
  """
  if not getattr(config.option, "loadgroup", False):
    return
  for item in items:
    names = sorted({str(m.args[0] if m.args else m.kwargs.get("name", "default"))
                    for m in item.iter_markers("xdist_group")})
    if not names:
      continue
    suffix = "@" + "_".join(names)
    if item.nodeid.endswith(suffix):
      continue  # xdist's own suffix took effect (pytest < 9.2)
    try:
      from _pytest.nodeid import NodeId
      item._id = NodeId.parse(item.nodeid + suffix)
    except (ImportError, AttributeError):
      pass
    if not item.nodeid.endswith(suffix):
      warnings.warn(f"xdist_group {suffix[1:]!r} of {item.nodeid} has no effect: the test is "
                    "scheduled on its own (see tests/conftest.py)")


@pytest.fixture
def parity_report(request) -> _ReportRows:
  """Rows of measured parity errors; printed at the end and written to .parity_report.jsonl."""
  return _ReportRows(request.node)


def pytest_runtest_logreport(report):
  if report.when == "call":
    _PARITY_REPORT.extend(json.loads(v) for k, v in report.user_properties if k == "parity_row")


def pytest_terminal_summary(terminalreporter):
  if not _PARITY_REPORT:
    return
  write = terminalreporter.write_line
  write("")
  write("parity with dm_control (largest absolute error per sample: median / p90 / max)")
  for row in sorted(_PARITY_REPORT, key=lambda r: (r["test"], r["task"], r["physics"])):
    parts = []
    for key, value in row.items():
      if key in ("test", "task", "physics"):
        continue
      if isinstance(value, dict) and "median" in value:
        parts.append(f"{key} {value['median']:.1e}/{value['p90']:.1e}/{value['max']:.1e}")
      else:
        parts.append(f"{key} {value}")
    write(f"  {row['test']:<20} {row['task']:<15} {row['physics']:<8} " + "  ".join(parts))
  path = os.path.join(os.path.dirname(_CACHE), ".parity_report.jsonl")
  with open(path, "w") as f:
    for row in _PARITY_REPORT:
      f.write(json.dumps(row) + "\n")


_PROFILE = os.environ.get("MJX_FORM_TEST_PROFILE")  # a JSON-lines file: where a test's time went


if _PROFILE:
  from jax import monitoring as _monitoring

  _SPENT: dict[str, float] = {}

  def _on_duration(event, duration, **_):
    _SPENT[event] = _SPENT.get(event, 0.0) + duration

  def _on_event(event, **_):
    _SPENT[event] = _SPENT.get(event, 0.0) + 1

  _monitoring.register_event_duration_secs_listener(_on_duration)
  _monitoring.register_event_listener(_on_event)

  @pytest.hookimpl(hookwrapper=True)
  def pytest_runtest_protocol(item, nextitem):
    """Writes one row per test: its wall time and the JAX compile events inside it (this
    process only; a test's subprocesses are not counted)."""
    _SPENT.clear()
    start = time.perf_counter()
    yield
    row = {"test": item.nodeid, "worker": os.environ.get("PYTEST_XDIST_WORKER"),
           "seconds": time.perf_counter() - start,
           **{k.rsplit("/", 1)[-1]: round(v, 3) for k, v in _SPENT.items()}}
    with open(_PROFILE, "a") as f:
      f.write(json.dumps(row) + "\n")
