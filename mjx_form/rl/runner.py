"""The Python side of a training run: progress lines, CSV (and TensorBoard) logs, evaluation,
checkpoints, resume, and the exported policy. Each step of work is one compiled
`Trainer.iteration`; nothing here touches per-step data.

A population (several seeds, or members with their own settings: mjx_form.rl.grid) writes
config.json and checkpoints/ (all members) in the run directory and everything else per member
in <run directory>/seed<s>/ (seed<s>_<setting><value>/ for a member with its own settings).

Run directory layout:
  config.json         the run's TrainConfig (a resumed run must match it)
  progress.csv        one row per logged iteration: env steps, wall clock, steps/s, returns, losses
                      (wall clock counts on across resumes: a resumed run continues the clock
                      of the checkpoint it starts from, and rows logged after that checkpoint
                      are dropped)
  checkpoints/        orbax checkpoints of the whole TrainState (replay and env states included,
                      so a stopped and resumed run ends where an uninterrupted one ends), or with
                      `checkpoint_replay=False` lean ones: networks, optimiser and dual states,
                      normaliser, reward source, RNG key and iteration (a few MB, small enough to
                      carry between machines); a run resumed from a lean checkpoint starts with
                      an empty replay and fresh episodes, so it does not repeat an uninterrupted
                      run exactly
  policy.npz          the final policy (+ observation normaliser), see mjx_form.files.policy_io
  best_policy.npz     the policy of the run's best evaluation so far (same format), written at
                      each evaluation that beats it: a run whose evaluations dip late keeps it
  best_log_pd_policy.npz  (FORM) the policy of the evaluation whose episodes the demonstrator
                      scores highest (their mean log pD per transition): the best an imitator
                      can choose without the task reward
  average_policy.npz  (`policy_average_decay` > 0) the policy averaged over updates
                      (mjx_form.rl.learner), written with policy.npz; each evaluation scores it
                      too (eval_return_average), on the same starts
  best_log_pd_average_policy.npz  (FORM, with an average) the average policy of the evaluation
                      whose episodes the demonstrator scores highest: the same choice, without
                      the task reward, among the average's evaluations
  imitator.npz        (FORM) the imitator model beside policy.npz, written with it: what the
                      reward subtracted (log pI) at the run's end, as an effect-model file
                      (mjx_form.files.effect_models; a run refuses it as a demonstrator)
"""

from __future__ import annotations

import concurrent.futures
import csv
import dataclasses
import json
import math
import os
import time

import jax
import jax.numpy as jnp
import numpy as np

from mjx_form import mesh as mesh_lib
from mjx_form.files import checkpoint, experts, policy_io, results
from mjx_form.rl import grid, normalizer
from mjx_form.rl.learner import LearnerConfig
from mjx_form.rl.train import TrainConfig, Trainer, iterations_for

# Settings that may change when a run is resumed (they do not change what is computed).
RESUMABLE = ("total_env_steps", "log_every", "eval_every", "checkpoint_every", "eval_on_host")
# Settings added since checkpoints were first written, with the value that does what runs did
# before them: a checkpoint whose config lacks one resumes only with that value.
ADDED_SETTINGS = {"learner.mpo.action_penalty": False, "learner.mpo.epsilon_penalty": 1e-3,
                  "learner.clip_critic_actions": False, "learner.sampled_q_bfloat16": False,
                  "policy_head": "paper", "action_noise_correlation": 0.0,
                  "wrap_angles": False, "init_policy": None, "angle_features": False,
                  "learner.policy_average_decay": 0.0, "source_update_every": 1,
                  "learner.sampled_q_float32_head": False, "noise_scale_min": 1.0,
                  "learner.cloning_loss": "likelihood", "learner.mpo.clip_mean_targets": False}


# Columns that not every row has (evaluation rows; devices that report memory).
_OPTIONAL_COLUMNS = ("eval_return", "eval_return_std", "peak_memory_bytes")


class RunError(ValueError):
  """A run that cannot start as asked (e.g. an existing directory without --resume)."""


def _scalar(x) -> float:
  return float(np.asarray(x))


def _show(x: float) -> str:
  return f"{x:.1f}" if np.isfinite(x) else "-"


class CsvLog:
  """Appends rows to progress.csv (columns fixed by the first row) and, when tensorboardX is
  installed, the same scalars to TensorBoard event files in the run directory."""

  def __init__(self, directory: str, optional: tuple[str, ...] = _OPTIONAL_COLUMNS):
    self.path = os.path.join(directory, "progress.csv")
    self._optional = optional  # columns not every row has
    self._columns = None
    if os.path.exists(self.path):
      with open(self.path) as f:
        header = f.readline().strip()
      self._columns = header.split(",") if header else None
    try:
      from tensorboardX import SummaryWriter
      self._tb = SummaryWriter(os.path.join(directory, "tb"))
    except ImportError:
      self._tb = None

  def rewind(self, iteration: int) -> float:
    """Drops the rows after `iteration` (logged after the checkpoint a run resumes from);
    returns the wall clock of the last row kept (0 if none)."""
    if not os.path.exists(self.path):
      return 0.0
    with open(self.path, newline="") as f:
      rows = list(csv.DictReader(f))
    kept = [r for r in rows if int(r["iteration"]) <= iteration]
    with open(self.path, "w", newline="") as f:
      writer = csv.DictWriter(f, fieldnames=self._columns)
      writer.writeheader()
      writer.writerows(kept)
    return float(kept[-1]["wall_s"]) if kept else 0.0

  def write(self, row: dict) -> None:
    if self._columns is None:
      self._columns = list(row) + [c for c in self._optional if c not in row]
      with open(self.path, "w", newline="") as f:
        csv.writer(f).writerow(self._columns)
    with open(self.path, "a", newline="") as f:
      csv.writer(f).writerow([row.get(c, "") for c in self._columns])
    if self._tb is not None:  # (not NaN: no return before the first episode ends)
      for k, v in row.items():
        if isinstance(v, (int, float)) and k != "env_steps" and np.isfinite(v):
          self._tb.add_scalar(k, v, row["env_steps"])
      self._tb.flush()


def check_run_dir(directory: str, resume: bool, also: tuple[str, ...] = ()) -> None:
  """Refuses to start a new run in a directory that holds one (its config.json or any file
  named in `also`), and to resume one that holds none; raises RunError."""
  config_path = os.path.join(directory, "config.json")
  if not resume:
    taken = [name for name in ("config.json", *also) if os.path.exists(os.path.join(directory,
                                                                                    name))]
    if taken:
      raise RunError(f"{directory} already holds a run ({', '.join(taken)}); pass --resume to "
                     "continue it or choose another --run_dir (nothing was overwritten)")
  elif not os.path.exists(config_path):
    raise RunError(f"--resume: {directory} holds no run to continue")


