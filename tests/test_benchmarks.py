"""The benchmark scripts' own logic (their timings are taken on the GPU, never in tests)."""

import jax
import numpy as np
from conftest import load_script

from mjx_form.rl.train import TrainConfig, Trainer


def test_train_throughput_env_only_runs_over_the_loops_devices():
  """The env-only rollout it compares the loop with is split over the same mesh (2 forced host
  devices here): its environments end where they started, on both devices."""
  assert jax.device_count() == 2  # tests/conftest.py forces two host devices
  bench = load_script("train_throughput", folder="benchmarks")
  trainer = Trainer(TrainConfig(task="reacher_easy", num_envs=4, unroll_length=5))
  run, start = bench.env_only_fn(trainer, 3, jax.random.PRNGKey(0))
  assert start.obs.sharding.device_set == set(jax.devices())
  first = np.asarray(start.obs)
  key = jax.random.PRNGKey(1)
  exe = run.lower(start, key).compile()  # compiled once and timed, as benchmarks/common.py does
  end = exe(start, key)  # the start is donated
  assert end.obs.shape == first.shape and end.obs.sharding.device_set == set(jax.devices())
  assert end.obs.sharding.spec == trainer._batch.spec
  assert not np.allclose(np.asarray(end.obs), first)  # it stepped
  # Each timed call is fed the previous output: every leaf (zero-size ones too) must come back
  # with the sharding the executable was compiled for.
  exe(end, key).obs.block_until_ready()


def test_form_reward_landscape_names_each_observation_dimension():
  """Its posture report names dimensions by the task's observation layout, in order."""
  bench = load_script("form_reward_landscape", folder="benchmarks")
  assert bench.dimension_names({"orientations": 2, "height": 1, "velocity": 2}) == [
      "orientations[0]", "orientations[1]", "height", "velocity[0]", "velocity[1]"]
  import tasks
  layout = tasks.make("cheetah_run").observation_layout
  assert len(bench.dimension_names(layout)) == sum(layout.values())
