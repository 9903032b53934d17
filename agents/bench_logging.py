"""What Rerun logging costs.

    python -m agents.bench_logging [--quick] [--json FILE]

Rows:
- `log-rollout`: logging a 100,000-step CartPole rollout of one env to a fresh .rrd:
  the host copy, the geom poses (C MuJoCo `mj_kinematics`), `send_columns` and the
  file save (stream closed, footer written); collecting the rollout is excluded.
  The alternative for the poses, a vmapped `mjx.kinematics`, is timed beside it.
- `train-rerun`: `train_run` on cartpole with and without a `TrainingLogger`
  (curves + a greedy evaluation rollout after every chunk), same config and seed,
  runs alternated; `slowdown` is the ratio of the median wall times minus 1, and
  `logger_share` the fraction of the run spent inside the callback (a steadier
  figure on a shared machine, but it misses the overlapped compile of the rollout).
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
from agents.recording import TrainingLogger
from agents.run import train_run
from envs import recording


def _timed(fn) -> float:
    start = time.perf_counter()
    fn()
    return time.perf_counter() - start


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
        "kind": "log-rollout", "steps": steps, "envs": 1, "repeats": repeats,
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


def train_record(steps: int = 20_000, pairs: int = 3) -> dict:
    config = DQNConfig(total_steps=steps)
    plain, logged, in_callback = [], [], []
    with tempfile.TemporaryDirectory() as tmp:
        def without():
            train_run("cartpole", config, progress=False)

        def with_rerun():
            logger = TrainingLogger(Path(tmp) / "train.rrd", "cartpole", config, overwrite=True)
            spent = []

            def on_chunk(index, train_state, record):
                spent.append(_timed(lambda: logger(index, train_state, record)))

            try:
                train_run("cartpole", config, progress=False, on_chunk=on_chunk)
            finally:
                spent.append(_timed(logger.close))
                in_callback.append(sum(spent))

        for _ in range(pairs):  # alternate, so load from elsewhere on the machine hits both alike
            plain.append(_timed(without))
            logged.append(_timed(with_rerun))
    base, with_log = statistics.median(plain), statistics.median(logged)
    return {
        "kind": "train-rerun", "env": "cartpole", "steps": steps, "seeds": 1, "pairs": pairs,
        "rollout_every_chunks": 1, "chunks": config.num_chunks,
        "wall_s_without": plain, "wall_s_with": logged,
        "median_without_s": base, "median_with_s": with_log, "slowdown": with_log / base - 1.0,
        "logger_s": in_callback,  # time inside the callback and close(): what logging adds on the main thread
        "logger_share": statistics.median(c / w for c, w in zip(in_callback, logged)),
    }


def bench_logging(quick: bool = False) -> list[dict]:
    device = jax.devices()[0].device_kind
    rows = [log_rollout_record(repeats=3 if quick else 5), train_record(steps=5_000 if quick else 20_000,
                                                                      pairs=1 if quick else 5)]
    return [{**row, "device": device} for row in rows]


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="fewer repeats and a shorter training run")
    parser.add_argument("--json", help="also write the rows to this file")
    args = parser.parse_args(argv)
    rows = bench_logging(args.quick)
    log, train = rows
    print(f"log a {log['steps']:,}-step rollout: {log['total_s_min']:.3f} s best, {log['total_s_median']:.3f} s median "
          f"(host copy {log['host_copy_s']:.3f} s, poses {log['poses_mj_kinematics_s']:.3f} s with mj_kinematics vs "
          f"{log['poses_mjx_kinematics_warm_s']:.3f} s warm / {log['poses_mjx_kinematics_first_call_s']:.2f} s first call "
          f"with vmapped mjx.kinematics; file {log['file_mb']:.1f} MB)")
    print(f"train cartpole {train['steps']:,} steps: {train['median_without_s']:.2f} s without Rerun, "
          f"{train['median_with_s']:.2f} s with (median of {train['pairs']}); slowdown {100 * train['slowdown']:+.1f}%; "
          f"time in the logger {statistics.median(train['logger_s']):.2f} s = {100 * train['logger_share']:.1f}% of the run")
    for row in rows:
        print(json.dumps(row))
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
