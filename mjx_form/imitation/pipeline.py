"""The FORM pipeline behind `scripts/run.py --method form`: expert -> demonstrations ->
demonstrator effect model -> imitation -> evaluation.

Stages, each of which can also start from a saved artefact:
  1. demonstrator: `--demonstrator FILE` (given several times: an ensemble, their mixture or
     the mean of their log pD, mjx_form.imitation.form), else the one shipped in
     tasks/demonstrators/ (when it was trained with this run's effect-model settings), else
     trained here on demonstrations;
  2. demonstrations: `--demos FILE`, else recorded from the expert (`--expert FILE`, else the
     shipped one) on the device. They train the demonstrator where one is trained (1000
     episodes by default, as the paper); with a ready demonstrator a few (16 by default)
     check it: its log-likelihood on them beside its own held-out figure, and the expert's
     return, the imitation's target;
  3. imitation: MPO + Retrace on the FORM reward (mjx_form.imitation.form), never the task
     reward, in the compiled loop of mjx_form.rl.train, run by mjx_form.rl.runner.
The demonstrator a run imitates is kept in its run directory (demonstrator.npz; an ensemble's
others, or the other members' where each member has its own, as demonstrator_1.npz, ...), so
`--resume` needs nothing else. A missing or mismatched artefact raises PipelineError naming
the file and the problem, before anything is written.
"""

from __future__ import annotations

import dataclasses
import glob
import json
import os
import shutil
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np

import tasks
from mjx_form import paper
from mjx_form.files import demos as demos_lib
from mjx_form.files import effect_models, experts, results
from mjx_form.imitation import demonstrator as demonstrator_lib
from mjx_form.imitation import effect_model as em
from mjx_form.imitation.form import Demonstrator, FormReward
from mjx_form.rl import normalizer, runner

DEMONSTRATOR_FILE = "demonstrator.npz"
DEFAULT_TRAINING_EPISODES = paper.DEMONSTRATIONS  # the paper's demonstrations per task
DEFAULT_CHECK_EPISODES = 16
# A ready demonstrator whose offset-1 log-likelihood on this run's demonstrations of the expert
# it learned lies more than this many nats per transition below its own held-out figure learned
# other behaviour of that expert (`misfit`). Measured on the CPU (session 68, 16 fresh episodes of
# each shipped pair, 2026-12-01_demonstrator_heldout_cpu_shipped_fresh16): the seven in use lie
# within 3.5 nats of their held-out figure on the mean, their single episodes at most 38.5 below
# (reacher_easy; the others 15); quadruped_walk's former one, trained on demonstrations recorded
# while actions were clipped to [-1, 1] inside its control range (lift to 1.1; benchmarks/
# NOTES.md, session 54), 376 below on the mean and every episode at least 304 below. So even a
# check on one episode keeps 2.6x room either side.
MISFIT_NATS = 100.0


class PipelineError(ValueError):
  """An artefact is missing or does not fit this run."""


@dataclasses.dataclass(frozen=True)
class Artefacts:
  """Where the pipeline's inputs come from (None: the default source)."""

  expert: str | None = None  # policy file
  demos: str | None = None  # demonstration file
  demonstrator: tuple[str, ...] = ()  # effect-model files (2 or more: an ensemble)
  member_demonstrators: bool = False  # the files go one to each member, not to a mixture
  # with member_demonstrators and train_demonstrator: the seeds of the draws trained, one per
  # member, side by side in one program
  draw_seeds: tuple[int, ...] = ()
  # None: 1000 to train a demonstrator, 16 to check a ready one; 0: do not check a ready one
  demo_episodes: int | None = None
  train_demonstrator: bool = False  # train even where one is shipped
  save_demos: str | None = None  # also write the recorded demonstrations here
  training: demonstrator_lib.DemonstratorTraining = demonstrator_lib.DemonstratorTraining()


def _expert_path(task: str, path: str | None) -> str:
  if path is not None:
    return path
  try:
    return tasks.bundled_expert(task)
  except ValueError as e:
    raise PipelineError(f"{e}; then pass --expert <run_dir>/policy.npz (or give --demos or "
                        "--demonstrator)") from None