def check_initial_policy(trainer: Trainer, policy: experts.Expert | None) -> None:
  """Refuses (RunError, naming the problem) a starting policy that the run's config does not
  name, or whose network, angle wrapping or angle features differ from the run's members'."""
  named = trainer.config.init_policy
  if policy is None:
    if named is not None:
      raise RunError(f"the config starts from the policy {named!r}, but none was given")
    return
  meta = policy.metadata
  if named != experts.policy_id(policy):
    raise RunError(f"the config starts from {named!r}, the policy given is "
                   f"{experts.policy_id(policy)!r}")
  for key, default in (("network_width", None), ("policy_head", "paper")):
    theirs, ours = meta.get(key, default), getattr(trainer.config, key)
    if theirs != ours:
      raise RunError(f"the starting policy ({meta['task']}) has {key} {theirs!r}, this run "
                     f"{ours!r}: pass --{key} {theirs}")
  # The angles the policy saw wrapped (its normaliser's period; none: zeros) must be the ones
  # each member wraps (a task without unbounded angles wraps none either way).
  size = trainer.env.observation_size
  periods = trainer.env.observation_period()
  _check_angle_view(trainer, meta["task"], "wrap_angles", periods, policy.normalizer.period,
                    "angles wrapped", ("does not wrap them", "wraps them"))
  # Likewise the angles it saw as cos and sin (its normaliser's `angles`; none: zero rows), and
  # its inputs' number (a member that saw the raw angle beside members that did not had D + 2K).
  rows = normalizer.angle_rows(periods)
  featured = any(trainer.member_config(i).angle_features for i in range(trainer.members))
  width = size + (2 * len(rows) if featured else 0)
  if policy.normalizer.mean.shape[-1] != width:
    raise RunError(f"the starting policy ({meta['task']}) takes "
                   f"{policy.normalizer.mean.shape[-1]} observation features, this run's "
                   f"networks {width} (a policy of a population member beside members with "
                   "angle features needs a run with the same --grid angle_features)")
  _check_angle_view(trainer, meta["task"], "angle_features", rows, policy.normalizer.angles,
                    "angles as cos and sin", ("does not", "does"))


def _check_angle_view(trainer: Trainer, task: str, name: str, on, theirs, seen: str,
                      member_does: tuple[str, str]) -> None:
  """RunError unless every member's setting `name` gives what the starting policy's normaliser
  holds (`theirs`: its period or angles, None for none): `on` where the member's flag is set,
  zeros where not. `seen` and `member_does` (its negative, its positive) word the message."""
  theirs = np.zeros_like(on) if theirs is None else np.asarray(theirs)
  sees = bool(np.any(theirs))
  for i in range(trainer.members):
    ours = on if getattr(trainer.member_config(i), name) else np.zeros_like(on)
    if theirs.shape != ours.shape or not np.array_equal(theirs, ours):
      fix = (f"give all members one setting (not --grid {name})" if name in trainer.overrides[i]
             else f"pass --{'' if sees else 'no-'}{name}")
      raise RunError(f"the starting policy ({task}) saw {'its' if sees else 'no'} {seen}, "
                     f"member {i} of this run {member_does[0] if sees else member_does[1]}: "
                     f"{fix}")


def member_dirs(directory: str, seeds: tuple[int, ...],
                overrides: tuple[dict, ...] | None = None) -> list[str]:
  """Where each member writes its logs and policies: the run directory itself for a single
  run, <directory>/seed<s> for the members of a population."""
  if len(seeds) == 1:
    return [directory]
  overrides = overrides or tuple({} for _ in seeds)
  return [os.path.join(directory, grid.dirname(s, o)) for s, o in zip(seeds, overrides)]


