#!/usr/bin/env python3
"""Milliseconds per MPO/Retrace learner update, and what its parts cost.

The learner update (`mjx_form.rl.learner.update`) on a random batch of the paper's size (64 unrolls
of 100 steps), `--updates` updates per jitted `lax.scan` as in the training loop, timed as the
best of `--repeats` calls after a warm-up call. Variants, each compiled on its own:
  - base:        the default LearnerConfig;
  - samples_1:   one sampled action per state instead of 20 (what the sampled critic costs);
  - highest:     float32 matmuls at 'highest' precision (the default lets the GPU use TF32);
  - tiled_critic: the critic as nn.Dense on the concatenation tiled over the 20 sampled
                 actions (`Critic(tiled=True)`, same function), against the split first layer of
                 `Critic` that computes the observation's half once per state;
  - bf16_sampled_q: the target critic's Q of the sampled actions in bfloat16
                 (`LearnerConfig.sampled_q_bfloat16`);
  - retrace_*:   the Retrace targets of one batch alone, as a loop and unrolled (the learner
                 unrolls it).
FORM's work per learner update (what `scripts/run.py --method form` adds to each; the task's
effect-model settings, an untrained demonstrator of the same shape; the batch moved by a tiny
amount each update, so that nothing of it is hoisted out of the loop, as a training run's fresh
batches are not):
  - form_source: the reward source's part (`FormReward.update`: the imitator model's step, then
                 the batch's rewards folded into their statistics; `relabel`);
  - form_log_pd: the demonstrator's log pD of the batch alone (what a replay storing log pD at
                 collection would save per update);
  - form_loop:   the source's part and the learner's update on its rewards, as the training
                 loop runs them, with bf16_sampled_q's learner (FORM's runs also keep an
                 average policy and may set T, the critic's clip or epsilon_scale: a few
                 element-wise operations more or none) to compare with it;
  - form_loop_every4: form_loop with the imitator trained on 1 update in 4 and every batch
                 relabelled (`--imitator_every 4`; the loop's nested scan, here a conditional
                 on the update's index: the same work).
Records `kind: update_speed` with `update_ms` (or `retrace_ms`). `--profile N` also runs each
update variant's program once under the profiler and prints and records (`profile`) the N source
lines with the most device time per update (`device_profile.py`).

  python benchmarks/update_speed.py --tasks cheetah_run humanoid_run
  python benchmarks/update_speed.py --tasks quadruped_run --variants bf16_sampled_q form_source \
      form_log_pd form_loop
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import common  # noqa: E402  (puts the repository on sys.path)
import device_profile  # noqa: E402
from mjx_form.cpu import configure_cpu_xla  # noqa: E402

configure_cpu_xla()

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402

import tasks  # noqa: E402
from mjx_form.imitation import effect_model as em  # noqa: E402
from mjx_form.imitation import settings as form_settings  # noqa: E402
from mjx_form.imitation.form import Demonstrator, FormReward  # noqa: E402
from mjx_form.rl import learner, normalizer, retrace  # noqa: E402
from mjx_form.rl.networks import Critic, Networks, make_networks  # noqa: E402

FORM_VARIANTS = ("form_source", "form_log_pd", "form_loop", "form_loop_every4")
EVERY = {"form_loop_every4": 4}  # a variant's source_update_every (1 where not named)
VARIANTS = ("base", "samples_1", "highest", "tiled_critic", "bf16_sampled_q", *FORM_VARIANTS)


def random_batch(key, batch: int, length: int, obs_size: int, action_size: int):
  """A batch shaped like the replay's: observations [B, T+1, D], actions [B, T, A], ..."""
  k = jax.random.split(key, 4)
  return {"observation": jax.random.normal(k[0], (batch, length + 1, obs_size)),
          "action": jax.random.uniform(k[1], (batch, length, action_size), minval=-1, maxval=1),
          "behaviour_log_prob": -jax.random.uniform(k[2], (batch, length)) * action_size,
          "discount": jnp.ones((batch, length))}, jax.random.normal(k[3], (batch, length))


def update_fn(networks, config: learner.LearnerConfig, updates: int):
  def run(state, norm, batch, rewards, key):
    def one(state, key):
      return learner.update(networks, config, state, norm, batch, rewards, key)[0], None
    return jax.lax.scan(one, state, jax.random.split(key, updates))[0]
  return jax.jit(run, donate_argnums=0)