def demonstrations(env, artefacts: Artefacts, episodes: int, physics: str, seed: int,
                    print_fn, with_actions: bool = False) -> tuple:
  """Observations [K, T+1, D] and what they are (the demonstrator file's `demonstrations`);
  with `with_actions`, (observations, actions [K, T, A], what they are), and a file without
  actions is refused."""
  if artefacts.demos is not None:
    loaded = demos_lib.load_demonstrations(artefacts.demos, task=env.name,
                                           observation_layout=env.observation_layout,
                                           need_actions=with_actions)
    meta = loaded.metadata
    print_fn(f"demonstrations: {meta['episodes']} episodes from {artefacts.demos}")
    info = {"file": os.path.basename(artefacts.demos), "sha256": meta["sha256"],
            "episodes": meta["episodes"], "physics": meta["physics"], "expert": meta["expert"]}
    return (loaded.observations, loaded.actions, info) if with_actions else (
        loaded.observations, info)
  path = _expert_path(env.name, artefacts.expert)
  expert = experts.load_expert(path, env)
  print_fn(f"demonstrations: recording {episodes} episodes of the expert {path} on the device")
  obs, actions, returns = experts.record_demonstrations(
      env, expert, jax.random.PRNGKey(seed), episodes, print_fn=print_fn)
  info = experts.recording_info(path, expert.metadata, returns, seed, stochastic=False)
  if artefacts.save_demos:
    demos_lib.save_demonstrations(artefacts.save_demos, obs, actions, metadata={
        "task": env.name, "observation_layout": env.observation_layout, "physics": physics,
        "expert": info})
    print_fn(f"demonstrations written to {artefacts.save_demos}")
  if with_actions:
    return obs, actions, {"sha256": demos_lib.checksum({"observations": obs, "actions": actions}),
                          "episodes": len(obs), "physics": physics, "expert": info}
  return obs, {"sha256": demos_lib.checksum({"observations": obs}), "episodes": len(obs),
               "physics": physics, "expert": info}


def load_demonstrator(path: str, env) -> effect_models.EffectModelFile:
  """The demonstrator file at `path`, refused (naming it) unless it is of `env`'s task and
  observation layout, without distractors, and a demonstrator (not a run's imitator model)."""
  file = effect_models.load_effect_model(path, task=env.name,
                                         observation_layout=env.observation_layout,
                                         distractors=None)
  if "imitator" in file.metadata:
    raise effect_models.EffectModelFileError(
        f"{path}: an imitator model (a FORM run's {FormReward.export_file}, trained on the "
        "run's own behaviour), not a demonstrator")
  return file


