"""Train with `mjxsuite train` and judge the saved policy on the task's reference env: Gymnasium's
own env for Gymnasium's tasks, dm_control's own env for the DeepMind Control Suite's (dmc-*): the
README's training table (task, agent, wall time, return here, return on the reference).

Each `--run` is the argument list of one `mjxsuite train` (its `--out` is added), run as a user
runs it, in its own process, timed from start to exit; `--parallel` starts every run at once (one
GPU shared by several trainings; each process takes 1/N of the GPU's memory). The saved policy
(`agents.load_policy`) then drives the reference env for `--episodes` episodes with deterministic
actions:
- Gymnasium's tasks: `gymnasium.make(gymnasium_id)` (C MuJoCo, float64, its `max_episode_steps`),
  reset with seeds 0, 1, ...;
- dmc-* tasks: dm_control's `suite.load(domain, task)` (through the mujoco-4 shim), one episode per
  seed from `envs.interop.dm_control.JUDGE_FIRST_SEED` on, its observation flattened in its order,
  1,000 steps (`returns_on_dm_control`).
The record holds that mean return beside the run's own final evaluation (eval.json), on our env,
and the run's evaluation curve (env steps, evaluation return per seed, env-steps/s); with several
seeds every seed is judged: their median, interquartile mean and worst seed
(`benchmarks.reliability`) beside the whole process's wall time. A run still training after `--timeout` seconds
gets Ctrl-C, so it saves its checkpoint; its saved policy is judged all the same and the record
says "interrupted". Records are JSON (`--json FILE`, kind "gym-training"), written run by run.
`--no-judge` trains only (a GPU machine without the reference package); `--judge FILE` judges the
runs of such records later, where their run directories are.

    python -m benchmarks.gym_training --run "--env inverted-pendulum --agent ppo" \\
        [--run "--env dmc-cartpole-swingup --agent ppo --seeds 4" ...] [--parallel]
        [--out runs/gym-training] [--episodes 10] [--timeout SECONDS] [--json FILE] [--no-judge]
    python -m benchmarks.gym_training --judge RECORDS.json [--episodes 10] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from agents import signals
from benchmarks import reliability

# The environment the trainings start with: main() lets this process's own JAX (the judge's small
# policies) take GPU memory only as it needs it, and the trainings keep JAX's defaults.
_GIVEN_ENVIRONMENT = dict(os.environ)
# After its Ctrl-C a training saves its checkpoint and exits; one still running SAVE_WAIT_S later (or
# EXIT_WAIT_S after a second interrupt) is stuck, and is killed STACKS_WAIT_S after its stacks are asked for.
SAVE_WAIT_S, EXIT_WAIT_S, STACKS_WAIT_S = 120.0, 30.0, 5.0


def reference_of(env_name: str) -> str | None:
    """The env a policy trained on `env_name` is judged on: "gymnasium", "dm_control", or None."""
    import envs

    env = envs.make(env_name).unwrapped
    if getattr(env, "gymnasium_id", None) is not None:
        return "gymnasium"
    return "dm_control" if hasattr(env, "domain") and hasattr(env, "put_episode") else None


def gymnasium_returns(out_dir: Path, env_name: str, episodes: int, seed_index: int | None = None) -> list[float] | None:
    """Returns of the run's saved policy (`seed_index`, default the run's best seed) on
    Gymnasium's own env of its task `env_name` (None: the task has no Gymnasium twin)."""
    import gymnasium

    import agents
    import envs

    gymnasium_id = getattr(envs.make(env_name).unwrapped, "gymnasium_id", None)
    if gymnasium_id is None:
        return None
    policy = agents.load_policy(out_dir, seed_index)
    env = gymnasium.make(gymnasium_id)
    returns = []
    for episode in range(episodes):
        obs, _ = env.reset(seed=episode)
        total, done = 0.0, False
        while not done:
            obs, reward, terminated, truncated, _ = env.step(policy(obs))
            total += float(reward)
            done = terminated or truncated
        returns.append(total)
    env.close()
    return returns