def form_source(name: str, env, key) -> FormReward:
  """FORM's reward source for task `name` with its effect-model settings and FORM's default
  reward (standardised, clipped at 3 sd), on an untrained demonstrator of the same shape."""
  config = form_settings.effect_model_config(name, env)
  model = em.make_model(config, env.observation_size)
  demonstrator = Demonstrator(em.init_params(model, key), normalizer.init(env.observation_size))
  return FormReward(config, demonstrator, "untrained", standardise_reward=True, reward_clip=3.0)


def form_fn(variant: str, source: FormReward, networks, config: learner.LearnerConfig,
            updates: int):
  """`updates` of a FORM variant's work per learner update (module docstring), in one scan;
  each update's batch moved by 1e-6 x its index."""
  def run(carry, norm, batch, key):
    def one(carry, xs):
      i, key = xs
      moved = {**batch, "observation": batch["observation"] + 1e-6 * i}
      if variant == "form_log_pd":
        d, total = carry
        x, x_next = moved["observation"][:, :-1], moved["observation"][:, 1:]
        return (d, total + em.transition_log_prob(source.model, d.params, d.normalizer, x,
                                                  x_next).mean()), None
      state, rest = carry  # rest: form_loop's learner state, form_source's running sum
      every = EVERY.get(variant, 1)
      if every > 1:  # (an unbatched predicate: only the branch taken runs)
        state = jax.lax.cond(jnp.mod(i, every) == 0,
                             lambda s: source.update(s, moved, key)[0], lambda s: s, state)
      else:
        state, _ = source.update(state, moved, key)
      rewards, _ = source.relabel(state, moved)
      if variant == "form_source":  # (the rewards kept live through the sum)
        return (state, rest + rewards.mean()), None
      return (state, learner.update(networks, config, rest, norm, moved, rewards, key)[0]), None
    steps = (jnp.arange(updates, dtype=jnp.float32), jax.random.split(key, updates))
    return jax.lax.scan(one, carry, steps)[0]
  return jax.jit(run, donate_argnums=0)


def program(variant: str, name: str, env, norm, batch, rewards, key, updates: int):
  """(jitted fn donating its first argument, its arguments, the learner's config, settings
  beyond the learner's) of an update variant (module docstring) of task `name`."""
  obs_size, action_size = env.observation_size, env.action_size
  networks = make_networks(action_size)
  if variant in FORM_VARIANTS:
    config = learner.LearnerConfig(sampled_q_bfloat16=True)
    source = form_source(name, env, key)
    state = source.init(key, obs_size, action_size)
    if variant == "form_log_pd":
      carry = (state.demonstrator, jnp.zeros(()))
    elif variant == "form_source":
      carry = (state, jnp.zeros(()))
    else:
      carry = (state, learner.init(networks, config, key, obs_size, action_size))
    carry = jax.tree.map(lambda x: jnp.array(x, copy=True), carry)  # (a buffer per leaf)
    extra = {"effect_model": source.config.to_dict()}
    if variant in EVERY:
      extra["source_update_every"] = EVERY[variant]
    return (form_fn(variant, source, networks, config, updates), (carry, norm, batch, key),
            config, extra)
  config = learner.LearnerConfig()
  if variant == "samples_1":
    config = dataclasses.replace(config, num_action_samples=1)
  if variant == "bf16_sampled_q":
    config = dataclasses.replace(config, sampled_q_bfloat16=True)
  if variant == "tiled_critic":
    networks = Networks(networks.policy, Critic(tiled=True))
  state = learner.init(networks, config, key, obs_size, action_size)
  # Targets start as the online parameters; donation needs a buffer per leaf.
  state = jax.tree.map(lambda x: jnp.array(x, copy=True), state)
  return update_fn(networks, config, updates), (state, norm, batch, rewards, key), config, {}


def retrace_fn(unroll, calls: int):
  def run(args):
    def one(carry, _):
      # Feed the result back so the calls cannot be hoisted out of the loop.
      targets = jax.vmap(retrace.retrace_targets, in_axes=(0, 0, 0, 0, 0, None, None))(
          *args[:-1], carry, 1.0, unroll)
      return carry + 1e-6 * targets, None
    return jax.lax.scan(one, args[-1], None, length=calls)[0]
  return jax.jit(run)


