"""What Rerun logging costs.

    python -m benchmarks.rerun_logging [--quick] [--json FILE]

Rows:
- `log-rollout`: logging a 100,000-step CartPole rollout of one env to a fresh .rrd:
  the host copy, the geom poses (C MuJoCo `mj_kinematics`), `send_columns` and the
  file save (stream closed, footer written); collecting the rollout is excluded.
  The alternative for the poses, a vmapped `mjx.kinematics`, is timed beside it.
- `train-rerun`: `train_run` on cartpole (default config, one seed) without Rerun, with
  the training curves only (`--rerun-every 0`), and with curves plus the greedy
  evaluation episode of every chunk (the CLI default); the runs alternate,
  repeated. `slowdown` is the median over repeats of (with / without) - 1, and
  `cpu_overhead` the same for the process's CPU time; `logger_share` is the part
  of the run spent inside the callback and `close()`.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import statistics
import tempfile
import time
from pathlib import Path

import jax
import numpy as np

import envs
from agents.dqn import DQNConfig
from agents.training_log import TrainingLogger
from agents.run import train_run
from envs import recording


def _timed(fn) -> float:
    start = time.perf_counter()
    fn()
    return time.perf_counter() - start


def _wall_and_cpu(fn) -> tuple[float, float]:
    """Wall seconds and CPU seconds of this process (all threads)."""
    wall, cpu = time.perf_counter(), time.process_time()
    fn()
    return time.perf_counter() - wall, time.process_time() - cpu


def log_rollout_record(steps: int = 100_000, repeats: int = 5) -> dict:
    env = envs.make("cartpole")
    rollout = recording.collect_rollout(env, recording.random_policy(env), jax.random.PRNGKey(0), steps=steps)
    jax.block_until_ready(rollout)
    model = env.scene_model()
    geoms = recording.scene_from_model(model)
    moving = [g.geom_id for g in geoms if not g.fixed]

    with tempfile.TemporaryDirectory() as tmp:
        def log_once():
            rec = recording.open_recording(Path(tmp) / "rollout.rrd", overwrite=True)
            recording.log_rollout(rec, env, rollout)
            recording.close_recording(rec)

        log_once()  # warm-up: first-use imports and allocations
        total = [_timed(log_once) for _ in range(repeats)]
        size = (Path(tmp) / "rollout.rrd").stat().st_size
    qpos = np.asarray(rollout.scene_qpos[:, 0])
    host_copy = [_timed(lambda: jax.device_get(rollout)) for _ in range(repeats)]
    poses = [_timed(lambda: recording.geom_poses(model, qpos, moving)) for _ in range(repeats)]
    mjx_compile, mjx_warm = _mjx_kinematics_times(env.unwrapped.scene_model(), qpos)
    return {
        "kind": "log-rollout", "env": "cartpole", "steps": steps, "envs": 1, "repeats": repeats,
        "total_s_min": min(total), "total_s_median": statistics.median(total),
        "host_copy_s": min(host_copy), "poses_mj_kinematics_s": min(poses),
        "poses_mjx_kinematics_first_call_s": mjx_compile, "poses_mjx_kinematics_warm_s": mjx_warm,
        "file_mb": size / 1e6,
    }


def _mjx_kinematics_times(model, qpos: np.ndarray) -> tuple[float, float]:
    """The alternative to the host loop: `mjx.kinematics` vmapped over all steps (first call, then warm)."""
    with contextlib.redirect_stdout(io.StringIO()):
        from mujoco import mjx
    mjx_model = mjx.put_model(model, impl="jax")
    data = mjx.make_data(mjx_model, impl="jax")

    @jax.jit
    def poses(q):
        out = jax.vmap(lambda q: mjx.kinematics(mjx_model, data.replace(qpos=q)))(q)
        return out.geom_xpos, out.geom_xmat

    qpos = qpos.astype(np.float32)
    first = _timed(lambda: jax.device_get(poses(qpos)))
    warm = min(_timed(lambda: jax.device_get(poses(qpos))) for _ in range(3))
    return first, warm


def _train_once(config: DQNConfig, path: Path, rollout_every: int | None) -> dict:
    """One training run; `rollout_every` None trains without a logger."""
    logger = None if rollout_every is None else TrainingLogger(path, "cartpole", config, overwrite=True,
                                                                rollout_every=rollout_every)
    in_logger = []

    def on_chunk(index, train_state, record):
        in_logger.append(_timed(lambda: logger(index, train_state, record)))

    def run():
        try:
            train_run("cartpole", config, progress=False, on_chunk=on_chunk if logger else None)
        finally:
            if logger is not None:
                in_logger.append(_timed(logger.close))

    wall, cpu = _wall_and_cpu(run)
    return {"wall_s": wall, "cpu_s": cpu, "logger_s": sum(in_logger)}


def train_records(steps: int = 20_000, repeats: int = 5) -> list[dict]:
    config = DQNConfig(total_steps=steps)
    variants = {"none": None, "curves": 0, "curves+rollouts": 1}  # rollout_every
    runs = {name: [] for name in variants}
    with tempfile.TemporaryDirectory() as tmp:
        _train_once(config, Path(tmp) / "train.rrd", None)  # warm-up: a process's first run pays one-off costs
        for _ in range(repeats):  # interleaved, so load from elsewhere on the machine hits all alike
            for name, rollout_every in variants.items():
                runs[name].append(_train_once(config, Path(tmp) / "train.rrd", rollout_every))
    median = statistics.median
    base = runs["none"]
    rows = []
    for name in [v for v in variants if v != "none"]:
        logged = runs[name]
        rows.append({
            "kind": "train-rerun", "logging": name, "env": "cartpole", "steps": steps, "seeds": 1,
            "chunks": config.num_chunks, "repeats": repeats,
            "wall_s_without": [r["wall_s"] for r in base], "wall_s_with": [r["wall_s"] for r in logged],
            "median_without_s": median(r["wall_s"] for r in base), "median_with_s": median(r["wall_s"] for r in logged),
            "slowdown": median(w["wall_s"] / b["wall_s"] for w, b in zip(logged, base)) - 1.0,
            "cpu_overhead": median(w["cpu_s"] / b["cpu_s"] for w, b in zip(logged, base)) - 1.0,
            "logger_s": median(r["logger_s"] for r in logged),
            "logger_share": median(r["logger_s"] / r["wall_s"] for r in logged),
        })
    return rows


def bench_logging(quick: bool = False, train: bool = True) -> list[dict]:
    """The rows above; `train=False` leaves out the (slow) training comparison."""
    device = jax.devices()[0].device_kind
    rows = [log_rollout_record(repeats=3 if quick else 5)]
    if train:
        rows += train_records(steps=5_000 if quick else 20_000, repeats=1 if quick else 5)
    return [{"lib": "mjxsuite", **row, "device": device} for row in rows]


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="fewer repeats and a shorter training run")
    parser.add_argument("--json", help="also write the rows to this file")
    args = parser.parse_args(argv)
    rows = bench_logging(args.quick)
    log, *trains = rows
    print(f"log a {log['steps']:,}-step rollout: {log['total_s_min']:.3f} s best, {log['total_s_median']:.3f} s median "
          f"(host copy {log['host_copy_s']:.3f} s; poses {log['poses_mj_kinematics_s']:.3f} s with mj_kinematics, "
          f"{log['poses_mjx_kinematics_warm_s']:.3f} s warm / {log['poses_mjx_kinematics_first_call_s']:.2f} s "
          f"first call with vmapped mjx.kinematics; file {log['file_mb']:.1f} MB)")
    for t in trains:
        print(f"train cartpole {t['steps']:,} steps, Rerun {t['logging']}: {t['median_with_s']:.2f} s vs "
              f"{t['median_without_s']:.2f} s without (medians of {t['repeats']}); "
              f"slowdown {100 * t['slowdown']:+.1f}%, "
              f"CPU time {100 * t['cpu_overhead']:+.1f}%; on the training thread {t['logger_s']:.2f} s "
              f"({100 * t['logger_share']:.1f}%)")
    for row in rows:
        print(json.dumps(row))
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