def prepare(env, config: em.EffectModelConfig, explicit: dict, artefacts: Artefacts,
            run_dir: str, *, resume: bool, physics: str, seed: int, results_path: str | None,
            reward: dict | None = None, varied: tuple[str, ...] = (),
            print_fn: Callable[[str], None] = print) -> FormReward:
  """Stages 1-2: the FORM reward source of this run, its demonstrator kept in `run_dir`.

  `config`: the effect-model settings asked for; `explicit`: those of them the user set (a
  ready demonstrator must agree with them); `reward`: the FormReward's reward settings
  (`standardise_reward`, `reward_clip`, `ensemble_log_pd`: see mjx_form.imitation.form);
  `varied`: those a population's members set for themselves (`--grid`; only named here).
  """
  given = artefacts.demonstrator
  if isinstance(given, str):
    raise TypeError("Artefacts.demonstrator is a tuple of paths")
  # (any demonstrator file in it: a leftover demonstrator_2.npz would join a later --resume)
  runner.check_run_dir(run_dir, resume, also=(DEMONSTRATOR_FILE, *sorted(
      os.path.basename(p) for p in glob.glob(os.path.join(run_dir, "demonstrator_*.npz")))))
  reward = reward or {}
  kept = os.path.join(run_dir, DEMONSTRATOR_FILE)
  if resume:
    return kept_source(run_dir, env, explicit, reward)

  per_member = artefacts.member_demonstrators
  if per_member and artefacts.train_demonstrator:
    if len(set(artefacts.draw_seeds)) < 2 or len(set(artefacts.draw_seeds)) != len(
        artefacts.draw_seeds):
      raise PipelineError("demonstrators per member, trained: 2 or more distinct draw seeds, "
                          f"got {list(artefacts.draw_seeds)}")
  elif per_member and len(given) < 2:
    raise PipelineError("demonstrators per member: give one --demonstrator file per member "
                        f"(2 or more), got {len(given)}")
  ready: list[tuple[str, effect_models.EffectModelFile]] = []  # (path, file)
  if given:
    ready = [(path, load_demonstrator(path, env)) for path in given]
  elif not artefacts.train_demonstrator:
    path, file, why = shipped_demonstrator(env, config)
    if path is not None:
      ready = [(path, file)]
    elif file is not None:
      print_fn(why + "; training one with this run's")
  if ready:  # ready demonstrators: refused, if they do not fit, before recording
    config, demonstrators, sha256 = (members_of if per_member else ensemble)(ready, explicit)
  if artefacts.demo_episodes == 0 and not ready:
    raise PipelineError("--demo_episodes 0 skips the check of a ready demonstrator; none is "
                        f"ready for {env.name} with this run's settings, and training one needs "
                        "demonstrations (give --demo_episodes N or --demos FILE)")
  episodes = artefacts.demo_episodes or (DEFAULT_CHECK_EPISODES if ready
                                         else DEFAULT_TRAINING_EPISODES)
  can_record = artefacts.demos is not None or artefacts.expert is not None or (
      env.name in tasks.bundled_experts())
  demos_obs = None
  if artefacts.demo_episodes == 0:
    print_fn("--demo_episodes 0: the demonstrator is not checked on demonstrations")
  elif not ready or can_record:
    demos_obs, demos_info = demonstrations(env, artefacts, episodes, physics, seed, print_fn)
  else:
    print_fn(f"no expert for {env.name}: the demonstrator is not checked on demonstrations")

  fits = {}  # sha256 -> log-likelihood by offset on this run's demonstrations
  if ready and demos_obs is not None:
    for (path, file), demonstrator in zip(ready, demonstrators):
      if file.metadata["sha256"] not in fits:
        fits[file.metadata["sha256"]] = np.asarray(demonstrator_lib.heldout_log_likelihood(
            em.make_model(config, env.observation_size), demonstrator.params,
            demonstrator.normalizer, jnp.asarray(demos_obs)))
  if ready and not given and demos_obs is not None:  # the shipped one: replaced where it misfits
    path, file = ready[0]
    why = misfit(file.metadata, demos_info, fits[file.metadata["sha256"]])
    if why:
      print_fn(f"the shipped demonstrator {path}: {why}; training one on this run's "
               "demonstrations (--demo_episodes 0 would use it unchecked)")
      ready, fits = [], {}
      if artefacts.demos is None and artefacts.demo_episodes is None:  # (16 only to check)
        if artefacts.save_demos:  # (the 16 just written there give way to the 1000)
          os.remove(artefacts.save_demos)
        demos_obs, demos_info = demonstrations(env, artefacts, DEFAULT_TRAINING_EPISODES,
                                               physics, seed, print_fn)

  if not ready and per_member:  # one draw per member, side by side, kept in the run directory
    os.makedirs(run_dir, exist_ok=True)
    paths = [os.path.join(run_dir, kept_name(i)) for i in range(len(artefacts.draw_seeds))]
    files = train_demonstrators(env, config, demos_obs, demos_info, artefacts.training,
                                physics, artefacts.draw_seeds, results_path, print_fn, paths)
    config, demonstrators, sha256 = members_of(list(zip(paths, files)), explicit)
    print_fn("demonstrators per member, in the members' order: draws of seeds "
             + ", ".join(f"{s} ({h[:6]})" for s, h in zip(artefacts.draw_seeds, sha256)))
    return FormReward(config, demonstrators, sha256, member_demonstrators=True, **reward)
  if not ready:  # train one; it is written to the run directory
    os.makedirs(run_dir, exist_ok=True)
    file = train_demonstrator(env, config, demos_obs, demos_info, artefacts.training, physics,
                              seed, results_path, print_fn, kept)
    return FormReward(*demonstrator_from_file(file, kept, explicit), file.metadata["sha256"],
                      **reward)

  checked = set()
  for (path, file), demonstrator in zip(ready, demonstrators):
    if file.metadata["sha256"] in checked:  # (a file given to several members)
      continue
    checked.add(file.metadata["sha256"])
    print_fn(f"demonstrator {path}: best of {file.metadata['training'].get('steps')} training "
             f"steps at step {file.metadata['training'].get('best_step')}, held-out "
             f"log-likelihood by offset {file.metadata['training'].get('heldout_log_likelihood')}")
    if demos_obs is not None:
      other = another_expert(file.metadata, demos_info)
      if other:
        print_fn(other)
      fit = fits[file.metadata["sha256"]]
      print_fn(f"its log-likelihood on this run's {len(demos_obs)} demonstrations by offset: "
               + " ".join(f"{v:.2f}" for v in fit))
      why = misfit(file.metadata, demos_info, fit)
      if why:  # (a given file: the user chose it)
        raise PipelineError(f"{path}: {why} (--train_demonstrator trains one on this run's "
                            "demonstrations; --demo_episodes 0 uses it unchecked)")
  os.makedirs(run_dir, exist_ok=True)
  for i, (path, _) in enumerate(ready):  # (after every check: no partial run directory)
    shutil.copyfile(path, os.path.join(run_dir, kept_name(i)))
  if per_member:
    print_fn("demonstrators per member, in the members' order: " + ", ".join(
        f"{path} ({sha[:6]})" for (path, _), sha in zip(ready, sha256)))
    return FormReward(config, demonstrators, sha256, member_demonstrators=True, **reward)
  source = FormReward(config, demonstrators, sha256, **reward)
  if source.ensemble:  # (what the source made of the files and `reward`)
    print_fn(f"an ensemble of {source.ensemble} demonstrators: log pD is "
             + ("their mixture's or the mean of their log pD, as each member's --grid "
                "ensemble_log_pd says" if "ensemble_log_pd" in varied
                else "the mean of their log pD" if source.ensemble_log_pd == "mean"
                else "their mixture's"))
  return source