def time_call(fn, args, repeats: int, donate_first: bool, profile: int = 0, per_call: int = 1):
  """(best seconds per call, compile seconds, profile) of jitted fn on args; profile: the
  `profile` source lines with the most device time in one more call, each with its
  microseconds per `per_call`-th of the call (None where not asked)."""
  t0 = time.perf_counter()
  exe = fn.lower(*args).compile()
  compile_s = time.perf_counter() - t0
  keep = []
  seconds = common.best_call_time(exe, args, repeats, feed_output=donate_first, keep=keep)
  if not profile:
    return seconds, compile_s, None
  # Its own executable (the timed one may run its kernels as command buffers, device_profile),
  # called once before the traced call, as the timed one was.
  profiled = device_profile.compile_for_profile(fn, args)
  live = jax.block_until_ready(profiled(*keep[0]))
  lines = device_profile.top_lines(profiled, (live, *keep[0][1:]) if donate_first else keep[0],
                                   profile)
  return seconds, compile_s, [{**line, "us": line["us"] / per_call} for line in lines]


def print_profile(lines: list[dict] | None) -> None:
  """The lines of `time_call`'s profile (None: none asked for; [] the trace held nothing)."""
  if lines is not None and not lines:
    print("    (profile: the trace held no operation of this program)", flush=True)
  for line in lines or ():
    print(f"    {line['share']:6.1%} {line['us']:9.1f} us/update  {line['where']}", flush=True)


def main(argv=None) -> int:
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--tasks", nargs="*", default=["cheetah_run", "humanoid_run"],
                      choices=tasks.TASKS, metavar="TASK")
  parser.add_argument("--variants", nargs="*", default=list(VARIANTS), choices=VARIANTS)
  parser.add_argument("--updates", type=int, default=64, help="updates per timed call")
  parser.add_argument("--batch_size", type=int, default=64)
  parser.add_argument("--unroll_length", type=int, default=100)
  parser.add_argument("--repeats", type=int, default=3)
  parser.add_argument("--profile", type=int, default=0, metavar="N",
                      help="also profile each update variant: its N costliest source lines")
  parser.add_argument("--out", default=common.default_results_path("update_speed"))
  args = parser.parse_args(argv)
  if min(args.updates, args.batch_size, args.unroll_length, args.repeats) <= 0:
    parser.error("--updates, --batch_size, --unroll_length and --repeats must be positive")
  if args.profile < 0:
    parser.error(f"--profile must be 0 (off) or positive, got {args.profile}")
  writer = common.ResultWriter(args.out)
  key = jax.random.PRNGKey(0)
  shape = {"batch_size": args.batch_size, "unroll_length": args.unroll_length}

  for name in args.tasks:
    env = tasks.make(name)
    obs_size, action_size = env.observation_size, env.action_size
    batch, rewards = random_batch(key, args.batch_size, args.unroll_length, obs_size,
                                  action_size)
    norm = normalizer.init(obs_size)
    for variant in args.variants:
      fn, fn_args, config, extra = program(variant, name, env, norm, batch, rewards, key,
                                           args.updates)
      precision = (jax.default_matmul_precision("highest") if variant == "highest"
                   else contextlib.nullcontext())
      with precision:
        seconds, compile_s, profile = time_call(fn, fn_args, args.repeats, donate_first=True,
                                                profile=args.profile, per_call=args.updates)
      ms = 1e3 * seconds / args.updates
      writer.write(kind="update_speed", task=name, variant=variant,
                   settings={**shape, "updates": args.updates, "repeats": args.repeats,
                             "observation_size": obs_size, "action_size": action_size,
                             "learner": dataclasses.asdict(config), **extra},
                   update_ms=ms, compile_s=compile_s,
                   **({} if profile is None else {"profile": profile}))
      print(f"{name:<16}{variant:<12}{ms:8.2f} ms/update  (compile {compile_s:.0f}s)",
            flush=True)
      print_profile(profile)
    retrace_args = tuple(jax.random.normal(k, (args.batch_size, args.unroll_length))
                         for k in jax.random.split(key, 5))
    retrace_args = retrace_args[:3] + (jnp.full_like(retrace_args[3], 0.99),) + retrace_args[4:]
    for label, unroll in (("retrace_loop", 1), ("retrace_unrolled", True)):
      seconds, compile_s, _ = time_call(retrace_fn(unroll, args.updates), (retrace_args,),
                                           args.repeats, donate_first=False)
      ms = 1e3 * seconds / args.updates
      writer.write(kind="update_speed", task=name, variant=label,
                   settings={**shape, "updates": args.updates, "repeats": args.repeats},
                   retrace_ms=ms, compile_s=compile_s)
      print(f"{name:<16}{label:<18}{ms:8.3f} ms/call  (compile {compile_s:.0f}s)", flush=True)
  print(f"results appended to {args.out}")
  return 0


if __name__ == "__main__":
  sys.exit(main())