def run(config: TrainConfig, directory: str, total_env_steps: int, *, resume: bool = False,
        log_every: int = 1, eval_every: int = 10, checkpoint_every: int = 50,
        max_seconds: float | None = None, results_path: str | None = None,
        checkpoint_replay: bool = True, final_eval_envs: int = 0, mesh=None, reward_source=None,
        seeds: tuple[int, ...] | None = None, overrides: tuple[dict, ...] | None = None,
        initial_policy: experts.Expert | None = None, seconds_before: float = 0.0,
        eval_on_host: bool = False, host_devices=None, stop_file: str | None = None,
        record_fields: dict | None = None, print_fn=print) -> list[dict]:
  """Trains until `total_env_steps`; returns each member's last logged row (with its final
  evaluation).

  `seeds`: run a population, one member per seed, in one compiled program (default:
  `config.seed` alone); `overrides`: each member's own settings (mjx_form.rl.grid). Each member
  writes progress.csv, policy.npz and best_policy.npz (FORM: also best_log_pd_policy.npz; with
  `policy_average_decay` > 0 average_policy.npz) to its own directory (`member_dirs`) and its
  own records (its seed and settings in them); one checkpoint in `directory` holds every member.
  `reward_source`: where the learner's rewards come from (default: the task reward, by
  `config.reward_source`); its `settings()` are part of the run's checked configuration.
  `final_eval_envs`: once training is finished, the final, average and best policies are
  evaluated afresh on this many episodes and written as `kind: final_return` records (0: not); a run
  stopped by `max_seconds` gets them too, where it stopped (`finished: false` in them: a
  time-budgeted run's result), and again at its end if resumed.
  `max_seconds`: stop once `seconds_before` (what the command spent before this call:
  recording demonstrations, training a demonstrator) and this call's time reach it (checked
  after each iteration; the final evaluations come after); the state is checkpointed and the
  policy exported, so `resume=True` continues the run. Records keep `seconds_before` as
  `pre_training_s`; their `wall_s` counts from this call.
  `stop_file`: once this path exists (checked after each iteration, the first included: a stop
  asked for while demonstrations were recorded gives one iteration) the run stops there as
  `max_seconds` stops it (checkpoint, exported policies, final evaluations):
  `scripts/gpu_jobs.py poll --stop` ends a sitting's runs early this way (run.py refuses a stop
  file that exists when the command starts).
  `record_fields`: what the command knows of the run that its records should carry (the
  baselines: `demonstrations_return`, the mean task return of the demonstrations they imitate).
  `results_path`: where `kind: learning_curve` records (one per evaluation) are appended.
  `checkpoint_replay`: False writes lean checkpoints (see the module docstring).
  `initial_policy`: a trained policy (of this task or another with its observation layout) that
  every member starts from (`Trainer.start_from`; a resumed run continues from its checkpoint);
  `config.init_policy` must name it (`experts.policy_id`).
  `eval_on_host`: the periodic evaluations run on the host's CPU (`host_devices`, default its
  CPU devices: the batch split over them, see `_HostEvaluation`) while training goes on: the
  same evaluation (program and starts) on copies of the evaluated policies, in the host's
  arithmetic (its returns differ from an accelerator's in rounding, e.g. a GPU's TF32
  products, which grows over 1000-step episodes; the records say `eval_on_host`). An evaluation's rows (progress line, CSV, record, best policies) are written
  once it is done, in order, with their iteration's `wall_s` (its own evaluation's time not in
  it). Due while the last one runs, an evaluation waits for it; so does a checkpoint and the
  run's end, after `max_seconds` too (`eval_s` counts the waits). The last iteration of a run
  that `max_seconds` stopped is not evaluated periodically; the final evaluations stay on the
  accelerator.
  """
  run_settings = {"total_env_steps": total_env_steps, "log_every": log_every,
                  "eval_every": eval_every, "checkpoint_every": checkpoint_every,
                  "checkpoint_replay": checkpoint_replay,
                  **({"eval_on_host": True} if eval_on_host else {})}
  ckpt_dir = os.path.join(os.path.abspath(directory), "checkpoints")
  config_path = os.path.join(directory, "config.json")
  check_run_dir(directory, resume)
  if max_seconds is not None and max_seconds <= 0:
    raise RunError(f"max_seconds must be positive, got {max_seconds}")

  call_start = time.perf_counter()
  budget_start = call_start - seconds_before  # where max_seconds counts from
  if max_seconds is not None and seconds_before > 0:
    print_fn(f"--max_seconds {max_seconds:g}: {seconds_before:.0f}s spent before training, "
             f"{max(max_seconds - seconds_before, 0.0):.0f}s left for it")
  trainer = Trainer(config, mesh, reward_source, seeds, overrides)
  check_initial_policy(trainer, initial_policy)
  full_config = {**config.to_dict(), "seeds": list(trainer.seeds),
                 "reward": trainer.source.settings(), **run_settings}
  if any(trainer.overrides):  # (absent otherwise: checkpoints from before grids match)
    full_config["overrides"] = [dict(sorted(o.items())) for o in trainer.overrides]
  restored = None
  if resume and checkpoint.latest_step(ckpt_dir) is not None:  # refused before compiling
    restored = checkpoint.restore(ckpt_dir, _checkpointed(trainer.abstract_state,
                                                          checkpoint_replay),
                                  full_config, ignore=RESUMABLE, added=ADDED_SETTINGS)
  elif resume and os.path.exists(config_path):  # stopped before its first checkpoint
    with open(config_path) as f:
      checkpoint.check_config(config_path, json.load(f), full_config, RESUMABLE, ADDED_SETTINGS)
  eval_keys = trainer.keys(1)
  # The policy averaged over updates (`policy_average_decay`) is evaluated beside the online one,
  # on the same starts and in the same call. (In a population, members at decay 0 beside
  # averaging ones keep a copy of their policy: not evaluated, exported or recorded as an
  # average.)
  averaging = [trainer.member_config(i).learner.policy_average_decay > 0
               for i in range(trainer.members)]
  averages = any(averaging)  # (the state keeps average policies: Trainer._init_learner)
  periodic = _per_call(trainer, 2 if averages else 1, trainer.config.eval_envs)
  print_fn("compiling the run's programs (init, iteration, evaluation"
           + (" on the host" if eval_on_host else "") + ") ...")
  compile_start = time.perf_counter()
  with results.count_persistent_cache_hits() as cache_hits:
    # (the host's evaluation program compiles beside the others)
    with concurrent.futures.ThreadPoolExecutor(1) as pool:
      built = (pool.submit(_HostEvaluation, trainer, host_devices, eval_keys, periodic)
               if eval_on_host else None)
      trainer.compile_ahead(eval_keys, policies_per_evaluation=periodic,
                            evaluation=not eval_on_host)
      host = built.result() if built else None
  print_fn(f"compiled in {time.perf_counter() - compile_start:.0f}s"
           + (f" ({cache_hits[0]} programs from the persistent cache)" if cache_hits[0] else ""))
  # A periodic evaluation of the state's policies (and average ones): on the host, running
  # when this returns; on the accelerator, done.
  start_evaluation = lambda state: (
      host.start(state, _held(state, averages)) if host is not None
      else _Evaluation.now(trainer, state, _held(state, averages), eval_keys))
  state = trainer.init(trainer.keys())
  # This call's time before its first iteration: building, tracing, compiling, init.
  startup = {"startup_s": time.perf_counter() - call_start,
             "persistent_cache_hits": cache_hits[0], "pre_training_s": round(seconds_before, 2),
             **(record_fields or {})}
  if restored is not None:
    state = restored if checkpoint_replay else state._replace(**restored)
    print_fn(f"resumed from iteration {int(state.iteration)} ({ckpt_dir})")
  elif initial_policy is not None:
    state = trainer.start_from(state, initial_policy.params, initial_policy.normalizer)
    meta = initial_policy.metadata
    # (beside its average, a copy of it here: the periodic evaluations' program, compiled)
    evaluation = start_evaluation(state)
    evaluation.wait()
    returns = evaluation.results[0][0]
    print_fn(f"every member starts from {meta['task']}'s policy {meta['sha256'][:12]} "
             f"(exported at {meta.get('env_steps') or 0:,} env steps): it evaluates "
             f"{returns.mean():.1f} on {config.task} ({returns.size} episodes)")
  os.makedirs(directory, exist_ok=True)
  with open(config_path, "w") as f:
    json.dump(full_config, f, indent=1)
  dirs = member_dirs(directory, trainer.seeds, trainer.overrides)
  labels = [grid.label(s, o) for s, o in zip(trainer.seeds, trainer.overrides)]
  for d in dirs:
    os.makedirs(d, exist_ok=True)
  scored = ("eval_demonstrator_log_prob",) if trainer.evaluation_inputs(state) else ()
  average_columns = tuple(f"{k}_average" for k in ("eval_return", "eval_return_std", *scored)
                          ) if averages else ()
  logs = [CsvLog(d, _OPTIONAL_COLUMNS + scored + average_columns) for d in dirs]
  wall_offset = max(log.rewind(int(state.iteration)) for log in logs) if resume else 0.0
  curve = results.ResultWriter(results_path) if results_path else None

  kept = [b for b in BEST + AVERAGE_BEST  # (name, key, file)
          if b[1] == "eval_return" or b[1] in scored + average_columns]
  best_paths = {name: [os.path.join(d, file) for d in dirs] for name, _, file in kept}
  best_values = {name: [_resumed_best(path, key, first) if resume else -np.inf
                        for path, first in zip(best_paths[name], best_paths["best"])]
                 for name, key, _ in kept}
  total_iterations = iterations_for(config, total_env_steps)
  steps_per_iteration = config.env_steps_per_iteration
  population = (f"a population of {trainer.members} ({'; '.join(labels)}), "
                if trainer.members > 1 else "")
  print_fn(f"{config.task}: {population}{config.num_envs} envs x {config.unroll_length}-step "
           f"unrolls, {config.updates_per_iteration} updates per iteration (updates/env step "
           f"{config.updates_per_env_step:.2e}, replay ratio {config.replay_ratio:.2f}), "
           + (f"the reward source trained on 1 batch in {config.source_update_every}, "
              if config.source_update_every > 1 else "")
           + f"{total_iterations} iterations, physics {config.physics}, "
           f"{trainer.mesh.devices.size} {jax.default_backend()} device(s)"
           + (f" ({_LAYOUT_WORDS[trainer.layout]})"
              if trainer.members > 1 and trainer.mesh.devices.size > 1 else ""))
  start_iteration = int(state.iteration)
  startup["start_iteration"] = start_iteration  # (> 0: a resumed run's later part)
  timed_steps, timed_seconds, eval_seconds = 0, 0.0, 0.0
  # Each member's last row; a run resumed at its end (no iteration left) keeps where it stopped.
  rows = [{"iteration": start_iteration, "env_steps": start_iteration * steps_per_iteration,
           "wall_s": wall_offset} for _ in dirs]
  stopped = False  # by max_seconds, before total_env_steps
  overtime_iterations = 0  # trained past max_seconds while the host finished an evaluation
  due_since = None  # the iteration since which a checkpoint is due
  # Each iteration's rows wait here, in order, for their evaluation (done at once on the
  # accelerator; on the host once its program has run): [(rows, logged, evaluation or None)].
  waiting = []

  def host_running() -> bool:
    """Whether an evaluation on the host is still running."""
    return host is not None and any(e is not None and not e.done() for *_, e in waiting)

  def write_rows(block: bool) -> None:
    """Writes the waiting rows whose evaluation is done (all of them, waiting, with `block`)."""
    nonlocal eval_seconds  # (a wait counts in the rows of the iterations after it)
    while waiting:
      member_rows, logged, evaluation = waiting[0]
      if evaluation is not None:
        if not (block or evaluation.done()):
          return
        t0 = time.perf_counter()
        evaluation.wait()  # (at once where done)
        eval_seconds += time.perf_counter() - t0
      waiting.pop(0)
      for i, row in enumerate(member_rows):
        if evaluation is not None:
          _take_evaluation(trainer, row, i, evaluation, averaging[i], kept, best_values,
                           best_paths)
        if logged:
          logs[i].write(row)
          prefix = f"{labels[i]}: " if trainer.members > 1 else ""
          print_fn(prefix + _progress_line(row, total_iterations, steps_per_iteration))
        if curve is not None and evaluation is not None:
          _write_curve_point(curve, trainer, i, row, eval_episodes=evaluation.episodes,
                             total_env_steps=total_env_steps, startup=startup,
                             on_host=host is not None)
        rows[i] = row

  while int(state.iteration) < total_iterations:
    t0 = time.perf_counter()
    state, metrics = trainer.iteration(state)
    metrics = jax.device_get(metrics)
    seconds = time.perf_counter() - t0
    iteration = int(state.iteration)
    if iteration > start_iteration + 1:  # the first call warms up
      timed_steps += steps_per_iteration
      timed_seconds += seconds
    finished = iteration == total_iterations
    spent = max_seconds is not None and time.perf_counter() - budget_start >= max_seconds
    overtime = spent or (stop_file is not None and os.path.exists(stop_file))
    # (on the host, a run out of time trains on, starting no evaluation, until the one running
    # there is done: the accelerator does not wait idle for it)
    host_busy = host_running()
    out_of_time = overtime and not host_busy
    overtime_iterations += overtime and host_busy
    last = finished or out_of_time
    # (on the host, the last iteration of a run that `max_seconds` stopped is not evaluated:
    # its final evaluations, on the accelerator, come after it at once)
    evaluate = ((iteration % eval_every == 0 and not overtime)
                or (last and (host is None or finished)))
    evaluation = None
    if evaluate:
      write_rows(block=True)  # (one evaluation at a time on the host; at once otherwise)
      t0 = time.perf_counter()
      evaluation = start_evaluation(state)
      eval_seconds += time.perf_counter() - t0
    wall = wall_offset + time.perf_counter() - call_start
    peak = results.peak_memory_bytes()
    if iteration % checkpoint_every == 0 and due_since is None:
      due_since = iteration
    # (on the host, a due checkpoint waits for the evaluation running there, training on: its
    # rows come first, and the accelerator does not wait idle)
    busy = host is not None and (evaluation is not None or host_running())
    # (forced, blocking, after checkpoint_every iterations: at one that starts no evaluation,
    # to wait for one already running there; at worst ~2 checkpoint_every apart)
    checkpointed = last or (due_since is not None and (
        not busy or (iteration - due_since >= checkpoint_every and evaluation is None)))
    updates = np.asarray(state.learner.updates)
    member_rows = []
    for i in range(trainer.members):
      # Wall clock of the run so far (compilation included, and an evaluation on the
      # accelerator); eval_s is the part spent in evaluation (or waiting for one on the host)
      # in this process.
      row = {"iteration": iteration, "env_steps": iteration * steps_per_iteration,
             "updates": int(updates[i]),
             "steps_per_s": timed_steps / timed_seconds if timed_seconds else float("nan"),
             **{k: _scalar(v[i]) for k, v in metrics.items()}, "wall_s": wall,
             "eval_s": eval_seconds}
      if peak is not None:
        row["peak_memory_bytes"] = peak
      member_rows.append(row)
    waiting.append((member_rows, iteration % log_every == 0 or last or evaluate or checkpointed,
                    evaluation))
    # (the rows before a checkpoint are written before it: a resumed run's CSV has no gap)
    write_rows(block=checkpointed)
    if checkpointed:
      checkpoint.save(ckpt_dir, iteration, _checkpointed(state, checkpoint_replay), full_config)
      due_since = None
    if out_of_time and not finished:
      why = (f"--max_seconds {max_seconds:g}, counted from the command's start" if spent else
             f"the stop file {stop_file} appeared")
      print_fn(f"stopped after {time.perf_counter() - budget_start:.0f}s ({why}) at iteration "
               f"{iteration}/{total_iterations}"
               + (f", training on for {overtime_iterations} iteration(s) while the host "
                  f"finished its evaluation" if overtime_iterations else "")
               + " (checkpointed; continue with --resume)")
      stopped = True
      break
  write_rows(block=True)

  exported = int(state.iteration) > start_iteration
  if exported:
    for i, d in enumerate(dirs):
      export_policy(trainer, state, i, os.path.join(d, "policy.npz"), rows[i])
      if averaging[i]:
        export_policy(trainer, state, i, os.path.join(d, AVERAGE_FILE), _average_row(rows[i]),
                      params=state.learner.average_policy)
      export_source(trainer, state, i, d, rows[i])
  if final_eval_envs and (stopped or int(state.iteration) == total_iterations):
    final_paths = [os.path.join(d, "policy.npz") for d in dirs] if exported else None
    _final_evaluation(trainer, state, best_paths, rows, final_eval_envs, curve,
                      total_env_steps, labels, print_fn, finished=not stopped,
                      final_paths=final_paths, averaging=averaging,
                      record_fields=record_fields)
  return rows


