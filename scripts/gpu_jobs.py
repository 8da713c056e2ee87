"""Run a list of jobs on one machine's GPUs, one job per GPU, detached; poll them; bring back
what they wrote.

A GPU machine takes one command at a time, for at most 10 minutes each, and nothing on it
outlasts the machine. So a sitting of several runs starts them detached (`start`), then polls
(`poll`, one call per command) until they end, and each poll writes the records, logs and
status to `--out` (the device's $OUT) as one `records.tgz`, so that whatever the sitting ends
like, the records already polled are safe. The last poll (`--final`, or once every job has
ended) also packs the run directories into parts of at most 15 MB, without checkpoints unless
`--checkpoints` asks for each run's newest (lean ones, to resume in the next sitting; `--runs`
packs only the jobs named, so that a last call can bring back one run with its checkpoint); the
runs' TensorBoard folders come last, where there is room (progress.csv holds the same values).

  python scripts/gpu_jobs.py check jobs.txt        # on the CPU, before the sitting
  python scripts/gpu_jobs.py start jobs.txt --dir /tmp/sitting --deadline 1200
  python scripts/gpu_jobs.py poll --dir /tmp/sitting --wait 540 --out $OUT [--final]
  python scripts/gpu_jobs.py poll --dir /tmp/sitting --out $OUT --final --runs qr3 --checkpoints
  python scripts/gpu_jobs.py poll --dir /tmp/sitting --out $OUT --stop --wait 300 --final
                                   # the device's time runs short: end the runs now, each with
                                   # its final evaluations, and bring them back

`check` parses each `scripts/run.py` job as run.py would (with $LEFT, $RES and $RUNS filled
in) and prints the settings it would train with, so that a mistyped flag or a setting other than
the one meant shows on the CPU, not after minutes of a GPU sitting.

Records copied to benchmarks/results/ after a sitting: pack FORM runs' learning curves with
scripts/pack_results.py (`scripts/report.py --check` refuses them unpacked).

--dir must lie outside the repository (the device refreshes its copy of the tree at each call).
The jobs file has one job per line, `NAME: COMMAND` (blank lines and `#` comments skipped);
`NAME gpus=N: COMMAND` gives a job N GPUs (default 1). Jobs start in order as soon as enough
GPUs are free; one that would start after the deadline is skipped. Each job runs from the
working directory in its own session with `CUDA_VISIBLE_DEVICES` set to its GPUs (of those
the machine lists, or of an inherited CUDA_VISIBLE_DEVICES), pinned to its GPUs' share of the
host's cores (each GPU owns an equal slice, so that one job's `--eval_on_host` does not take
the cores of another's), and these variables:
  RES   the folder for its records (`--results $RES/NAME.jsonl`), brought back at every poll;
  RUNS  the folder for its run directories (`--run_dir $RUNS/NAME`), packed at the end;
  MJX_FORM_STOP_FILE  the sitting's stop file, run.py's `--stop_file` (`poll --stop` makes
        it: each run stops at the end of its iteration, as `--max_seconds` stops it);
  LEFT  seconds left until the deadline at the job's start (`--max_seconds $LEFT` makes a
        queued job's training end by the deadline, demonstrations and a demonstrator
        included; its final evaluations come after, ~1-2.5 min; the deadline counts from
        `start`).
Its output goes to `logs/NAME.log` under --dir; `status.json` says which jobs run, wait, ended
(with their exit code) or were skipped.
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import io
import json
import os
import re
import shlex
import subprocess
import sys
import tarfile
import time
from pathlib import Path

PART_BYTES = 15 * 2**20  # a part of the packed runs; under the device's limit on a file
PACK_LIMIT = 56 * 2**20  # the packed runs that may come back (the device's limit: 64 MiB)
MAX_PARTS = 7  # the device brings back 8 files: records.tgz and the parts
LINE = re.compile(r"^(?P<name>[A-Za-z0-9_.-]+)(\s+gpus=(?P<gpus>\d+))?\s*:\s*(?P<cmd>.+)$")


class JobsError(ValueError):
  """A jobs file or request that cannot be run; the message names the problem."""


STOP = "stop"  # the sitting's stop file (`poll --stop`), under --dir
STOP_VARIABLE = "MJX_FORM_STOP_FILE"  # run.py's --stop_file default (run.STOP_FILE_VARIABLE)


def parse_jobs(text: str, num_gpus: int) -> list[dict]:
  """[{name, gpus, cmd}] of a jobs file's text; JobsError on a malformed line, a repeated name
  or a job that needs more GPUs than the machine has."""
  jobs, names = [], set()
  for number, line in enumerate(text.splitlines(), 1):
    line = line.strip()
    if not line or line.startswith("#"):
      continue
    match = LINE.match(line)
    if match is None:
      raise JobsError(f"line {number}: expected 'NAME: COMMAND' or 'NAME gpus=N: COMMAND', got "
                      f"{line!r}")
    name, gpus = match["name"], int(match["gpus"] or 1)
    if name in names:
      raise JobsError(f"line {number}: job name {name!r} used twice")
    if not 1 <= gpus <= num_gpus:
      raise JobsError(f"line {number}: job {name!r} asks for {gpus} GPUs; this machine has "
                      f"{num_gpus}")
    names.add(name)
    jobs.append({"name": name, "gpus": gpus, "cmd": match["cmd"]})
  if not jobs:
    raise JobsError("the jobs file has no job")
  return jobs


def _run_script_args(cmd: str) -> list[str] | None:
  """The arguments of a job that is one `python .../scripts/run.py ...` command, alone or last
  after `&&` (`cp -r runs/X $RUNS/X && python scripts/run.py ... --resume`), else None."""
  try:
    words = shlex.split(cmd)
  except ValueError:
    return None
  if any(w in ("||", ";", "|") for w in words):
    return None
  if "&&" in words:  # (the command after the last one)
    words = words[max(i for i, w in enumerate(words) if w == "&&") + 1:]
  if len(words) < 2:
    return None
  return words[2:] if words[1].replace("\\", "/").endswith("scripts/run.py") else None


def check(jobs_file: Path, deadline_s: float = 1200.0) -> list[str]:
  """One line per job of a jobs file: for a run.py job, the settings run.py would train with
  (its arguments parsed by run.py, $LEFT = `deadline_s`, $RES and $RUNS placeholders); other
  jobs as they are. JobsError naming the job where run.py refuses its arguments."""
  jobs = parse_jobs(jobs_file.read_text(), num_gpus=1 << 10)
  sys.path.insert(0, str(Path(__file__).resolve().parent))
  import run  # noqa: E402  (JAX and the tasks: only for checking)
  from mjx_form.files import results  # noqa: E402
  values = {"LEFT": f"{deadline_s:g}", "RES": "/tmp/res", "RUNS": "/tmp/runs"}
  lines = []
  for job in jobs:
    cmd = re.sub(r"\$\{?(LEFT|RES|RUNS)\}?", lambda m: values[m[1]], job["cmd"])
    argv = _run_script_args(cmd)
    if argv is None:
      lines.append(f"{job['name']}: not a run.py command, not checked: {job['cmd']}")
      continue
    errors = io.StringIO()
    try:
      with contextlib.redirect_stderr(errors):
        args = run.parse_args(argv)
      config = run.train_config(args)
      config.check(1)
    except ValueError as e:  # (a setting TrainConfig.check refuses, as run.py would)
      raise JobsError(f"job {job['name']!r}: run.py would refuse it: {e}") from None
    except SystemExit:
      said = errors.getvalue().strip().splitlines()[-1].split("error: ", 1)[-1]
      raise JobsError(f"job {job['name']!r}: run.py refuses its arguments: {said}") from None
    learner = config.learner
    seeds = ",".join(map(str, args.seeds)) if args.seeds else str(config.seed)
    grid = "".join(f"; grid {k}=" + ",".join(map(str, v)) for k, v in (args.grid or {}).items())
    if args.method == "form":
      try:
        grid += "; " + _form_models(run, args)
      except (ValueError, OSError) as e:  # (the file errors are ValueErrors)
        raise JobsError(f"job {job['name']!r}: run.py would refuse it: {e}") from None
    elif args.method in run.GAIFO:
      discriminator = run.discriminator_config(args)
      grid += (f"; discriminator: {discriminator.frames} frame(s), gradient penalty "
               f"{discriminator.gradient_penalty:g}, "
               + ("" if discriminator.kl_bound is None
                  else f"bottleneck KL <= {discriminator.kl_bound:g}, ")
               + f"reward {args.reward_scale or 'raw'}")
    elif args.method in run.CLONING:  # (MPO's settings below are unused: cloning.py)
      grid += f"; cloning loss {learner.cloning_loss}"
    lines.append(
        f"{job['name']}: {config.task} {args.method}, seeds {seeds}{grid}; {config.num_envs} "
        f"envs x {config.updates_per_iteration} updates (replay ratio {config.replay_ratio:g}"
        + (f"; imitator on 1 batch in {config.source_update_every}"
           if config.source_update_every > 1 else "") + "), "
        f"width {config.network_width}, T {learner.target_update_period}, sampled Q "
        f"{results.sampled_q_precision(vars(learner))}, critic clips actions "
        f"{learner.clip_critic_actions}, action penalty {learner.mpo.action_penalty}, "
        f"mean fitted to clipped actions {learner.mpo.clip_mean_targets}, "
        f"epsilon_scale {learner.mpo.epsilon_scale:g}, average policy decay "
        f"{learner.policy_average_decay:g}, head "
        f"{config.policy_head}, noise correlation {config.action_noise_correlation:g}"
        + (f", envs' noise scaled {config.noise_scale_min:g} to 1"
           if config.noise_scale_min < 1.0 else "") + ", wrap "
        f"angles {config.wrap_angles}, angle features {config.angle_features}, "
        f"physics {config.physics}, init policy "
        f"{args.init_policy or '-'}, env steps {args.env_steps:,}, max seconds "
        f"{args.max_seconds}")
  return lines


def _form_models(run, args) -> str:
  """A FORM job's effect-model settings and where its demonstrator comes from, decided as
  run.py decides them (`run.effect_model_settings`, `pipeline.shipped_demonstrator`)."""
  import tasks  # noqa: E402
  from mjx_form.imitation import pipeline  # noqa: E402
  env = tasks.make(args.task, physics=args.physics)
  explicit, config = run.effect_model_settings(args, env)
  if args.resume:
    where = "the one kept in its run directory (--resume)"
  elif args.demonstrator and not all(map(os.path.exists, args.demonstrator)):
    where = (f"one per member, {', '.join(args.demonstrator)}" if args.member_demonstrators
             else f"given, {' + '.join(args.demonstrator)}") + " (not all here to check)"
  elif args.demonstrator:
    ready = [(path, pipeline.load_demonstrator(path, env)) for path in args.demonstrator]
    # (refused, as run.py refuses them, where the job's flags ask for other settings or the
    # files of an ensemble, or of the members, differ in theirs)
    config = (pipeline.members_of if args.member_demonstrators else pipeline.ensemble)(
        ready, explicit)[0]
    where = (f"one per member, {', '.join(args.demonstrator)}" if args.member_demonstrators
             else f"given, {' + '.join(args.demonstrator)}")
    if len(args.demonstrator) > 1 and not args.member_demonstrators:
      where += (", as each member's --grid ensemble_log_pd says" if "ensemble_log_pd" in args.grid
                else ", the mean of their log pD" if args.ensemble_log_pd == "mean"
                else ", their mixture")
  elif args.train_demonstrator:
    where = "trained (--train_demonstrator)"
  else:
    path, file, _ = pipeline.shipped_demonstrator(env, config)
    where = ("shipped" if path else "trained (the shipped one has other settings)" if file
             else "trained (none shipped)")
  if where.startswith("trained") and args.demo_episodes == 0:
    raise ValueError("--demo_episodes 0 skips the check of a ready demonstrator; this job's "
                     f"would be {where}, from demonstrations")
  if where.startswith("trained") and args.member_demonstrators:
    first = run.demonstrator_seed_of(args)
    where += f", one draw per member, seeds {first}-{first + run.population_size(args) - 1}"
  elif where.startswith("trained"):
    where += f", seed {run.demonstrator_seed_of(args)}"
  return (f"effect models beta_ar {config.beta_ar:g}, L2 {config.l2:g}, width {config.width}"
          f"{', turn-invariant' if config.period else ''}"
          f"{', angle increments' if config.angle_increments else ''}"
          f"{', angle inputs' if config.angle_inputs else ''}"
          f"{f', max scale {config.max_scale:g}' if config.max_scale else ''}; "
          f"demonstrator {where}")


def machine_gpus() -> list[str]:
  """The GPUs jobs may use: an inherited CUDA_VISIBLE_DEVICES's entries, else the indices of
  those `nvidia-smi -L` lists (none where it is missing)."""
  inherited = os.environ.get("CUDA_VISIBLE_DEVICES")
  if inherited:
    return [d.strip() for d in inherited.split(",") if d.strip()]
  try:
    out = subprocess.run(["nvidia-smi", "-L"], capture_output=True, text=True, check=True).stdout
  except (OSError, subprocess.CalledProcessError):
    return []
  return [str(i) for i in range(sum(line.startswith("GPU ") for line in out.splitlines()))]


def core_shares(gpus: list[str], cores: list[int],
                siblings=None) -> dict[str, list[int]]:
  """Each GPU's equal slice of `cores`, whole physical cores in order: the logical CPUs that
  share one (`siblings(cpu)`, default `thread_siblings`) stay together, so that two GPUs' jobs
  do not share a core's hyperthreads; all of them for each GPU where there are fewer physical
  cores than GPUs."""
  siblings = siblings or thread_siblings
  groups = sorted({tuple(sorted(set(siblings(c)) & set(cores) | {c})) for c in cores})
  if len(groups) < len(gpus):
    return {g: list(cores) for g in gpus}
  n = len(groups)
  return {g: sorted(c for group in groups[i * n // len(gpus):(i + 1) * n // len(gpus)]
                    for c in group) for i, g in enumerate(gpus)}


def thread_siblings(cpu: int) -> list[int]:
  """The logical CPUs on `cpu`'s physical core (Linux's topology; [cpu] where unreadable)."""
  try:
    text = Path(f"/sys/devices/system/cpu/cpu{cpu}/topology/thread_siblings_list").read_text()
  except OSError:
    return [cpu]
  out = []
  for part in text.strip().split(","):
    low, _, high = part.partition("-")
    out += range(int(low), int(high or low) + 1)
  return out


def schedule(jobs: list[dict], gpus: list[str], folder: Path, end_time: float,
             poll_s: float = 2.0) -> None:
  """Runs `jobs` in order on the devices `gpus`, each as soon as it has enough free ones (one
  that would start at or after `end_time`, a time.time(), is skipped); writes
  folder/status.json whenever a job starts or ends; returns when every job has ended."""
  start = time.time()
  free, running, status = list(gpus), {}, {j["name"]: {"state": "waiting"} for j in jobs}
  shares = core_shares(gpus, sorted(os.sched_getaffinity(0)))
  waiting = list(jobs)
  write_status(folder, status)
  while waiting or running:
    while waiting and len(free) >= waiting[0]["gpus"]:
      job = waiting.pop(0)
      left = int(end_time - time.time())
      if left <= 0 or (folder / STOP).exists():
        status[job["name"]] = {"state": "skipped (past the deadline)" if left <= 0
                               else "skipped (stopped)"}
        write_status(folder, status)
        continue
      mine, free = free[:job["gpus"]], free[job["gpus"]:]
      env = {**os.environ, "CUDA_VISIBLE_DEVICES": ",".join(mine),
             "RES": str(folder / "res"), "RUNS": str(folder / "runs"), "LEFT": str(left),
             STOP_VARIABLE: str(folder / STOP)}
      cores = sorted({c for g in mine for c in shares[g]})
      log = open(folder / "logs" / f"{job['name']}.log", "w")
      process = subprocess.Popen(["bash", "-c", job["cmd"]], env=env, stdout=log,
                                 stderr=subprocess.STDOUT, start_new_session=True,
                                 preexec_fn=functools.partial(os.sched_setaffinity, 0, cores))
      running[job["name"]] = (process, mine, log)
      status[job["name"]] = {"state": "running", "gpus": mine, "cores": len(cores), "left_s": left,
                             "started_s": round(time.time() - start, 1)}
      write_status(folder, status)
    time.sleep(poll_s)
    for name, (process, mine, log) in list(running.items()):
      if process.poll() is not None:
        log.close()
        free = [g for g in gpus if g in free or g in mine]
        del running[name]
        status[name].update(state="ended", rc=process.returncode,
                            ended_s=round(time.time() - start, 1))
        write_status(folder, status)
  (folder / "all_done").touch()


def write_status(folder: Path, status: dict) -> None:
  """folder/status.json, replaced whole (a reader never sees half of it)."""
  tmp = folder / "status.json.tmp"
  tmp.write_text(json.dumps(status, indent=1))
  tmp.replace(folder / "status.json")


def start(jobs_file: Path, folder: Path, deadline_s: float, num_gpus: int | None) -> None:
  """Checks the jobs, makes the folders and runs `schedule` detached (it outlives the command)."""
  gpus = machine_gpus()
  if num_gpus is not None:
    if gpus and not 1 <= num_gpus <= len(gpus):
      raise JobsError(f"--gpus {num_gpus}: this machine has {len(gpus)} GPU(s) ({','.join(gpus)})")
    gpus = gpus[:num_gpus] if gpus else [str(i) for i in range(num_gpus)]
  if not gpus:
    raise JobsError("no GPU found (nvidia-smi -L lists none); pass --gpus to say how many")
  if deadline_s <= 0:
    raise JobsError(f"--deadline {deadline_s}: must be positive (seconds from now)")
  jobs = parse_jobs(jobs_file.read_text(), len(gpus))
  if (folder / "status.json").exists():
    raise JobsError(f"{folder} already holds a sitting (status.json); pick another --dir")
  if folder.exists() and any(folder.iterdir()):  # (an earlier sitting's records would be packed)
    raise JobsError(f"{folder} is not empty ({', '.join(sorted(p.name for p in folder.iterdir()))}"
                    "); pick another --dir")
  for sub in ("logs", "res", "runs"):
    (folder / sub).mkdir(parents=True, exist_ok=True)
  (folder / "jobs.json").write_text(json.dumps({"jobs": jobs, "gpus": gpus,
                                                "end_time": time.time() + deadline_s}))
  write_status(folder, {j["name"]: {"state": "waiting"} for j in jobs})
  scheduler = subprocess.Popen([sys.executable, __file__, "_schedule", "--dir", str(folder)],
                               stdout=open(folder / "scheduler.log", "w"),
                               stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                               start_new_session=True)
  (folder / "scheduler.pid").write_text(str(scheduler.pid))
  print(f"{len(jobs)} jobs on GPUs {','.join(gpus)}, deadline {deadline_s:.0f} s: "
        + ", ".join(f"{j['name']} ({j['gpus']} GPU{'s' if j['gpus'] > 1 else ''})" for j in jobs))


def _tail(path: Path, lines: int) -> list[str]:
  """The last `lines` lines of a log, warnings left out, each cut to 300 characters."""
  if not path.exists() or lines <= 0:
    return []
  text = path.read_text(errors="replace").splitlines()
  kept = [line for line in text if "warn" not in line.lower()]
  return [line[:300] for line in kept[-lines:]]


def _in_checkpoints(relative: Path) -> bool:
  """Whether a path lies in (or is) a run's `checkpoints` folder."""
  return "checkpoints" in relative.parts


