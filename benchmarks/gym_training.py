"""Train with `mjxsuite train` and judge the saved policy on Gymnasium's own env: the README's
training table (task, agent, wall time, return here, return on Gymnasium).

Each `--run` is the argument list of one `mjxsuite train` (its `--out` is added), run as a user
runs it, in its own process, timed from start to exit. The saved policy (`agents.load_policy`)
then drives Gymnasium's own env of the task (`gymnasium.make(gymnasium_id)`: C MuJoCo, float64,
its `max_episode_steps`) for `--episodes` episodes with deterministic actions, reset with seeds
0, 1, ...; the record holds that mean return beside the run's own final evaluation (eval.json),
on our env, and the run's evaluation curve (env steps, evaluation return per seed, env-steps/s);
with several seeds every seed is judged on Gymnasium, and the record holds their median,
interquartile mean and worst seed (`benchmarks.reliability`) beside the whole process's wall time.
A run still training after `--timeout` seconds gets Ctrl-C, so it saves its checkpoint; its saved
policy is judged all the same and the record says "interrupted". Records are JSON (`--json FILE`,
kind "gym-training"), written run by run.

    python -m benchmarks.gym_training --run "--env inverted-pendulum --agent ppo" \\
        [--run "--env half-cheetah --agent ppo --impl warp --steps 20000000" ...]
        [--out runs/gym-training] [--episodes 10] [--timeout SECONDS] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import shlex
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from benchmarks import reliability


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


def run_one(train_args: list[str], out_dir: Path, episodes: int, timeout: float | None) -> dict:
    """Train, then judge. A training still running after `timeout` s gets Ctrl-C (it saves its
    checkpoint and stops); its saved policy is judged all the same, marked "interrupted"."""
    record = {"kind": "gym-training", "command": "mjxsuite train " + shlex.join(train_args)}
    command = [sys.executable, "-m", "benchmarks.cli", "train", *train_args, "--out", str(out_dir), "--overwrite"]
    start = time.perf_counter()
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        # A shell ignores SIGINT in background jobs and the child would inherit that, so Python
        # there would never raise KeyboardInterrupt and the Ctrl-C below would do nothing. A
        # handled signal starts the child with the default instead.
        signal.signal(signal.SIGINT, signal.default_int_handler)
    training = subprocess.Popen(command)
    try:
        training.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        record["interrupted"] = f"stopped after {timeout:.0f} s"
        training.send_signal(signal.SIGINT)
        try:
            training.wait(timeout=120)
        except subprocess.TimeoutExpired:
            training.kill()
            training.wait()
    record["wall_s"] = time.perf_counter() - start
    if training.returncode != 0 and "interrupted" not in record:
        return {**record, "skipped": f"exit status {training.returncode}"}
    if not (out_dir / "config.json").exists():
        return {**record, "skipped": "no run was saved"}
    from agents import checkpoint

    saved = checkpoint.load_config(out_dir)
    record.update(env=saved.env, agent=saved.agent, env_options=saved.env_options)
    metrics = out_dir / "metrics.jsonl"
    evaluations = [json.loads(text) for text in metrics.read_text().splitlines()] if metrics.exists() else []
    curve_keys = ("env_steps", "eval_return", "steps_per_s", "overflow_contacts", "overflow_constraints")
    record["evaluations"] = [{key: r.get(key) for key in curve_keys} for r in evaluations]
    # Training env-steps (of the most-overflowing seed, summed over chunks) that MuJoCo Warp's buffers could not hold.
    record["overflowed_steps"] = int(sum(np.max(r.get(key, 0)) for r in evaluations for key in curve_keys[3:]))
    if (out_dir / "eval.json").exists():
        summary = json.loads((out_dir / "eval.json").read_text())
        record.update(return_here=float(np.mean(summary["mean_return"])), train_wall_s=summary.get("wall_s"),
                      compile_s=summary.get("compile_s"))
    else:  # interrupted: the best evaluation during training stands in for the final one
        record["return_here"] = max((float(np.max(r["eval_return"])) for r in evaluations), default=None)
    if not (out_dir / checkpoint.POLICY_FILE).exists():  # stopped before its first checkpoint
        return {**record, "skipped": "stopped before any trained parameters were evaluated and saved"}
    best = checkpoint.best_seed(out_dir)
    per_seed = [gymnasium_returns(out_dir, saved.env, episodes, i) for i in range(saved.seeds)]
    if per_seed[0] is not None:
        means = [float(np.mean(returns)) for returns in per_seed]
        spread = reliability.over_seeds(means)
        record.update(gymnasium_returns=per_seed[best], return_on_gymnasium=means[best], best_seed=best,
                      seeds_on_gymnasium=means, median_on_gymnasium=spread["median"],
                      iqm_on_gymnasium=spread["iqm"], worst_on_gymnasium=spread["worst"])
        if record["return_here"]:
            record["gymnasium_over_here"] = means[best] / record["return_here"]
    return record


def line(r: dict) -> str:
    if "skipped" in r:
        return f"{r['command']}: {r['skipped']}"
    gym = f"{r['return_on_gymnasium']:.1f}" if "return_on_gymnasium" in r else "-"
    here = f"{r['return_here']:.1f}" if r.get("return_here") is not None else "-"
    stopped = f" [{r['interrupted']}]" if "interrupted" in r else ""
    overflow = f"  {r['overflowed_steps']:,} training steps overflowed" if r.get("overflowed_steps") else ""
    seeds = (f"  seeds on Gymnasium {', '.join(f'{m:.0f}' for m in r['seeds_on_gymnasium'])}"
             f" (median {r['median_on_gymnasium']:.0f}, IQM {r['iqm_on_gymnasium']:.0f}, worst {r['worst_on_gymnasium']:.0f})"
             if len(r.get("seeds_on_gymnasium", [])) > 1 else "")
    return (f"{r['env']:<26} {r['agent']:<4} {r['wall_s']:7.0f} s  return here {here:>9}  "
            f"on Gymnasium {gym:>9}{seeds}{overflow}   ({r['command']}){stopped}")


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.gym_training", description=__doc__.splitlines()[0])
    parser.add_argument("--run", dest="runs", action="append", required=True, metavar='"TRAIN ARGS"',
                        help='the arguments of one `mjxsuite train`, quoted, e.g. "--env hopper --agent sac"; repeatable')
    parser.add_argument("--out", default="runs/gym-training", help="parent of the runs' directories")
    parser.add_argument("--episodes", type=int, default=10, help="episodes on Gymnasium's env")
    parser.add_argument("--timeout", type=float, help="seconds one training may take before it is stopped (Ctrl-C: it saves, then is judged)")
    parser.add_argument("--json", metavar="FILE", help="write the records as JSON")
    args = parser.parse_args(argv)
    found = []
    for i, text in enumerate(args.runs):
        train_args = shlex.split(text)
        if "--out" in train_args:
            parser.error(f"--run {text!r}: leave --out out, the runs go under --out {args.out}")
        record = run_one(train_args, Path(args.out) / f"run{i}", args.episodes, args.timeout)
        found.append(record)
        print(line(record), flush=True)
        if args.json:
            Path(args.json).write_text(json.dumps(found, indent=2))


if __name__ == "__main__":
    main()