def _final_evaluation(trainer: Trainer, state, best_paths: dict[str, list[str]],
                      rows: list[dict], episodes: int, curve, total_env_steps: int,
                      labels: list[str], print_fn, finished: bool = True,
                      final_paths: list[str] | None = None,
                      averaging: list[bool] | None = None,
                      record_fields: dict | None = None) -> None:
  """Every member's final policy (the state's; exported to `final_paths`, where given), its
  average policy (the state's, for the members `averaging` says keep one) and each of its best
  ones (`best_paths`: {BEST or AVERAGE_BEST name: each member's file}) on `episodes` fresh
  episodes: kind final_return (`finished`: False where `max_seconds` stopped the run before
  `total_env_steps`). A best policy whose files hold, for every member, the arrays of one
  evaluated before (often: the best by log pD is the best by return) is not evaluated again:
  its records repeat that evaluation's, what evaluating it again on the same episodes (`keys`)
  gives to float precision, and say so (`same_policy_as`)."""
  keys = trainer.keys(2)
  sha256 = lambda paths: tuple(policy_io.load_policy(p)[1]["sha256"] for p in paths)
  final_shas = sha256(final_paths) if final_paths else None
  # (name, files, shas); the final policy also with its actions drawn from it
  policies = [("final", None, final_shas), ("final_sampled", None, final_shas)]
  chosen_from_average = []  # (evaluated after the average policy, which they may repeat)
  for name, paths in best_paths.items():
    keeps, missing = _member_files(name, paths, averaging)
    if missing:
      print_fn(f"no {os.path.basename(paths[missing[0]])} for "
               f"{', '.join(labels[i] for i in missing)}: the {_POLICY_WORDS[name]} is not "
               "evaluated afresh")
    elif any(keeps):
      # (members that keep no average stand in with the file of one that does: evaluated,
      # not recorded)
      paths = [p if keep else paths[keeps.index(True)] for p, keep in zip(paths, keeps)]
      (chosen_from_average if name in _AVERAGE_BEST_NAMES else policies).append(
          (name, paths, sha256(paths)))
  if any(averaging or ()):  # (the exported files' sha256s where every member wrote one now)
    files = ([os.path.join(os.path.dirname(p), AVERAGE_FILE) for p in final_paths]
             if final_paths else [])
    policies.append(("average", None, sha256(files) if files and all(averaging) else None))
  policies += chosen_from_average
  # Each distinct policy (by its members' sha256s, where known, and how it acts) is evaluated
  # once, and all of them together (`_evaluated`); a repeat's records are the first's.
  first_of = {}  # (each member's sha256s, sampled) -> the index in `policies` of the first
  pending = []  # (index in `policies`, (policy, normaliser))
  same_as = lambda name, shas: (shas, name == "final_sampled")  # (first_of's key)
  for j, (name, paths, shas) in enumerate(policies):
    if shas is not None and same_as(name, shas) in first_of:
      continue
    if shas is not None:
      first_of[same_as(name, shas)] = j
    held = state.learner.average_policy if name == "average" else state.learner.policy
    pending.append((j, _stacked(trainer, state, paths) if paths is not None
                    else (held, state.normalizer)))
  evaluated = dict(zip([j for j, _ in pending],
                       _evaluated(trainer, state, [pair for _, pair in pending], keys,
                                  num_envs=episodes,
                                  sampled=[policies[j][0] == "final_sampled"
                                           for j, _ in pending])))
  for j, (name, paths, shas) in enumerate(policies):
    same = None
    if j in evaluated:
      returns, scores = evaluated[j]
    else:
      first = first_of[same_as(name, shas)]
      same = policies[first][0]
      returns, scores = evaluated[first]
    for i in range(trainer.members):
      if (name == "average" or name in _AVERAGE_BEST_NAMES) and not averaging[i]:
        continue
      rows[i][f"{name}_policy_return"] = float(returns[i].mean())
      scored = ({} if scores is None
                else {"eval_demonstrator_log_prob": float(scores[i].mean())})
      result = (f"{returns[i].mean():.1f} +- {returns[i].std():.1f}"
                + (f" (log pD {scores[i].mean():.1f})" if scored else ""))
      print_fn((f"{labels[i]}: " if trainer.members > 1 else "")
               + (f"fresh evaluation of the {_POLICY_WORDS[name]} over {returns.shape[1]} "
                  f"episodes: {result}" if same is None else
                  f"the {_POLICY_WORDS[name]} holds the {_POLICY_WORDS[same]}'s arrays: "
                  f"{result}, not evaluated again"))
      if curve is not None:
        curve.write(**_record_base(trainer, i), **(record_fields or {}), kind="final_return",
                    policy=name,
                    final_return=float(returns[i].mean()),
                    final_return_std=float(returns[i].std()), **scored,
                    episodes=int(returns.shape[1]),
                    **({"policy_sha256": shas[i]} if shas is not None else {}),
                    **({"same_policy_as": same} if same is not None else {}),
                    env_steps=rows[i]["env_steps"], wall_s=rows[i]["wall_s"], finished=finished,
                    settings=_record_settings(trainer, i, total_env_steps))


