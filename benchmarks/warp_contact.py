"""MuJoCo Warp on a contact model (issue #26): does it follow JAX, does an undersized buffer show,
how fast is it, and does Brax's PPO learn the same on it.

The contact task is Gymnasium's half_cheetah.xml (`benchmarks.contact_task`; the suite's
`half-cheetah` where registered). On a GPU with warp-lang (`pip install 'mjxsuite[warp]'`):

(a) `impl="warp"` against `impl="jax"`: `--envs` envs, `--steps` steps (5 physics steps each) of
    the same random actions from the same starts at the default buffer sizes: the max abs
    difference of qpos and qvel (over all envs, and the median env's), Warp's overflow count, and
    for the first 16 envs both implementations against C MuJoCo (float64) from the same start
    (contact dynamics under random actions amplify float32 rounding: that gap is the tolerance).
(b) the same run with a contact pool of one contact per env (`nconmax=1`): flagged steps.
(c) physics steps/s (env-steps/s times substeps) of `cartpole-mjx` and the contact task, JAX and
    Warp, at `--sizes` envs (random actions, auto-reset), with compile (XLA) and first-call
    (Warp's kernels too) seconds.
(d) Brax PPO (`brax.training.agents.ppo.train` on `envs.to_brax`) on the contact task with each
    implementation: final eval return and wall time.

    python -m benchmarks.warp_contact [--parts abcd] [--sizes 4096 32768 131072] [--ppo-steps 3000000] [--json FILE]

On the CPU it runs at tiny sizes as a smoke test (`--envs 4 --steps 3 --sizes 4 --ppo-steps 0`);
without a CUDA GPU (or warp-lang) the Warp rows say why they were skipped.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

import envs
from benchmarks.contact_task import contact_task_name
from benchmarks.env_throughput import device_name, time_side_by_side
from agents.env_options import parse_option

IMPLS = ("jax", "warp")
C_CHECKED = 16  # envs compared with C MuJoCo in (a)


def warp_missing() -> str | None:
    """Why `impl="warp"` cannot run here, or None."""
    try:
        envs.make("cartpole-mjx", impl="warp")
    except RuntimeError as err:
        return str(err)
    return None


def trajectory(env_name: str, num_envs: int, steps: int, **overrides):
    """Starts, actions and per-step (qpos|qvel, info["overflow"], done) of `num_envs` envs without
    auto-reset, under random actions; all on the host."""
    env = envs.VmapWrapper(envs.make(env_name, **overrides), num_envs)
    actions = jax.random.uniform(jax.random.PRNGKey(1), (steps, num_envs, env.action_size), minval=-1, maxval=1)

    def run(key):
        start = env.reset(key)

        def body(state, action):
            state = env.step(state, action)
            physics = jnp.concatenate([state.pipeline_state.qpos, state.pipeline_state.qvel], -1)
            return state, (physics, state.info["overflow"], state.done)

        first = jnp.concatenate([start.pipeline_state.qpos, start.pipeline_state.qvel], -1)
        return first, jax.lax.scan(body, start, actions)[1]

    first, (physics, overflow, done) = jax.jit(run)(jax.random.PRNGKey(0))
    return np.asarray(first), np.asarray(actions), np.asarray(physics), np.asarray(overflow), np.asarray(done)


def c_mujoco(task, first: np.ndarray, actions: np.ndarray) -> np.ndarray:
    """C MuJoCo (float64) from the same starts under the same actions: (steps, envs, nq + nv)."""
    model, nq = task.mj_model, task.mj_model.nq
    out = np.zeros((actions.shape[0], first.shape[0], first.shape[1]))
    for i in range(first.shape[0]):
        data = mujoco.MjData(model)
        data.qpos[:], data.qvel[:] = first[i, :nq], first[i, nq:]
        for t in range(actions.shape[0]):
            data.ctrl[:] = np.asarray(task.action_to_ctrl(jnp.asarray(actions[t, i])))
            for _ in range(task.n_substeps):
                mujoco.mj_step(model, data)
            out[t, i] = np.concatenate([data.qpos, data.qvel])
    return out


def follows(num_envs: int, steps: int, missing: str | None) -> list[dict]:
    """(a) and (b)."""
    name = contact_task_name()
    record = {"env": name, "num_envs": num_envs, "steps": steps, "device": device_name()}
    if missing:
        return [{"kind": "warp-contact-vs-jax", **record, "skipped": missing},
                {"kind": "warp-contact-undersized", **record, "skipped": missing}]
    task = envs.make(name, impl="warp").unwrapped
    first, actions, reference, _, _ = trajectory(name, num_envs, steps)
    first_warp, _, warp, overflow, _ = trajectory(name, num_envs, steps, impl="warp")
    assert np.array_equal(first, first_warp), "both implementations start from the same states"
    per_env = np.abs(warp - reference).max(axis=(0, 2))
    checked = min(C_CHECKED, num_envs)
    c = c_mujoco(task, first[:checked], actions[:, :checked])
    found = [{"kind": "warp-contact-vs-jax", **record, "nconmax": task.warp_buffers.nconmax,
              "njmax": task.warp_buffers.njmax, "max_abs_diff": float(per_env.max()),
              "median_env_max_abs_diff": float(np.median(per_env)),
              "max_abs_diff_qpos": float(np.abs(warp - reference)[..., :task.mj_model.nq].max()),
              "overflow_steps": int((overflow > 0).sum()),
              "c_mujoco_envs": checked,
              "jax_vs_c_max_abs_diff": float(np.abs(reference[:, :checked] - c).max()),
              "warp_vs_c_max_abs_diff": float(np.abs(warp[:, :checked] - c).max())}]
    overflow, done = trajectory(name, num_envs, steps, impl="warp", nconmax=1)[3:]
    flagged = overflow > 0
    found.append({"kind": "warp-contact-undersized", **record, "nconmax": 1,
                  "flagged_steps": int(flagged.sum()), "env_steps": int(flagged.size),
                  "flagged_steps_that_ended_the_episode": int((done[flagged] == 1).sum())})
    return found


def rollout(env_name: str, num_envs: int, steps: int, impl: str):
    """`run(key)`: `steps` steps of `num_envs` auto-resetting envs under random actions."""
    base = envs.make(env_name, impl=impl)
    env = envs.wrap_for_training(base, num_envs, episode_stats=False)

    def random_action(key):
        if env.action_size is None:
            return jax.random.randint(key, (num_envs,), 0, env.num_actions)
        return jax.random.uniform(key, (num_envs, env.action_size), minval=-1, maxval=1)

    def body(carry, _):
        state, key, total, overflows = carry
        key, action_key = jax.random.split(key)
        state = env.step(state, random_action(action_key))
        overflowed = (state.info.get("overflow", jnp.zeros_like(state.reward)) > 0).sum()
        return (state, key, total + state.reward.sum(), overflows + overflowed), None

    @jax.jit
    def run(key):
        key, reset_key = jax.random.split(key)
        start = (env.reset(reset_key), key, jnp.zeros(()), jnp.zeros((), jnp.int32))
        (state, _, total, overflows), _ = jax.lax.scan(body, start, None, steps)
        return total, overflows, state.pipeline_state.qpos  # the qpos keeps the physics from being dropped

    return run, base.unwrapped.n_substeps


def throughput(sizes: list[int], steps: int | None, repeats: int, missing: str | None) -> list[dict]:
    """(c)."""
    found = []
    for num_envs in sizes:
        n_steps = steps or max(10, min(1000, 2**20 // num_envs))  # ~1M env-steps a run: seconds for JAX's contacts
        for env_name in ("cartpole-mjx", contact_task_name()):
            for impl in IMPLS:
                record = {"kind": "warp-contact-throughput", "env": env_name, "impl": impl, "num_envs": num_envs,
                          "steps": n_steps, "device": device_name()}
                if impl == "warp" and missing:
                    found.append({**record, "skipped": missing})
                    continue
                run, substeps = rollout(env_name, num_envs, n_steps, impl)
                key = jax.random.PRNGKey(0)
                start = time.perf_counter()
                compiled = run.lower(key).compile()
                compile_s = time.perf_counter() - start
                _, overflows, _ = jax.block_until_ready(compiled(key))  # Warp builds its kernels on the first call
                first_call_s = time.perf_counter() - start
                seconds = statistics.median(time_side_by_side([compiled], repeats)[0])
                env_steps = num_envs * n_steps / seconds
                found.append({**record, "substeps": substeps, "compile_s": compile_s, "first_call_s": first_call_s,
                              "env_steps_per_s": env_steps, "physics_steps_per_s": env_steps * substeps,
                              "overflow_steps": int(overflows)})  # env-steps of the first call that overflowed
    return found


def ppo(num_timesteps: int, num_envs: int, impls: list[str], opt: dict, missing: str | None):
    """(d): Brax PPO with Brax's MuJoCo-locomotion settings (as MuJoCo Playground's for cheetah),
    one record per implementation, yielded as each run ends (a run cut short keeps the ones before),
    every evaluation printed as it comes with the wall time since the run began."""
    if num_timesteps <= 0:
        return
    from brax.training.agents.ppo import train as ppo_train

    for impl in impls:
        record = {"kind": "warp-contact-ppo", "env": contact_task_name(), "impl": impl, "num_timesteps": num_timesteps,
                  "num_envs": num_envs, "opt": opt, "device": device_name()}
        if impl == "warp" and missing:
            yield {**record, "skipped": missing}
            continue
        env = envs.to_brax(contact_task_name(), impl=impl, **({"opt": opt} if opt else {}))
        evals = []
        start = time.perf_counter()

        def progress(step, metrics, impl=impl, evals=evals, start=start):
            evals.append((int(step), float(metrics["eval/episode_reward"]), time.perf_counter() - start))
            print(f"  ppo {impl}: step {evals[-1][0]:>9,}  eval return {evals[-1][1]:9.1f}  {evals[-1][2]:6.1f} s",
                  flush=True)

        ppo_train.train(environment=env, num_timesteps=num_timesteps, episode_length=env.episode_length,
                        num_envs=num_envs, batch_size=min(512, num_envs), num_minibatches=32 if num_envs >= 512 else 4,
                        unroll_length=20, num_updates_per_batch=8, learning_rate=3e-4, entropy_cost=1e-3,
                        discounting=0.95, reward_scaling=1.0, normalize_observations=True, action_repeat=1,
                        num_evals=5, num_eval_envs=min(128, num_envs), seed=0, progress_fn=progress)
        yield {**record, "eval_return": evals[-1][1], "evals": evals, "wall_s": time.perf_counter() - start,
               "first_eval_s": evals[0][2]}


def table(found: list[dict]) -> str:
    lines = []
    for r in found:
        if "skipped" in r:
            lines.append(f"{r['kind']:<26} {r.get('env', '')} {r.get('impl', '')}: skipped")
        elif r["kind"] == "warp-contact-vs-jax":
            lines.append(f"(a) {r['env']} {r['num_envs']} envs x {r['steps']} steps, nconmax={r['nconmax']} "
                         f"njmax={r['njmax']}: max |warp - jax| {r['max_abs_diff']:.2e} (qpos {r['max_abs_diff_qpos']:.2e}, "
                         f"median env {r['median_env_max_abs_diff']:.2e}), overflow steps {r['overflow_steps']}; "
                         f"{r['c_mujoco_envs']} envs vs C MuJoCo: jax {r['jax_vs_c_max_abs_diff']:.2e}, "
                         f"warp {r['warp_vs_c_max_abs_diff']:.2e}")
        elif r["kind"] == "warp-contact-undersized":
            lines.append(f"(b) nconmax=1: {r['flagged_steps']} of {r['env_steps']} env-steps flagged, "
                         f"{r['flagged_steps_that_ended_the_episode']} of them ended their episode")
        elif r["kind"] == "warp-contact-throughput":
            lines.append(f"(c) {r['env']:<20} {r['impl']:<5} {r['num_envs']:>8} envs  "
                         f"{r['physics_steps_per_s']:.3g} physics steps/s  compile {r['compile_s']:.1f} s, "
                         f"first call {r['first_call_s']:.1f} s, overflow steps {r['overflow_steps']}")
        elif r["kind"] == "warp-contact-ppo":
            lines.append(f"(d) PPO {r['impl']:<5} {r['num_timesteps']:,} steps: eval return {r['eval_return']:.1f} "
                         f"in {r['wall_s']:.0f} s")
    return "\n".join(lines)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.warp_contact", description=__doc__.splitlines()[0])
    parser.add_argument("--envs", type=int, default=4096, help="envs of (a) and (b)")
    parser.add_argument("--steps", type=int, default=100, help="env steps of (a) and (b)")
    parser.add_argument("--sizes", type=int, nargs="+", default=[4096, 32768, 131072], help="batch sizes of (c)")
    parser.add_argument("--scan-steps", type=int, help="scan length per timed run of (c) (default: by batch size)")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--parts", default="abcd", help="which of (a)+(b) 'ab', (c) 'c', (d) 'd' to run, e.g. --parts abc")
    parser.add_argument("--ppo-steps", type=int, default=3_000_000, help="env steps of each PPO run in (d); 0: skip")
    parser.add_argument("--ppo-envs", type=int, default=2048)
    parser.add_argument("--ppo-impls", nargs="+", choices=IMPLS, default=list(IMPLS), help="PPO runs of (d), in order")
    parser.add_argument("--ppo-opt", nargs="*", default=[], metavar="FIELD=VALUE",
                        help="MuJoCo solver options of the PPO task, e.g. iterations=4 ls_iterations=8")
    parser.add_argument("--json", metavar="FILE", help="write the records as JSON")
    args = parser.parse_args(argv)
    missing = warp_missing()
    ppo_opt = {field: parse_option(contact_task_name(), f"opt.{field}", text)
               for field, _, text in (pair.partition("=") for pair in args.ppo_opt)}
    parts = [(lambda: follows(args.envs, args.steps, missing)) if "a" in args.parts or "b" in args.parts else None,
             (lambda: throughput(args.sizes, args.scan_steps, args.repeats, missing)) if "c" in args.parts else None,
             (lambda: ppo(args.ppo_steps, args.ppo_envs, args.ppo_impls, ppo_opt, missing)) if "d" in args.parts else None]
    print(f"device: {device_name()}", flush=True)
    found = []
    # Printed and written part by part: a run cut short (a device call's time limit) keeps what it measured.
    for part in filter(None, parts):
        records = []
        for record in part():  # (d) yields its records one run at a time
            records.append(record)
            found.append(record)
            if args.json:
                with open(args.json, "w") as f:
                    json.dump(found, f, indent=2)
        print(table(records), flush=True)


if __name__ == "__main__":
    main()