def dm_control_returns(out_dir: Path, env_name: str, episodes: int, seed_index: int | None = None) -> list[float]:
    """Returns of the run's saved policy (`seed_index`, default the run's best seed) on dm_control's
    own env of its DeepMind Control Suite task `env_name` (`envs.returns_on_dm_control`); a run on
    camera images is judged on dm_control's pictures, with the run's camera options."""
    import agents
    import envs
    from agents import checkpoint
    from envs.pixels import PIXEL_OPTIONS

    camera = {k: v for k, v in checkpoint.load_config(out_dir).env_options.items() if k in PIXEL_OPTIONS}
    return envs.returns_on_dm_control(agents.load_policy(out_dir, seed_index), envs.make(env_name, **camera), episodes)


def reference_returns(out_dir: Path, env_name: str, episodes: int,
                      seed_index: int | None = None) -> tuple[str, list[float]] | None:
    """(reference, returns) of the run's saved policy on its task's reference env (`reference_of`);
    None for a task that has none."""
    reference = reference_of(env_name)
    judge = {"gymnasium": gymnasium_returns, "dm_control": dm_control_returns}.get(reference)
    return None if judge is None else (reference, judge(out_dir, env_name, episodes, seed_index))


def start(train_args: list[str], out_dir: Path, share: int = 1) -> tuple[dict, subprocess.Popen]:
    """Start one `mjxsuite train` into `out_dir` (its record and process); `share` trainings at once
    on one GPU each take 1/share of its memory (JAX takes 75% by default)."""
    record = {"kind": "gym-training", "command": "mjxsuite train " + shlex.join(train_args), "out": str(out_dir),
              "started": time.perf_counter()}
    command = [sys.executable, "-m", "benchmarks.cli", "train", *train_args, "--out", str(out_dir), "--overwrite"]
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        # A shell ignores SIGINT in background jobs and the child would inherit that, so Python
        # there would never raise KeyboardInterrupt and the Ctrl-C below would do nothing. A
        # handled signal starts the child with the default instead.
        signal.signal(signal.SIGINT, signal.default_int_handler)
    child_env = dict(_GIVEN_ENVIRONMENT)
    if share > 1:
        child_env.setdefault("XLA_PYTHON_CLIENT_MEM_FRACTION", f"{0.9 / share:.3f}")
    return record, subprocess.Popen(command, env=child_env)


def stop(started: list[tuple[dict, subprocess.Popen]], timeout: float | None) -> list[dict]:
    """Wait for started trainings until `timeout` s after each one's start; then Ctrl-C every one
    still running, all at once (each saves its checkpoint at the end of its chunk and stops). The
    records get the wall time and, where it was stopped, "interrupted"."""
    for record, training in started:
        try:
            left = None if timeout is None else max(0.0, record["started"] + timeout - time.perf_counter())
            training.wait(timeout=left)
        except subprocess.TimeoutExpired:
            record["interrupted"] = f"stopped after {timeout:.0f} s"
            training.send_signal(signal.SIGINT)
    for record, training in started:
        try:
            try:
                training.wait(timeout=SAVE_WAIT_S)
            except KeyboardInterrupt:  # a second Ctrl-C, or an outer time bound's: the trainings got it too
                record["interrupted"] = (f"{record.get('interrupted', 'running')}, then a second interrupt while it "
                                         "saved: its last saved chunk stands")
                training.wait(timeout=EXIT_WAIT_S)
        except subprocess.TimeoutExpired:
            kill_unresponsive(training, record)
        record["wall_s"] = time.perf_counter() - record.pop("started")
        if training.returncode != 0 and "interrupted" not in record:
            record["skipped"] = f"exit status {training.returncode}"
    return [record for record, _ in started]


def kill_unresponsive(training: subprocess.Popen, record: dict) -> None:
    """End a training that did not stop when asked: its threads' stacks first, into its log
    (`agents.signals.dump_stacks_on_signal`), then SIGKILL; its last saved chunk stands."""
    training.send_signal(signals.STACKS_SIGNAL)
    time.sleep(STACKS_WAIT_S)
    training.kill()
    training.wait()
    record["interrupted"] = (f"{record.get('interrupted', 'running')}; it did not stop when asked, so it was "
                             "killed after printing its threads' stacks: its last saved chunk stands")