def _member_files(name: str, paths: list[str], averaging: list[bool] | None
                  ) -> tuple[list[bool], list[int]]:
  """For the kept policy `name` (each member's file in `paths`): whether each member keeps one
  (every member; for the average's bests, `AVERAGE_BEST`, the members that average) and the
  members that should and have none (a run started before the file existed, or whose
  evaluations' log pD was never finite)."""
  keeps = [name not in _AVERAGE_BEST_NAMES or bool(averaging and averaging[i])
           for i in range(len(paths))]
  return keeps, [i for i, (keep, p) in enumerate(zip(keeps, paths))
                 if keep and not os.path.exists(p)]


def _stacked(trainer: Trainer, state, paths: list[str]):
  """The members' policies and normalisers in `paths` (one file each), stacked [P, ...] and
  placed as `state`'s own."""
  bests = [experts.load_expert(path, trainer.env) for path in paths]
  best_policy = jax.tree.map(lambda *x: jnp.stack(x), *[b.params for b in bests])
  norms = [b.normalizer for b in bests]
  if state.normalizer.period is not None:  # members that wrap beside ones that do not (zeros)
    norms = [n if n.period is not None else n._replace(
        period=jnp.zeros((normalizer.input_size(n),), n.mean.dtype)) for n in norms]
  best_norm = jax.tree.map(lambda *x: jnp.stack(x), *norms)
  # Placed as the state's own policy and normaliser are, so that the best policy's evaluation
  # is the final one's program (read from the files they would lie on one device: another
  # input sharding, and the evaluation traced and compiled a second time).
  return jax.device_put((best_policy, best_norm), (trainer.state_sharding.learner.policy,
                                                   trainer.state_sharding.normalizer))


