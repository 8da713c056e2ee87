"""`mjx_form.sim.rewards.tolerance` against dm_control's own `rewards.tolerance`."""

import numpy as np
import pytest
from dm_control.utils import rewards as dm_rewards

from mjx_form.sim import rewards

SIGMOIDS = ["gaussian", "hyperbolic", "long_tail", "reciprocal", "cosine", "linear", "quadratic",
            "tanh_squared"]
CASES = [
    dict(bounds=(0.0, 0.0), margin=0.0),
    dict(bounds=(-1.0, 2.0), margin=0.0),
    dict(bounds=(0.0, 0.0), margin=2.0),
    dict(bounds=(10.0, float("inf")), margin=10.0, value_at_margin=0.0),
    dict(bounds=(1.2, float("inf")), margin=0.6),
    dict(bounds=(0.9, float("inf")), margin=1.9, value_at_margin=0.0),
    dict(bounds=(0.6, 2.0), margin=0.0),
    dict(bounds=(-0.5, 0.5), margin=1.0, value_at_margin=0.5),
]


@pytest.mark.parametrize("sigmoid", SIGMOIDS)
@pytest.mark.parametrize("case", range(len(CASES)))
def test_tolerance_matches_dm_control(sigmoid, case):
  kwargs = dict(CASES[case], sigmoid=sigmoid)
  value_at_margin = kwargs.get("value_at_margin", 0.1)
  if value_at_margin == 0 and sigmoid not in ("cosine", "linear", "quadratic"):
    kwargs["value_at_margin"] = 0.1  # dm_control refuses 0 for these sigmoids
  x = np.random.RandomState(case).uniform(-25, 25, size=200)
  x = np.concatenate([x, [0.0, 1.2, 0.9, 10.0, -1.0, 2.0]])  # include the bounds themselves
  expected = dm_rewards.tolerance(x, **kwargs)
  got = np.asarray(rewards.tolerance(x.astype(np.float32), **kwargs))
  np.testing.assert_allclose(got, expected, rtol=1e-5, atol=1e-6)


def test_tolerance_rejects_what_dm_control_rejects():
  with pytest.raises(ValueError, match="Lower bound"):
    rewards.tolerance(0.0, bounds=(1.0, 0.0))
  with pytest.raises(ValueError, match="non-negative"):
    rewards.tolerance(0.0, margin=-1.0)
  with pytest.raises(ValueError, match="strictly between"):
    rewards.tolerance(2.0, margin=1.0, sigmoid="gaussian", value_at_margin=0.0)
  with pytest.raises(ValueError, match="Unknown sigmoid"):
    rewards.tolerance(2.0, margin=1.0, sigmoid="nope")