def describe(record: dict) -> dict:
    """The saved run's config, evaluation curve and final evaluation, added to its record."""
    import jax

    from agents import checkpoint

    out_dir = Path(record["out"])
    if not (out_dir / "config.json").exists():
        return {**record, "skipped": "no run was saved"}
    saved = checkpoint.load_config(out_dir)
    device = jax.devices()[0]
    record.update(env=saved.env, agent=saved.agent, env_options=saved.env_options, seeds=saved.seeds,
                  impl=saved.env_options.get("impl", "jax"), device=device.device_kind, platform=device.platform,
                  jax=jax.__version__)
    metrics = out_dir / "metrics.jsonl"
    evaluations = [json.loads(text) for text in metrics.read_text().splitlines()] if metrics.exists() else []
    overflow_keys = ("overflow_contacts", "overflow_constraints")
    curve_keys = ("env_steps", "eval_return", "steps_per_s", "judge_s", *overflow_keys)
    if any("actor_saturation" in r for r in evaluations):  # TD3's: a seed that stands still shows there
        curve_keys += ("actor_saturation",)
    record["evaluations"] = [{key: r.get(key) for key in curve_keys} for r in evaluations]
    # Training env-steps (of the most-overflowing seed, summed over chunks) that MuJoCo Warp's buffers could not hold.
    record["overflowed_steps"] = int(sum(np.max(r.get(key, 0)) for r in evaluations for key in overflow_keys))
    if (out_dir / "eval.json").exists():
        summary = json.loads((out_dir / "eval.json").read_text())
        record.update(return_here=float(np.mean(summary["mean_return"])), train_wall_s=summary.get("wall_s"),
                      compile_s=summary.get("compile_s"), wall_parts_s=summary.get("wall_parts_s"))
    else:  # interrupted: the best evaluation during training stands in for the final one
        record["return_here"] = max((float(np.max(r["eval_return"])) for r in evaluations), default=None)
        record["wall_parts_s"] = saved_time_split(out_dir)
    if not (out_dir / checkpoint.POLICY_FILE).exists():  # stopped before its first checkpoint
        return {**record, "skipped": "stopped before any trained parameters were evaluated and saved"}
    return record


def saved_time_split(out_dir: Path) -> dict | None:
    """The run's seconds by part (setup, compile, train, judge, save, ...) at its last checkpoint; None where
    its progress.json predates the clock it now carries."""
    from agents import checkpoint

    try:
        progress = json.loads((out_dir / checkpoint.PROGRESS_FILE).read_text())
    except (OSError, ValueError):
        return None
    return (progress.get("clock") or {}).get("wall_parts_s")


def judge(record: dict, episodes: int) -> dict:
    """Every seed's saved policy on the task's reference env: the best seed's returns, every seed's
    mean, their median and the worst seed, as `{name}_on_{reference}` keys."""
    from agents import checkpoint

    out_dir = Path(record["out"])
    if "skipped" in record or reference_of(record["env"]) is None:
        return record
    best = checkpoint.best_seed(out_dir)
    judged = [reference_returns(out_dir, record["env"], episodes, i) for i in range(record["seeds"])]
    reference, means = judged[0][0], [float(np.mean(returns)) for _, returns in judged]
    spread = reliability.over_seeds(means)
    record.update({f"{reference}_returns": judged[best][1], f"return_on_{reference}": means[best], "best_seed": best,
                   f"seeds_on_{reference}": means, f"median_on_{reference}": spread["median"],
                   f"iqm_on_{reference}": spread["iqm"], f"worst_on_{reference}": spread["worst"],
                   "judge_episodes": episodes, "judged_on": reference})
    if record["return_here"]:
        record[f"{reference}_over_here"] = means[best] / record["return_here"]
    return record


def run_one(train_args: list[str], out_dir: Path, episodes: int, timeout: float | None) -> dict:
    """Train, then judge. A training still running after `timeout` s gets Ctrl-C (it saves its
    checkpoint and stops); its saved policy is judged all the same, marked "interrupted"."""
    [record] = stop([start(train_args, out_dir)], timeout)
    return judge(describe(record), episodes) if "skipped" not in record else record


