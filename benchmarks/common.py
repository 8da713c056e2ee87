"""What the benchmarks share: result records (JSON Lines under benchmarks/results/), timing,
where observations turn past a raw angle's [-pi, pi), and reacher's target quadrants."""

from __future__ import annotations

import datetime
import os
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
RESULTS_DIR = os.path.join(ROOT, "benchmarks", "results")
if ROOT not in sys.path:
  sys.path.insert(0, ROOT)

from mjx_form.files.results import ResultWriter, device_name, versions  # noqa: E402,F401


def add_expert_arguments(parser) -> None:
  """`--tasks` and `--policy`, as the scripts that run expert policies take them."""
  import tasks  # (here, not at import: the scripts set XLA's flags before JAX starts)

  parser.add_argument("--tasks", nargs="*", default=None, choices=tasks.TASKS, metavar="TASK",
                      help="default: every task with a shipped expert")
  parser.add_argument("--policy", default=None, help="one task's policy file instead of the "
                      "shipped expert (with a single --tasks)")


def expert_tasks(parser, args) -> list[str]:
  """The tasks `add_expert_arguments` chose (every task with a shipped expert by default);
  exits through `parser.error` when `--policy` comes with other than one task."""
  import tasks

  names = args.tasks if args.tasks is not None else list(tasks.bundled_experts())
  if args.policy is not None and len(names) != 1:
    parser.error("--policy needs exactly one --tasks")
  return names


def load_expert(task: str, path: str):
  """(expert, env): the policy file at `path`, checked against `task`, and the task in the
  physics the policy was trained in (its metadata's; e.g. quadruped_walk's: fast_ls4)."""
  import tasks
  from mjx_form.files import experts

  env = tasks.make(task)
  expert = experts.load_expert(path, env)
  physics = expert.metadata.get("physics", env.physics)
  return expert, env if physics == env.physics else tasks.make(task, physics=physics)


def mean_action_rollout(env, agent, key, episodes: int, probe):
  """One episode in each of `episodes` environments of `agent`'s (a loaded policy file's) mean
  action, clipped to the task's control range: `probe(next_state)` of every step, stacked
  [T, K, ...], on the host."""
  import jax
  from mjx_form.files import experts
  from mjx_form.rl import normalizer
  from mjx_form.sim import env as env_lib

  policy = experts.policy_network(agent.metadata, env.action_size)

  @jax.jit
  def run(key):
    states = jax.vmap(env.reset)(jax.random.split(key, episodes))

    def step(states, _):
      pi = policy.apply(agent.params, normalizer.normalize(agent.normalizer, states.obs))
      nxt = jax.vmap(env.step)(states, env.clip_action(pi.mode()))
      return nxt, probe(nxt)

    return jax.lax.scan(step, states, None, length=env_lib.EPISODE_LENGTH)[1]

  return jax.device_get(run(key))


def default_results_path(what: str) -> str:
  day = datetime.date.today().isoformat()
  return os.path.join(RESULTS_DIR, f"{day}_{what}.jsonl")


def turned_past(observations, period):
  """[...] bool: whether a periodic dimension (`period` [D] > 0, the task's
  `observation_period()`) of observations [..., D] lies outside [-period / 2, period / 2)
  (pi itself outside, -pi inside): a raw unbounded angle that has turned past pi."""
  periodic = period > 0
  raw, half = observations[..., periodic], period[periodic] / 2  # [..., P], [P]
  return ((raw < -half) | (raw >= half)).any(axis=-1)


def angle_quadrant(angle):
  """The quadrant 0..3 of each angle in [-pi, pi]: [-pi, -pi/2), [-pi/2, 0), [0, pi/2),
  [pi/2, pi] (pi itself in the last)."""
  return np.clip(np.floor((angle + np.pi) / (np.pi / 2)).astype(int), 0, 3)


def best_time(fn, repeats: int) -> float:
  """Smallest wall time of `repeats` calls of `fn` (which must block until done)."""
  times = []
  for _ in range(repeats):
    t0 = time.perf_counter()
    fn()
    times.append(time.perf_counter() - t0)
  return min(times)


def time_compiled(fn, fn_args: tuple, steps: int, num_envs: int, repeats: int):
  """Compiles jitted `fn` for `fn_args`, warms it up and times it: (steps/s, compile seconds).

  `fn(state, key)` donates its first argument, so each timed call is fed the previous output.
  """
  t0 = time.perf_counter()
  exe = fn.lower(*fn_args).compile()
  compile_s = time.perf_counter() - t0
  return time_executable(exe, fn_args, steps, num_envs, repeats), compile_s


def time_executable(exe, fn_args: tuple, steps: int, num_envs: int, repeats: int) -> float:
  """Control steps per second of compiled `exe(state, key)` (state donated): one warm-up call,
  then the best of `repeats` calls, each fed the previous output."""
  return steps * num_envs / best_call_time(exe, fn_args, repeats)


def best_call_time(exe, fn_args: tuple, repeats: int, feed_output: bool = True,
                   keep: list | None = None) -> float:
  """Best seconds per call of compiled `exe` after one warm-up call. With `feed_output`, each
  call gets the previous output as its first argument (for an `exe` that donates it). `keep`:
  where given, the arguments of one more call are appended to it afterwards."""
  import jax
  holder = [jax.block_until_ready(exe(*fn_args))]  # warm-up
  next_args = lambda: (holder[0], *fn_args[1:]) if feed_output else fn_args

  def call():
    holder[0] = jax.block_until_ready(exe(*next_args()))
  seconds = best_time(call, repeats)
  if keep is not None:
    keep.append(next_args())
  return seconds