def newest_checkpoints(folder: Path) -> set[Path]:
  """Every `checkpoints/step_<N>` folder under folder with the largest N of its folder
  (finalised ones: orbax's temporary folders are not named step_<N>)."""
  newest = set()
  for checkpoints in folder.rglob("checkpoints"):
    if not checkpoints.is_dir():
      continue
    steps = [p for p in checkpoints.iterdir() if p.is_dir() and re.fullmatch(r"step_\d+", p.name)]
    if steps:
      newest.add(max(steps, key=lambda p: int(p.name[5:])))
  return newest


def _files(folder: Path, subs: tuple[str, ...]) -> list[Path]:
  """The files of folder's `subs`, those in checkpoints folders left out."""
  files = []
  for sub in subs:
    root = folder / sub
    for path in sorted(root.rglob("*")) if root.is_dir() else [root]:
      relative = path.relative_to(folder)
      if path.is_file() and not _in_checkpoints(relative):
        files.append(path)
  return files


def _archive(path: Path, folder: Path, files: list[Path],
             extra: dict[str, bytes] | None = None) -> None:
  """The files (named relative to folder) and `extra` {name: bytes} in one .tgz at `path`,
  written beside it and renamed; a file that vanishes meanwhile is skipped."""
  tmp = path.with_name(path.name + ".tmp")
  with tarfile.open(tmp, "w:gz") as tar:
    for file in files:
      try:
        tar.add(file, arcname=str(file.relative_to(folder)), recursive=False)
      except FileNotFoundError:
        pass
    for name, data in (extra or {}).items():
      info = tarfile.TarInfo(name)
      info.size, info.mtime = len(data), time.time()
      tar.addfile(info, io.BytesIO(data))
  tmp.replace(path)