def line(r: dict) -> str:
    if "skipped" in r:
        return f"{r['command']}: {r['skipped']}"
    reference = r.get("judged_on") or ("gymnasium" if "return_on_gymnasium" in r else None)
    names = {"gymnasium": "Gymnasium", "dm_control": "dm_control"}
    judged = f"{r[f'return_on_{reference}']:.1f}" if reference else "-"
    here = f"{r['return_here']:.1f}" if r.get("return_here") is not None else "-"
    stopped = f" [{r['interrupted']}]" if "interrupted" in r else ""
    overflow = f"  {r['overflowed_steps']:,} training steps overflowed" if r.get("overflowed_steps") else ""
    seeds = (f"  seeds on {names[reference]} {', '.join(f'{m:.0f}' for m in r[f'seeds_on_{reference}'])}"
             f" (median {r[f'median_on_{reference}']:.0f}, IQM {r[f'iqm_on_{reference}']:.0f},"
             f" worst {r[f'worst_on_{reference}']:.0f})" if reference and len(r[f"seeds_on_{reference}"]) > 1 else "")
    return (f"{r['env']:<26} {r['agent']:<4} {r['wall_s']:7.0f} s  return here {here:>9}  "
            f"on {names.get(reference, 'its reference')} {judged:>9}{seeds}{overflow}   ({r['command']}){stopped}")


def train_all(parser, args) -> list[dict]:
    """Every `--run`, one after another or (`--parallel`) all at once; judged unless `--no-judge`."""
    runs = []
    for i, text in enumerate(args.runs):
        train_args = shlex.split(text)
        if "--out" in train_args:
            parser.error(f"--run {text!r}: leave --out out, the runs go under --out {args.out}")
        runs.append((train_args, Path(args.out) / f"run{i}"))
    if args.parallel:
        stopped = iter(stop([start(*run, share=len(runs)) for run in runs], args.timeout))
    found = []
    for run in runs:
        [record] = [next(stopped)] if args.parallel else stop([start(*run)], args.timeout)
        record = describe(record) if "skipped" not in record else record
        found.append(record if args.no_judge else judge(record, args.episodes))
        print(line(found[-1]), flush=True)
        if args.json:
            Path(args.json).write_text(json.dumps(found, indent=2))
    return found


def judge_saved(args, records: list[dict]) -> list[dict]:
    """The records of an earlier `--no-judge` run (`--judge FILE`), each judged where its run
    directory is."""
    found = []
    for record in records:
        if "skipped" not in record and not Path(record["out"]).is_dir():
            record = {**record, "skipped": f"run directory {record['out']} not found here"}
        found.append(judge(record, args.episodes))
        print(line(found[-1]), flush=True)
        if args.json:
            Path(args.json).write_text(json.dumps(found, indent=2))
    return found


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.gym_training", description=__doc__.splitlines()[0])
    parser.add_argument("--run", dest="runs", action="append", metavar='"TRAIN ARGS"',
                        help='the arguments of one `mjxsuite train`, quoted, e.g. "--env hopper --agent sac"; repeatable')
    parser.add_argument("--judge", metavar="RECORDS", help="judge the runs of these records (from --no-judge) instead")
    parser.add_argument("--out", default="runs/gym-training", help="parent of the runs' directories")
    parser.add_argument("--episodes", type=int, default=10, help="episodes on the reference env")
    parser.add_argument("--timeout", type=float, help="seconds one training may take before it is stopped (Ctrl-C: it saves, then is judged)")
    parser.add_argument("--parallel", action="store_true", help="start every --run at once")
    parser.add_argument("--no-judge", action="store_true", help="train only; judge later with --judge")
    parser.add_argument("--json", metavar="FILE", help="write the records as JSON")
    args = parser.parse_args(argv)
    os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")
    if bool(args.runs) == bool(args.judge):
        parser.error("give --run (train, then judge) or --judge RECORDS (judge saved runs), not both or neither")
    saved = json.loads(Path(args.judge).read_text()) if args.judge else []
    if any("observation=pixels" in text for text in args.runs or []) or any(
            record.get("env_options", {}).get("observation") == "pixels" for record in saved):
        # dm_control picks its renderer when first imported: a pixel run's judge renders its pictures.
        os.environ.setdefault("MUJOCO_GL", "egl")
    judge_saved(args, saved) if args.judge else train_all(parser, args)


if __name__ == "__main__":
    main()
