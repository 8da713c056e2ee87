"""Run a list of jobs on one machine's GPUs, one job per GPU, detached; poll them; bring back
what they wrote.

A GPU machine takes one command at a time, for at most 10 minutes each, and nothing on it
outlasts the machine. So a sitting of several runs starts them detached (`start`), then polls
(`poll`, one call per command) until they end, and each poll writes the records, logs and
status to `--out` (the device's $OUT) as one `records.tgz`, so that whatever the sitting ends
like, the records already polled are safe. The last poll (`--final`, or once every job has
ended) also packs the run directories into parts of at most 15 MB, without checkpoints unless
`--checkpoints` asks for each run's newest (lean ones, to resume in the next sitting).

  python scripts/gpu_jobs.py start jobs.txt --dir /tmp/sitting --deadline 1200
  python scripts/gpu_jobs.py poll --dir /tmp/sitting --wait 540 --out $OUT [--final]

The jobs file has one job per line, `NAME: COMMAND` (blank lines and `#` comments skipped);
`NAME [gpus=N]: COMMAND` gives a job N GPUs (default 1). Jobs start in order as soon as
enough GPUs are free. Each job runs from the working directory in its own session with
`CUDA_VISIBLE_DEVICES` set to its GPUs and these variables:
  RES   the folder for its records (`--results $RES/NAME.jsonl`), copied back at every poll;
  RUNS  the folder for its run directories (`--run_dir $RUNS/NAME`), packed at the end;
  LEFT  seconds left until the deadline at the job's start (`--max_seconds $LEFT` makes a
        queued job fit the sitting; the deadline counts from `start`).
Its output goes to `logs/NAME.log` under --dir; `status.json` says which jobs run, wait or
ended, and with which exit code.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tarfile
import time
from pathlib import Path

PART_BYTES = 15 * 2**20  # a part of the packed runs; under the device's limit on a file
LINE = re.compile(r"^(?P<name>[A-Za-z0-9_.-]+)(\s+gpus=(?P<gpus>\d+))?\s*:\s*(?P<cmd>.+)$")


class JobsError(ValueError):
  """A jobs file or request that cannot be run; the message names the problem."""


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


def count_gpus() -> int:
  """The GPUs `nvidia-smi -L` lists (0 where it is missing)."""
  try:
    out = subprocess.run(["nvidia-smi", "-L"], capture_output=True, text=True, check=True).stdout
  except (OSError, subprocess.CalledProcessError):
    return 0
  return sum(line.startswith("GPU ") for line in out.splitlines())


def schedule(jobs: list[dict], num_gpus: int, folder: Path, deadline_s: float,
             poll_s: float = 2.0) -> None:
  """Runs `jobs` in order on `num_gpus` GPUs, each as soon as it has enough free ones; writes
  folder/status.json whenever a job starts or ends; returns when every job has ended."""
  start = time.time()
  free, running, status = list(range(num_gpus)), {}, {j["name"]: {"state": "waiting"} for j in jobs}
  waiting = list(jobs)

  def write_status():
    tmp = folder / "status.json.tmp"
    tmp.write_text(json.dumps(status, indent=1))
    tmp.replace(folder / "status.json")

  write_status()
  while waiting or running:
    while waiting and len(free) >= waiting[0]["gpus"]:
      job = waiting.pop(0)
      gpus, free = free[:job["gpus"]], free[job["gpus"]:]
      left = max(int(deadline_s - (time.time() - start)), 1)
      env = {**os.environ, "CUDA_VISIBLE_DEVICES": ",".join(map(str, gpus)),
             "RES": str(folder / "res"), "RUNS": str(folder / "runs"), "LEFT": str(left)}
      log = open(folder / "logs" / f"{job['name']}.log", "w")
      process = subprocess.Popen(["bash", "-c", job["cmd"]], env=env, stdout=log,
                                 stderr=subprocess.STDOUT, start_new_session=True)
      running[job["name"]] = (process, gpus, log)
      status[job["name"]] = {"state": "running", "gpus": gpus, "left_s": left,
                             "started_s": round(time.time() - start, 1)}
      write_status()
    time.sleep(poll_s)
    for name, (process, gpus, log) in list(running.items()):
      if process.poll() is not None:
        log.close()
        free = sorted(free + gpus)
        del running[name]
        status[name].update(state="ended", rc=process.returncode,
                            ended_s=round(time.time() - start, 1))
        write_status()
  (folder / "all_done").touch()


def start(jobs_file: Path, folder: Path, deadline_s: float, num_gpus: int | None) -> None:
  """Checks the jobs, makes the folders and runs `schedule` detached (it outlives the command)."""
  num_gpus = count_gpus() if num_gpus is None else num_gpus
  if num_gpus < 1:
    raise JobsError("no GPU found (nvidia-smi -L lists none); pass --gpus to say how many")
  jobs = parse_jobs(jobs_file.read_text(), num_gpus)
  if (folder / "status.json").exists():
    raise JobsError(f"{folder} already holds a sitting (status.json); pick another --dir")
  for sub in ("logs", "res", "runs"):
    (folder / sub).mkdir(parents=True, exist_ok=True)
  (folder / "jobs.json").write_text(json.dumps(jobs, indent=1))
  (folder / "status.json").write_text(json.dumps({j["name"]: {"state": "waiting"} for j in jobs}))
  subprocess.Popen([sys.executable, __file__, "_schedule", "--dir", str(folder),
                    "--deadline", str(deadline_s), "--gpus", str(num_gpus)],
                   stdout=open(folder / "scheduler.log", "w"), stderr=subprocess.STDOUT,
                   stdin=subprocess.DEVNULL, start_new_session=True)
  print(f"{len(jobs)} jobs on {num_gpus} GPUs, deadline {deadline_s:.0f} s: "
        + ", ".join(f"{j['name']} ({j['gpus']} GPU{'s' if j['gpus'] > 1 else ''})" for j in jobs))


def _tail(path: Path, lines: int) -> list[str]:
  """The last `lines` lines of a log, warnings left out, each cut to 300 characters."""
  if not path.exists():
    return []
  text = path.read_text(errors="replace").splitlines()
  kept = [line for line in text if "warn" not in line.lower()]
  return [line[:300] for line in kept[-lines:]]


PACK_LIMIT = 56 * 2**20  # the packed runs that may come back (the device's limit: 64 MiB)


def newest_checkpoints(folder: Path) -> set[Path]:
  """Every `checkpoints/step_<N>` under folder with the largest N of its folder (finalised
  ones: orbax's temporary folders are not named step_<N>)."""
  newest = set()
  for checkpoints in folder.rglob("checkpoints"):
    steps = [p for p in checkpoints.iterdir() if re.fullmatch(r"step_\d+", p.name)]
    if steps:
      newest.add(max(steps, key=lambda p: int(p.name[5:])))
  return newest


def _archive(path: Path, folder: Path, subs: tuple[str, ...], keep=frozenset()) -> None:
  """folder's `subs` in one .tgz at `path`, checkpoints left out except the folders `keep`."""
  keep = {str(p.relative_to(folder)) for p in keep}

  def kept(info):
    if "checkpoint" not in info.name:
      return info
    parts = Path(info.name).parts
    inside = any(str(Path(*parts[:i])) in keep for i in range(1, len(parts) + 1))
    return info if inside or (keep and parts[-1] == "checkpoints") else None

  with tarfile.open(path, "w:gz") as tar:
    for sub in subs:
      tar.add(folder / sub, arcname=sub, filter=kept)


def _bytes(path: Path, skip_checkpoints: bool = False) -> int:
  """The bytes of the files under path (checkpoints left out if `skip_checkpoints`)."""
  return sum(f.stat().st_size for f in path.rglob("*") if f.is_file() and not (
      skip_checkpoints and "checkpoint" in str(f.relative_to(path))))


def pack(folder: Path, out: Path, checkpoints: bool = False) -> list[Path]:
  """folder's runs in one .tgz, split into parts of at most PART_BYTES under `out`
  (runs.tgz.part00, ...); returns the parts. Checkpoints are left out, except with
  `checkpoints` each run's newest (lean ones, `--lean_checkpoints`, are a few MB), smallest
  first, as many as keep the files under PACK_LIMIT (it names those left out)."""
  keep, total = set(), _bytes(folder / "runs", skip_checkpoints=True)
  if checkpoints:
    for step in sorted(newest_checkpoints(folder / "runs"), key=_bytes):
      if total + _bytes(step) <= PACK_LIMIT:
        keep.add(step)
        total += _bytes(step)
      else:
        print(f"left out {step.relative_to(folder)} ({_bytes(step) / 2**20:.0f} MiB): the packed "
              f"runs may not pass {PACK_LIMIT / 2**20:.0f} MiB (use --lean_checkpoints)")
  archive = folder / "runs.tgz"
  _archive(archive, folder, ("runs",), keep)
  parts, data = [], archive.read_bytes()
  for i in range(0, max(len(data), 1), PART_BYTES):
    part = out / f"runs.tgz.part{i // PART_BYTES:02d}"
    part.write_bytes(data[i:i + PART_BYTES])
    parts.append(part)
  return parts


def poll(folder: Path, wait_s: float, out: Path | None, final: bool, lines: int = 3,
         checkpoints: bool = False) -> bool:
  """Waits until every job has ended or `wait_s` has passed; prints each job's state and last
  log lines; copies the records and status to `out`; packs the runs there (with their newest
  checkpoints if `checkpoints`) once every job has ended or `final`. Returns whether every job
  has ended."""
  if not (folder / "status.json").exists():
    raise JobsError(f"{folder} holds no sitting (no status.json): run `start` first")
  end = time.time() + wait_s
  while not (folder / "all_done").exists() and time.time() < end:
    time.sleep(min(5.0, max(end - time.time(), 0.0)))
  done = (folder / "all_done").exists()
  status = json.loads((folder / "status.json").read_text())
  for name, state in status.items():
    print(f"== {name}: " + ", ".join(f"{k} {v}" for k, v in state.items()))
    for line in _tail(folder / "logs" / f"{name}.log", lines):
      print("   " + line)
  if out is not None:  # few files: the device brings back at most 8
    out.mkdir(parents=True, exist_ok=True)
    _archive(out / "records.tgz", folder, ("res", "logs", "status.json"))
    print(f"records, logs and status in {out / 'records.tgz'}")
    if done or final:
      parts = pack(folder, out, checkpoints)
      print(f"runs packed into {len(parts)} part(s) under {out}: cat runs.tgz.part* | tar xz")
  print("every job has ended" if done else "jobs still running")
  return done


def main(argv=None) -> int:
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  sub = parser.add_subparsers(dest="action", required=True)
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
  p.add_argument("--checkpoints", action="store_true",
                 help="pack each run's newest checkpoint too (to resume on another machine: "
                      "run with --lean_checkpoints; as many as keep the whole under 56 MiB)")
  p = sub.add_parser("_schedule")  # the detached scheduler `start` launches
  p.add_argument("--dir", type=Path, required=True)
  p.add_argument("--deadline", type=float, required=True)
  p.add_argument("--gpus", type=int, required=True)
  args = parser.parse_args(argv)
  try:
    if args.action == "start":
      start(args.jobs, args.dir, args.deadline, args.gpus)
    elif args.action == "poll":
      poll(args.dir, args.wait, args.out, args.final, args.lines, args.checkpoints)
    else:
      jobs = json.loads((args.dir / "jobs.json").read_text())
      schedule(jobs, args.gpus, args.dir, args.deadline)
  except (JobsError, OSError) as error:
    print(f"error: {error}", file=sys.stderr)
    return 2
  return 0


if __name__ == "__main__":
  sys.exit(main())