def kept_source(run_dir: str, env, explicit: dict | None = None, reward: dict | None = None,
                what: str = "--resume") -> FormReward:
  """The FORM reward source of the demonstrators kept in `run_dir` (one, an ensemble, or one per
  member where config.json says the run was started with them, checked against it), with the
  `reward` settings; refused (naming the file, `what` first) where none is kept or one does not
  fit. What a resumed run continues with, and what a finished run's reward was."""
  paths = kept_paths(run_dir)
  if not paths:
    raise PipelineError(f"{what}: {run_dir} holds no {DEMONSTRATOR_FILE}")
  ready = [(p, load_demonstrator(p, env)) for p in paths]
  reward = reward or {}
  stored = _stored_reward(run_dir).get("member_demonstrators")
  if stored is not None:  # (what the run was started with)
    _check_kept(run_dir, ready, stored, what)
    config, demonstrators, sha256 = members_of(ready, explicit)
    return FormReward(config, demonstrators, sha256, member_demonstrators=True, **reward)
  config, demonstrators, sha256 = ensemble(ready, explicit)
  return FormReward(config, demonstrators, sha256, **reward)


def _check_kept(run_dir: str, ready: list[tuple[str, effect_models.EffectModelFile]],
                stored: list[str], what: str) -> None:
  """Refuses kept demonstrators per member that are not those config.json lists, naming the
  first file missing or changed."""
  for i, sha in enumerate(stored):
    name = os.path.join(run_dir, kept_name(i))
    if i >= len(ready):
      raise PipelineError(f"{what}: {name} is missing (the run's {len(stored)} members "
                          "each kept a demonstrator)")
    if ready[i][1].metadata["sha256"] != sha:
      raise PipelineError(f"{what}: {name} is not member {i}'s demonstrator (sha256 "
                          f"{ready[i][1].metadata['sha256'][:12]}, config.json: {sha[:12]})")
  if len(ready) > len(stored):
    raise PipelineError(f"{what}: {ready[len(stored)][0]} is not one of the run's "
                        f"{len(stored)} members' demonstrators")