# The most environments one evaluation call steps (members x policies x episodes) where it
# evaluates several policies: more policies go to further calls of equal size. (An evaluation's
# environments are held beside the training state; the iteration's memory check does not count
# them.)
EVALUATION_ENVS = 8192


def _per_call(trainer: Trainer, policies: int, episodes: int) -> int:
  """How many of `policies` policies one evaluation call takes (`_evaluated`)."""
  calls = math.ceil(policies / max(1, EVALUATION_ENVS // (trainer.members * episodes)))
  return math.ceil(policies / calls)


def _held(state, averages: bool) -> list:
  """What a periodic evaluation evaluates: (policy, normaliser) of the state's online policy
  and, where the run keeps one (`averages`), of its average policy."""
  return [(state.learner.policy, state.normalizer)] + (
      [(state.learner.average_policy, state.normalizer)] if averages else [])


def _dispatched(trainer: Trainer, pairs: list, keys, inputs: dict, num_envs: int | None = None,
                sampled: list[bool] | None = None) -> list:
  """Starts the evaluation of each (policy [P, ...], normaliser [P, ...]) of `pairs` together,
  on the same starts (`keys`), up to EVALUATION_ENVS environments per call; calls are of one
  size (the last padded with a repeat of its first pair): one program. `inputs`: the
  evaluation's source inputs (`Trainer.evaluation_inputs`); `sampled`: for each pair, whether
  its actions are drawn from the policy (default: its mean actions, all). Returns the calls'
  outputs, not waited for (`_gathered`)."""
  per_call = _per_call(trainer, len(pairs), num_envs or trainer.config.eval_envs)
  more = {} if num_envs is None else {"num_envs": num_envs}
  outputs = []
  for start in range(0, len(pairs), per_call):
    chunk = pairs[start:start + per_call]
    padded = chunk + chunk[:1] * (per_call - len(chunk))
    if sampled is not None:
      drawn = sampled[start:start + per_call]
      more["sampled"] = np.asarray(drawn + drawn[:1] * (per_call - len(drawn)), np.float32)
    outputs.append((len(chunk), trainer.evaluate(
        tuple(p for p, _ in padded), tuple(m for _, m in padded), keys, **inputs, **more)))
  return outputs


def _gathered(outputs: list) -> list[tuple[np.ndarray, np.ndarray | None]]:
  """`_dispatched`'s outputs as, for each pair in order, its returns [P, n] and, where the
  run's source scores the episodes (FORM: their mean log pD per transition,
  `Trainer.evaluate`), the scores [P, n], else None (one transfer per call)."""
  out = []
  for count, result in outputs:
    result = jax.device_get(result)
    returns, scores = result if isinstance(result, tuple) else (result, None)
    out += [(np.asarray(returns[j]), None if scores is None else np.asarray(scores[j]))
            for j in range(count)]
  return out


def _evaluated(trainer: Trainer, state, pairs: list, keys, num_envs: int | None = None,
               sampled: list[bool] | None = None) -> list[tuple[np.ndarray, np.ndarray | None]]:
  """For each (policy, normaliser) of `pairs`, in order, its evaluation's returns [P, n] and
  scores [P, n] or None (`_dispatched`, `_gathered`), on the accelerator, waited for."""
  return _gathered(_dispatched(trainer, pairs, keys, trainer.evaluation_inputs(state),
                               num_envs, sampled))


@dataclasses.dataclass
class _Evaluation:
  """A periodic evaluation of `pairs` (the (policy, normaliser) it evaluates: the state's, or
  copies of them on the host), done (`results`) or running (`outputs` of `_dispatched`)."""

  pairs: list
  episodes: int
  outputs: list | None = None
  results: list | None = None

  @classmethod
  def now(cls, trainer: Trainer, state, pairs: list, keys) -> "_Evaluation":
    return cls(pairs, trainer.config.eval_envs, results=_evaluated(trainer, state, pairs, keys))

  def done(self) -> bool:
    return self.results is not None or all(
        leaf.is_ready() for _, out in self.outputs for leaf in jax.tree.leaves(out))

  def wait(self) -> None:
    if self.results is None:
      self.results = _gathered(self.outputs)
      self.outputs = None


class _HostEvaluation:
  """Periodic evaluations on the host's CPU: the run's evaluation program for a copy of its
  trainer on a mesh of CPU devices (`devices`, default all of them: XLA steps a batch on one
  CPU device with few of its cores, so run.py's --eval_on_host asks JAX for one per core,
  and the batch is split over as many as divide it), compiled on construction for `policies`
  policies per call; `start` copies what it evaluates there and returns at once."""

  def __init__(self, trainer: Trainer, devices, keys, policies: int):
    devices = list(devices or jax.devices("cpu"))
    batch = trainer.members * policies * trainer.config.eval_envs
    count = max(n for n in range(1, len(devices) + 1)
                if batch % n == 0 and trainer.config.num_envs % n == 0)
    self.devices = devices[:count]
    with jax.default_device(self.devices[0]):  # (its environment's model is placed there)
      self.trainer = Trainer(trainer.config, mesh_lib.make_mesh(self.devices), trainer.source,
                             trainer.seeds, trainer.overrides, source_data=False)
    self.placed = self.trainer._replicated  # (what the program takes, as it was compiled)
    self.keys = jax.device_put(keys, self.placed)
    held, norms, inputs = self.trainer.evaluation_example(policies, self.placed)
    self.trainer.evaluate.lower(held, norms, self.keys, **inputs).compile()

  def start(self, state, pairs: list) -> _Evaluation:
    # (copies, done before the next iteration takes over the state's buffers: copied where they
    # lie first, as placing them may keep a buffer where the host is the training's device)
    pairs, inputs = jax.block_until_ready(jax.device_put(jax.tree.map(
        lambda x: x.copy(), (pairs, self.trainer.evaluation_inputs(state))), self.placed))
    return _Evaluation(pairs, self.trainer.config.eval_envs,
                       outputs=_dispatched(self.trainer, pairs, self.keys, inputs))


def _take_evaluation(trainer: Trainer, row: dict, i: int, evaluation: _Evaluation,
                     averaging: bool, kept: list, best_values: dict, best_paths: dict) -> None:
  """Puts member i's part of a done periodic `evaluation` into its `row` and exports each kept
  policy (`kept`: BEST and AVERAGE_BEST entries) it beats, from the pairs evaluated."""
  (returns, scores), (policy, norm) = evaluation.results[0], evaluation.pairs[0]
  row.update(eval_return=float(returns[i].mean()), eval_return_std=float(returns[i].std()))
  if scores is not None:  # (FORM: log pD of the evaluation episodes, no task reward)
    row["eval_demonstrator_log_prob"] = float(scores[i].mean())
  if averaging:
    average_returns, average_scores = evaluation.results[1]
    row.update(eval_return_average=float(average_returns[i].mean()),
               eval_return_std_average=float(average_returns[i].std()))
    if average_scores is not None:
      row["eval_demonstrator_log_prob_average"] = float(average_scores[i].mean())
  for name, key, _ in kept:  # (a member at decay 0 has no average's key: keeps none)
    if row.get(key, -np.inf) > best_values[name][i]:
      best_values[name][i] = row[key]
      if name in _AVERAGE_BEST_NAMES:
        export_policy(trainer, None, i, best_paths[name][i], _average_row(row),
                      params=evaluation.pairs[1][0], normalizer=evaluation.pairs[1][1])
      else:
        export_policy(trainer, None, i, best_paths[name][i], row, params=policy,
                      normalizer=norm)


def _rate(steps_per_s: float) -> str:
  """Steps/s as progress lines show it; '-' before there is a timed iteration (the first one
  compiles and is not counted)."""
  return f"{steps_per_s:,.0f}" if np.isfinite(steps_per_s) else "-"


def _progress_line(row: dict, total_iterations: int, steps_per_iteration: int) -> str:
  """One line per logged iteration: steps, speed, time left, returns and learner state."""
  left = (total_iterations - row["iteration"]) * steps_per_iteration / row["steps_per_s"]
  line = (f"iter {row['iteration']}/{total_iterations}  steps {row['env_steps']:,}  "
          f"{row['wall_s']:.0f}s  {_rate(row['steps_per_s'])} steps/s"
          + (f"  ~{left:.0f}s left" if np.isfinite(left) else "")
          + f"  train return {_show(row['train_return'])}"
          + (f"  eval {row['eval_return']:.1f}" if "eval_return" in row else "")
          + (f" (log pD {row['eval_demonstrator_log_prob']:.1f})"
             if "eval_demonstrator_log_prob" in row else "")
          + (f"  average policy {row['eval_return_average']:.1f}"
             if "eval_return_average" in row else ""))
  if "form_reward" in row:
    clipped = row["form_reward_clipped"]
    line += (f"  form reward {row['form_reward']:.2f} (sd {row['form_reward_std']:.2f}"
             + (f", {100 * clipped:.1f}% clipped" if clipped > 0 else "")
             + f"; log pD {row['demonstrator_log_prob']:.1f}, log pI "
             f"{row['imitator_batch_log_prob']:.1f}"
             + (f", fresh {row['imitator_fresh_log_prob']:.1f}"
                if "imitator_fresh_log_prob" in row else "") + ")")
  if "gaifo_reward" in row:
    line += (f"  gaifo reward {row['gaifo_reward']:.3f} (sd {row['gaifo_reward_std']:.3f}; "
             f"discriminator right on {100 * row['discriminator_expert_accuracy']:.0f}% of the "
             f"expert's, {100 * row['discriminator_imitator_accuracy']:.0f}% of the imitator's)")
  if "inverse_model_log_prob" in row:
    line += (f"  inverse model log-likelihood {row['inverse_model_log_prob']:.2f} (action error "
             f"{row['inverse_model_action_error']:.4f})")
  if "bc_log_prob" in row:  # a cloning source: no critic
    return line + (f"  bc log-likelihood {row['bc_log_prob']:.2f}  action error "
                   f"{row['bc_action_error']:.4f}  mean out of bounds "
                   f"{row['mean_out_of_bounds']:.2f}")
  return line + (f"  q {row['q_mean']:.2f}  critic {row['critic_loss']:.3f}  mean out of bounds "
                 f"{row['mean_out_of_bounds']:.2f}")


# The policies a run keeps beside its final one: (name in its final_return records, the
# evaluation's value that chooses it, file). "best" by the task return; "best_log_pd" (runs
# whose source scores the evaluation episodes, FORM) by the demonstrator's mean log pD of them:
# the choice an imitator can make without the task reward.
BEST = (("best", "eval_return", "best_policy.npz"),
        ("best_log_pd", "eval_demonstrator_log_prob", "best_log_pd_policy.npz"))
# The same choice by log pD among the evaluations of the policy averaged over updates (runs
# that keep one): its file holds the average's parameters and evaluation (`_average_row`).
AVERAGE_BEST = (("best_log_pd_average", "eval_demonstrator_log_prob_average",
                 "best_log_pd_average_policy.npz"),)
_AVERAGE_BEST_NAMES = {name for name, _, _ in AVERAGE_BEST}
# How progress lines name the policies of the final evaluation.
_POLICY_WORDS = {"final": "final policy", "final_sampled": "final policy with sampled actions",
                 "best": "best policy",
                 "best_log_pd": "best policy by log pD", "average": "average policy",
                 "best_log_pd_average": "best average policy by log pD"}
# The policy averaged over updates, exported beside policy.npz (`policy_average_decay` > 0).
AVERAGE_FILE = "average_policy.npz"


def _average_row(row: dict) -> dict:
  """`row` with the average policy's evaluation in the place of the online policy's."""
  out = {k: v for k, v in row.items() if k not in ("eval_return", "eval_demonstrator_log_prob")}
  for key in ("eval_return", "eval_demonstrator_log_prob"):
    if f"{key}_average" in row:
      out[key] = row[f"{key}_average"]
  return out


# How a population lies on several devices, as the run's first line says it.
_LAYOUT_WORDS = {"members": "whole members per device",
                 "environments": "each member's environments over all of them"}


def _resumed_best(path: str, key: str, best_path: str) -> float:
  """The evaluation's `key` (a BEST or AVERAGE_BEST entry's) of the policy a resumed run
  exported to `path` so far: -inf if none, unless the run kept a best policy by the return
  (`best_path`) and not this one, i.e. it started before this file existed: then +inf, so that
  it keeps none (its evaluations before the resume would not count)."""
  if os.path.exists(path):  # (an average's file keeps its evaluation under the online key:
                            # `_average_row`)
    return float(policy_io.load_policy(path)[1][key.removesuffix("_average")])
  return np.inf if path != best_path and os.path.exists(best_path) else -np.inf


def _checkpointed(state, with_replay: bool):
  """What a checkpoint holds: the whole TrainState, or its lean part (no replay, no envs)."""
  if with_replay:
    return state
  return {"learner": state.learner, "normalizer": state.normalizer, "source": state.source,
          "key": state.key, "iteration": state.iteration}


def method_name(config: TrainConfig) -> str:
  """The `method` of a run's records: 'expert' on the task reward, else the reward source."""
  return "expert" if config.reward_source == "task" else config.reward_source


def learner_preset(config: TrainConfig) -> str:
  """'paper' where the learner runs the paper's settings (LearnerConfig's defaults; an average
  policy kept for evaluation changes no update)."""
  learner = dataclasses.replace(config.learner, policy_average_decay=0.0)
  return "paper" if learner == LearnerConfig() else "custom"


def _record_base(trainer: Trainer, member: int) -> dict:
  config = trainer.member_config(member)
  return {"task": config.task, "method": method_name(config), "physics": config.physics,
          "num_envs": config.num_envs, "seed": config.seed,
          "learner_preset": learner_preset(config), "population": trainer.members}


def _record_settings(trainer: Trainer, member: int, total_env_steps: int) -> dict:
  """Member `member`'s settings (its own where it overrides the run's)."""
  config = trainer.member_config(member)
  return {**config.to_dict(), "reward": trainer.member_source(member).settings(),
          "updates_per_env_step": config.updates_per_env_step,
          "replay_ratio": config.replay_ratio, "total_env_steps": total_env_steps,
          "devices": trainer.mesh.devices.size}


# Fields of a learning-curve record, where the row has them.
_CURVE_FIELDS = (
    "iteration", "env_steps", "updates", "wall_s", "eval_s", "steps_per_s", "eval_return",
    "eval_return_std", "train_return", "peak_memory_bytes",
    # the policy's saturation: shares of its mean and samples outside [-1, 1], and of the
    # (state, dimension) pairs whose samples all lie beyond one bound
    "mean_out_of_bounds", "sampled_out_of_bounds", "sampled_all_beyond", "penalty_temperature",
    # MPO's state: temperature, the mean and scale multipliers, the KLs over their bounds
    # (> 1: constraint violated), the policy's mean scale and entropy, the critic
    "temperature", "alpha_mean", "alpha_scale", "kl_mean_rel", "kl_scale_rel",
    "kl_nonparametric_rel", "scale_mean", "entropy", "q_online", "critic_loss",
    # what the E-step's weights go on: the sampled actions' Q spread, bfloat16's error in it
    # (and the part of it that differs between a state's actions)
    "sampled_q_spread", "sampled_q_bf16_error", "sampled_q_bf16_centred_error",
    # FORM: the reward, its running sd and clipped share, and both models' log-likelihoods on
    # the learner's batches, and on the iteration's new transitions before the imitator model
    # saw them (form.py: fresh_metrics; fresh below batch: the imitator model lags the policy)
    "form_reward", "form_reward_std", "form_reward_clipped", "demonstrator_log_prob",
    "imitator_batch_log_prob", "imitator_log_prob", "demonstrator_fresh_log_prob",
    "imitator_fresh_log_prob", "form_reward_fresh",
    # GAIfO: the reward and its running sd, and the discriminator on the learner's batches (its
    # mean log D on the expert's inputs and log(1 - D) on the imitator's, the share of each it
    # tells right, the gradient norm its penalty charges)
    "gaifo_reward", "gaifo_reward_std", "discriminator_expert_log_prob",
    "discriminator_imitator_log_prob", "discriminator_expert_accuracy",
    "discriminator_imitator_accuracy", "discriminator_gradient_norm",
    # VAIfO: the bottleneck's KL (bounded by `kl_bound`) and its multiplier
    "discriminator_kl", "discriminator_beta",
    # BC and BCO: the policy's mean log-likelihood of the actions it clones, its mean's squared
    # error; BCO's inverse model's of the imitator's actions on the learner's batches
    "bc_log_prob", "bc_action_error", "inverse_model_log_prob", "inverse_model_action_error",
    # FORM: the demonstrator's mean log pD of the evaluation episodes' transitions (the policy's
    # mean action): how well the policy imitates, measured without the task reward
    "eval_demonstrator_log_prob",
    # the policy averaged over updates (`policy_average_decay`), on the same episodes' starts
    "eval_return_average", "eval_return_std_average", "eval_demonstrator_log_prob_average")


def _write_curve_point(writer: results.ResultWriter, trainer: Trainer, member: int, row: dict, *,
                       eval_episodes: int, total_env_steps: int, startup: dict,
                       on_host: bool = False) -> None:
  """One `kind: learning_curve` record: evaluation return at this point of the run.

  `startup`: `startup_s`, this call's seconds before its first iteration,
  `persistent_cache_hits`, the programs it loaded from JAX's persistent compilation cache, and
  `pre_training_s`, the command's seconds before this call (demonstrations, a demonstrator),
  and `start_iteration`, the iteration this call started from (0, or its checkpoint's).
  """
  settings = {**_record_settings(trainer, member, total_env_steps),
              "eval_episodes": eval_episodes, **({"eval_on_host": True} if on_host else {})}
  writer.write(compact=True, kind="learning_curve", **_record_base(trainer, member),
               settings=settings,
               **startup,
               **{k: row[k] for k in _CURVE_FIELDS if k in row and np.isfinite(row[k])})


def export_source(trainer: Trainer, state, member: int, directory: str, row: dict) -> None:
  """Writes what a member's reward source learned online (FORM: its imitator model) to its
  `export_file` in the member's directory, where the source has one (mjx_form.rl.reward_sources);
  nothing for others."""
  name = getattr(trainer.source, "export_file", None)
  if name is None:
    return
  env = trainer.env
  trainer.source.export(trainer.member(state.source, member), os.path.join(directory, name), {
      "task": env.name, "observation_size": env.observation_size,
      "observation_layout": [[k, v] for k, v in env.observation_layout.items()],
      "env_steps": row.get("env_steps"), "policy_file": "policy.npz"})


def export_policy(trainer: Trainer, state, member: int, path: str, row: dict,
                  params=None, normalizer=None) -> None:
  """Writes a member's policy (`params`, [P, ...]; default the state's online policy) and its
  observation normaliser (`normalizer`, [P, ...]; default the state's) as a small,
  pickle-free file."""
  env, cfg = trainer.env, trainer.member_config(member)
  norm = trainer.member(state.normalizer if normalizer is None else normalizer, member)
  params = state.learner.policy if params is None else params
  arrays = {"policy": jax.device_get(trainer.member(params, member)),
            "normalizer": {"mean": np.asarray(norm.mean), "var": np.asarray(norm.var),
                           # (a member that does not wrap, beside ones that do, has zeros)
                           **({"period": np.asarray(norm.period)} if cfg.wrap_angles else {}),
                           # (zero rows in a member that does not, beside ones that do)
                           **({"angles": np.asarray(norm.angles)}
                              if norm.angles is not None else {})}}
  metadata = {"task": cfg.task, "observation_size": env.observation_size,
              "action_size": env.action_size,
              "observation_layout": [[k, v] for k, v in env.observation_layout.items()],
              "network_width": cfg.network_width, "policy_head": cfg.policy_head,
              "physics": cfg.physics,
              "env_steps": row.get("env_steps"), "eval_return": row.get("eval_return"),
              **({"eval_demonstrator_log_prob": row["eval_demonstrator_log_prob"]}
                 if "eval_demonstrator_log_prob" in row else {}),
              "train_config": cfg.to_dict()}
  policy_io.save_policy(path, arrays, metadata, overwrite=True)