def _bytes(paths) -> int:
  """The bytes of the files `paths`, or of the files under one folder."""
  if isinstance(paths, Path):
    paths = [f for f in paths.rglob("*") if f.is_file()]
  return sum(f.stat().st_size for f in paths)


def pack(folder: Path, out: Path, checkpoints: bool = False,
         jobs: tuple[str, ...] | None = None) -> list[Path]:
  """folder's runs (`jobs`: only those jobs' run directories, runs/NAME) in one .tgz, split
  into parts of at most PART_BYTES under `out` (runs.tgz.part00, ...); returns the parts.
  Checkpoints are left out, except with `checkpoints` each run's newest (lean ones,
  `--lean_checkpoints`, are a few MB per member), smallest first, as many as keep the files
  under PACK_LIMIT; then each run's TensorBoard folder (`tb`, the same values as its
  progress.csv: a six-member run's are ~18 MB), as many as fit. It names those left out.
  JobsError, nothing packed, where the rest of the runs alone pass PACK_LIMIT."""
  runs = folder / "runs"
  if jobs is not None:
    missing = [j for j in jobs if not (runs / j).is_dir()]
    if missing:
      raise JobsError(f"no run directory for {', '.join(missing)} under {runs}")
  chosen = lambda p: jobs is None or p.relative_to(runs).parts[0] in jobs
  boards = sorted(p for p in runs.rglob("tb") if p.is_dir() and chosen(p)) if runs.is_dir() else []
  files = [f for f in _files(folder, ("runs",)) if chosen(f)
           and not any(b in f.parents for b in boards)]
  total = _bytes(files)
  steps = ({p: _bytes(p) for p in newest_checkpoints(runs) if chosen(p)} if checkpoints
           else {})
  logs = {p: _bytes(p) for p in boards}
  for extra, size in [*sorted(steps.items(), key=lambda kv: kv[1]),
                      *sorted(logs.items(), key=lambda kv: kv[1])]:
    if total + size <= PACK_LIMIT:
      files += [f for f in sorted(extra.rglob("*")) if f.is_file()]
      total += size
    else:
      hint = "" if extra.name == "tb" else " (use --lean_checkpoints)"
      print(f"left out {extra.relative_to(folder)} ({size / 2**20:.0f} MiB): the packed "
            f"runs may not pass {PACK_LIMIT / 2**20:.0f} MiB{hint}")
  archive = folder / "runs.tgz"
  _archive(archive, folder, files)
  size = archive.stat().st_size
  if size > PACK_LIMIT or -(-size // PART_BYTES) > MAX_PARTS:
    raise JobsError(f"the runs packed take {size / 2**20:.0f} MiB, over the "
                    f"{PACK_LIMIT / 2**20:.0f} MiB that come back: not packed; pack a part of "
                    f"{folder / 'runs'} by hand")
  parts, data = [], archive.read_bytes()
  for i in range(0, max(len(data), 1), PART_BYTES):
    part = out / f"runs.tgz.part{i // PART_BYTES:02d}"
    part.write_bytes(data[i:i + PART_BYTES])
    parts.append(part)
  return parts


def _scheduler_alive(folder: Path) -> bool:
  """Whether the detached scheduler of folder's sitting still runs."""
  try:
    os.kill(int((folder / "scheduler.pid").read_text()), 0)
  except (OSError, ValueError):
    return False
  return True


def poll(folder: Path, wait_s: float, out: Path | None, final: bool, lines: int = 3,
         checkpoints: bool = False, jobs: tuple[str, ...] | None = None,
         stop: bool = False) -> bool:
  """Waits until every job has ended or `wait_s` has passed; prints each job's state and last
  log lines; writes the records, logs and status to `out`; packs the runs there (with their
  newest checkpoints if `checkpoints`; `jobs`: only theirs) once every job has ended or `final`.
  `stop` first asks the runs to stop (the sitting's stop file: each run.py job ends at the end
  of its iteration, checkpointed, with its final evaluations; waiting jobs are skipped).
  Returns whether every job has ended."""
  if not (folder / "status.json").exists():
    raise JobsError(f"{folder} holds no sitting (no status.json): run `start` first")
  if stop:
    (folder / STOP).touch()
    print(f"asked the runs to stop ({folder / STOP})")
  end = time.time() + wait_s
  while not (folder / "all_done").exists() and time.time() < end:
    time.sleep(min(5.0, max(end - time.time(), 0.0)))
  done = (folder / "all_done").exists()
  status_bytes = (folder / "status.json").read_bytes()
  for name, state in json.loads(status_bytes).items():
    print(f"== {name}: " + ", ".join(f"{k} {v}" for k, v in state.items()))
    for line in _tail(folder / "logs" / f"{name}.log", lines):
      print("   " + line)
  if not done and not _scheduler_alive(folder):
    print(f"the scheduler is not running and the jobs have not all ended: see "
          f"{folder / 'scheduler.log'}")
  if out is not None:  # few files: the device brings back at most 8
    out.mkdir(parents=True, exist_ok=True)
    _archive(out / "records.tgz", folder, _files(folder, ("res", "logs", "scheduler.log")),
             {"status.json": status_bytes})
    print(f"records, logs and status in {out / 'records.tgz'}")
    if done or final:
      parts = pack(folder, out, checkpoints, jobs)
      print(f"runs packed into {len(parts)} part(s) under {out}: cat runs.tgz.part* | tar xz")
  print("every job has ended" if done else "jobs still running")
  return done


def main(argv=None) -> int:
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  sub = parser.add_subparsers(dest="action", required=True)
  p = sub.add_parser("check", help="print the settings each run.py job would train with")
  p.add_argument("jobs", type=Path)
  p.add_argument("--deadline", type=float, default=1200.0, help="the value of $LEFT")
  p = sub.add_parser("start", help="start the jobs of a jobs file, detached")
  p.add_argument("jobs", type=Path)
  p.add_argument("--dir", type=Path, required=True, help="the sitting's folder (new)")
  p.add_argument("--deadline", type=float, default=1200.0,
                 help="seconds from now that $LEFT counts down to (default 1200)")
  p.add_argument("--gpus", type=int, default=None, help="GPUs to use (default: all listed)")
  p = sub.add_parser("poll", help="wait, report, copy records (and pack the runs) to --out")
  p.add_argument("--dir", type=Path, required=True)
  p.add_argument("--wait", type=float, default=0.0, help="seconds to wait for the jobs to end")
  p.add_argument("--out", type=Path, default=None, help="where to copy (the device's $OUT)")
  p.add_argument("--final", action="store_true", help="pack the runs even if jobs still run")
  p.add_argument("--lines", type=int, default=3, help="log lines per job")
  p.add_argument("--stop", action="store_true",
                 help="first ask the runs to stop at the end of their iteration (run.py's "
                      "--stop_file: checkpointed, final evaluations after) and skip waiting jobs: "
                      "e.g. `poll --stop --wait 240 --final` where the device's time runs short")
  p.add_argument("--checkpoints", action="store_true",
                 help="pack each run's newest checkpoint too (to resume on another machine: "
                      "run with --lean_checkpoints; as many as keep the whole under 56 MiB)")
  p.add_argument("--runs", default=None, metavar="NAME[,NAME]",
                 help="pack only these jobs' run directories (default all): e.g. a last call "
                      "`--wait 0 --final --runs qr3 --checkpoints` after the others came back, "
                      "where one pack would not hold every run and a checkpoint")
  p = sub.add_parser("_schedule")  # the detached scheduler `start` launches
  p.add_argument("--dir", type=Path, required=True)
  args = parser.parse_args(argv)
  try:
    if args.action == "check":
      print("\n".join(check(args.jobs, args.deadline)))
    elif args.action == "start":
      start(args.jobs, args.dir, args.deadline, args.gpus)
    elif args.action == "poll":
      poll(args.dir, args.wait, args.out, args.final, args.lines, args.checkpoints,
           tuple(args.runs.split(",")) if args.runs else None, args.stop)
    else:
      plan = json.loads((args.dir / "jobs.json").read_text())
      schedule(plan["jobs"], plan["gpus"], args.dir, plan["end_time"])
  except (ValueError, OSError) as error:  # JobsError, unreadable or corrupt files
    print(f"error: {error}", file=sys.stderr)
    return 2
  return 0


if __name__ == "__main__":
  sys.exit(main())