def _stored_reward(run_dir: str) -> dict:
  """The reward settings a run directory's config.json holds ({} where it names none)."""
  with open(os.path.join(run_dir, "config.json")) as f:
    return json.load(f).get("reward") or {}


def kept_paths(run_dir: str) -> list[str]:
  """The demonstrators kept in a run directory, in order: demonstrator.npz, demonstrator_1.npz,
  ... up to the first missing one (none: [])."""
  paths = []
  while os.path.exists(path := os.path.join(run_dir, kept_name(len(paths)))):
    paths.append(path)
  return paths


def kept_name(i: int) -> str:
  """The name in a run directory of the run's i-th demonstrator (an ensemble's i > 0)."""
  return DEMONSTRATOR_FILE if i == 0 else f"demonstrator_{i}.npz"


def ensemble_sha256(checksums: list[str]) -> str:
  """What identifies a run's demonstrators: one's sha256, an ensemble's sorted and joined by
  '+' (the mixture does not depend on their order)."""
  return "+".join(sorted(checksums))


def ensemble(ready: list[tuple[str, effect_models.EffectModelFile]], explicit: dict | None
              ) -> tuple[em.EffectModelConfig, list[Demonstrator], str]:
  """The shared settings, the models and the identity of one demonstrator or an ensemble of
  them; refused where one does not fit, where two were trained with other settings (the
  imitator model shares them) and where one file is given twice."""
  config, models = _shared_settings(ready, explicit, "an ensemble's demonstrators")
  checksums = [file.metadata["sha256"] for _, file in ready]
  for i, sha in enumerate(checksums):
    if sha in checksums[:i]:
      path, earlier = ready[i][0], ready[checksums.index(sha)][0]
      what = "given twice" if path == earlier else f"the same demonstrator as {earlier}"
      raise PipelineError(f"{path}: {what} (an ensemble's demonstrators must differ)")
  return config, models, ensemble_sha256(checksums)


def _shared_settings(ready: list[tuple[str, effect_models.EffectModelFile]],
                     explicit: dict | None, whose: str
                     ) -> tuple[em.EffectModelConfig, list[Demonstrator]]:
  """The one effect-model setting of several demonstrator files and their models; refused
  where one does not fit or two were trained with other settings (`whose` share one)."""
  models = [demonstrator_from_file(file, path, explicit) for path, file in ready]
  (first, _), config = ready[0], models[0][0]
  for (path, _), (other, _) in zip(ready[1:], models[1:]):
    theirs, ours = other.to_dict(), config.to_dict()
    differ = {k: (theirs.get(k), ours.get(k)) for k in sorted(set(theirs) | set(ours))
              if theirs.get(k) != ours.get(k)}
    if differ:
      raise PipelineError(f"{path}: trained with other effect-model settings than {first} ("
                          + ", ".join(f"{k} {a} against {b}" for k, (a, b) in differ.items())
                          + f"): {whose} share one setting")
  return config, [d for _, d in models]


def members_of(ready: list[tuple[str, effect_models.EffectModelFile]], explicit: dict | None
               ) -> tuple[em.EffectModelConfig, list[Demonstrator], list[str]]:
  """The shared settings, the models and the checksums of demonstrators per member, in order;
  refused where one does not fit or where two were trained with other settings (the members
  share one imitator model architecture). A file may go to several members."""
  config, models = _shared_settings(ready, explicit, "a population's demonstrators")
  return config, models, [file.metadata["sha256"] for _, file in ready]


def shipped_demonstrator(env, config: em.EffectModelConfig
                         ) -> tuple[str | None, effect_models.EffectModelFile | None, str]:
  """The shipped demonstrator of `env`'s task if it was trained with `config` (path, file,
  ''), else (None, the file or None, why not): what `prepare` uses unless told otherwise."""
  shipped = tasks.bundled_demonstrator(env.name)
  if shipped is None:
    return None, None, f"no demonstrator is shipped for {env.name}"
  file = load_demonstrator(shipped, env)
  try:  # (read back through the settings: a key written at its default still matches)
    same = em.EffectModelConfig(**file.metadata["config"]).to_dict() == config.to_dict()
  except TypeError:
    same = False
  if not same:
    return None, file, (f"the shipped demonstrator {shipped} was trained with other settings "
                        f"({file.metadata['config']})")
  return shipped, file, ""


def _experts(demonstrator_metadata: dict, demos_info: dict) -> tuple[dict, dict]:
  """What the demonstrator's demonstrations and this run's say of their expert policy ({} where
  nothing)."""
  return (demonstrator_metadata.get("demonstrations", {}).get("expert") or {},
          demos_info.get("expert") or {})


def another_expert(demonstrator_metadata: dict, demos_info: dict) -> str | None:
  """A notice where a demonstrator was trained on demonstrations of another expert policy than
  this run's demonstrations (by the policies' sha256; None where they agree or are unknown):
  it then imitates that expert, and the run's expert return is not the one it imitates."""
  theirs, ours = _experts(demonstrator_metadata, demos_info)
  a, b = theirs.get("policy_sha256"), ours.get("policy_sha256")
  if not a or not b or a == b:
    return None
  ret = lambda e: "" if e.get("mean_return") is None else f", mean return {e['mean_return']:.1f}"
  return (f"note: the demonstrator was trained on demonstrations of another expert policy "
          f"({theirs.get('policy_file')} sha256 {a[:12]}{ret(theirs)}) than this run's "
          f"({ours.get('policy_file')} sha256 {b[:12]}{ret(ours)}): the run imitates that one; "
          "--train_demonstrator trains one on this run's demonstrations")


def misfit(demonstrator_metadata: dict, demos_info: dict, fit) -> str | None:
  """Why a demonstrator does not describe this run's demonstrations of the expert policy it
  learned: its log-likelihood on them at offset 1 (`fit`, by offset) lies more than MISFIT_NATS
  below its own held-out figure. None where it fits, where they are another policy's (see
  `another_expert`) or where either policy or the held-out figure is unknown."""
  theirs, ours = _experts(demonstrator_metadata, demos_info)
  heldout = (demonstrator_metadata.get("training") or {}).get("heldout_log_likelihood")
  sha = theirs.get("policy_sha256")
  if not sha or sha != ours.get("policy_sha256") or not heldout:
    return None
  own, here = float(heldout[0]), float(np.asarray(fit)[0])
  if here >= own - MISFIT_NATS:
    return None
  return (f"its log-likelihood at offset 1 on this run's {demos_info.get('episodes')} "
          f"demonstrations of the expert it learned (sha256 {sha[:12]}) is {here:.2f} nats per "
          f"transition, {own - here:.1f} below its own held-out {own:.2f}: it learned other "
          "behaviour of that expert (demonstrations recorded with other settings, such as "
          "another physics or action range)")


def demonstrator_from_file(file: effect_models.EffectModelFile, path: str,
                           explicit: dict | None = None) -> tuple[em.EffectModelConfig,
                                                                  Demonstrator]:
  """The file's settings (which the imitator model shares) and its model as a Demonstrator;
  refused where `explicit` settings differ from the file's or its parameters do not fit."""
  try:
    config = em.EffectModelConfig(**file.metadata["config"])
    config.check()
  except (TypeError, ValueError) as e:
    raise PipelineError(f"{path}: unusable effect-model settings: {e}") from None
  for key, value in (explicit or {}).items():
    if value is not None and getattr(config, key) != value:
      name = {"period": "turn-invariance period (--turn_invariant)",
              "max_scale": "max_scale (--effect_max_scale)"}.get(key, key)
      raise PipelineError(f"{path}: the demonstrator was trained with {name}="
                          f"{getattr(config, key)}, this run asks for {value} (the imitator "
                          "model shares the demonstrator's settings: leave it out, or train a "
                          "demonstrator with --train_demonstrator)")
  d = file.metadata["observation_size"]
  model = em.make_model(config, d)
  expected = jax.eval_shape(lambda key: em.init_params(model, key), jax.random.PRNGKey(0))
  shapes = lambda tree: jax.tree.map(lambda x: tuple(x.shape), tree)
  try:
    fits = shapes(file.params) == shapes(expected)
  except (TypeError, ValueError):
    fits = False
  if not fits:
    raise PipelineError(f"{path}: its parameters do not fit an effect model with its settings "
                        f"{config.to_dict()}")
  norm = normalizer.NormalizerState(jnp.asarray(file.mean), jnp.asarray(file.var),
                                    jnp.asarray(1, jnp.int32))
  return config, Demonstrator(jax.tree.map(jnp.asarray, file.params), norm)


def _demonstrations_ids(demos_info: dict) -> dict:
  """What a demonstrator record names its training data by: the demonstrations' checksum and
  the expert policy's (held-out likelihoods compare only over the same demonstrations)."""
  expert = demos_info.get("expert") or {}
  return {"sha256": demos_info.get("sha256"), "expert_sha256": expert.get("policy_sha256"),
          "expert_return": expert.get("mean_return")}


def train_demonstrator(env, config: em.EffectModelConfig, demos_obs: np.ndarray,
                       demos_info: dict, training: demonstrator_lib.DemonstratorTraining,
                       physics: str, seed: int, results_path: str | None, print_fn,
                       path: str) -> effect_models.EffectModelFile:
  """Trains a demonstrator of `seed` on demonstrations (`demonstrations`' output), writes it to
  `path` (never over an existing file) and a `kind: effect_model` record to `results_path`;
  returns the file as read back."""
  return train_demonstrators(env, config, demos_obs, demos_info, training, physics, (seed,),
                             results_path, print_fn, [path])[0]


def train_demonstrators(env, config: em.EffectModelConfig, demos_obs: np.ndarray,
                        demos_info: dict, training: demonstrator_lib.DemonstratorTraining,
                        physics: str, seeds: tuple[int, ...], results_path: str | None,
                        print_fn, paths: list[str]) -> list[effect_models.EffectModelFile]:
  """`train_demonstrator` for one draw per seed, trained side by side in one program
  (`demonstrator.train_draws`), draw i written to paths[i] with its record."""
  trained = demonstrator_lib.train_draws(demos_obs, config, training, seeds, print_fn)
  files = []
  for seed, path, (state, report) in zip(seeds, paths, trained):
    metadata = {"task": env.name, "observation_size": env.observation_size,
                "observation_layout": env.observation_layout, "distractors": None,
                "config": config.to_dict(), "training": report,
                "demonstrations": demos_info}
    params = jax.device_get(state.params)
    mean, var = np.asarray(state.normalizer.mean), np.asarray(state.normalizer.var)
    if results_path:
      results.ResultWriter(results_path).write(
          kind="effect_model", task=env.name, method="form", physics=physics, seed=seed,
          settings={**config.to_dict(), **dataclasses.asdict(training), "seed": seed,
                    "demo_episodes": demos_info["episodes"]},
          demonstrations=_demonstrations_ids(demos_info),
          **{k: report[k] for k in ("steps", "best_step", "stopped_by", "seconds",
                                    "heldout_log_likelihood", "curve")})
    effect_models.save_effect_model(path, params, mean, var, metadata)
    print_fn(f"demonstrator written to {path}")
    files.append(effect_models.load_effect_model(path))
  return files
