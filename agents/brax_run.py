"""Host-side driver of Brax's PPO and SAC (`mjxsuite train --agent ppo|sac`): the same run
directory, progress bar, periodic saves and Rerun logging as DQN's driver (`agents.driver`
holds the steps both take), around one call of Brax's own `train` on `envs.to_brax(env)`.

Brax reports each evaluation through `progress_fn`; PPO hands over the parameters it evaluates
through `policy_params_fn`, SAC writes them to its own checkpoint folder (`checkpoint_logdir`,
a scratch folder in the run directory that is read back and emptied after each evaluation).
Each evaluation becomes a metrics.jsonl record, and, as the save clock says, a checkpoint in
the suite's self-checking format (`agents.checkpoint`): the latest parameters and the best
ones by Brax's deterministic evaluation (the policy `eval`, `rollout` and `load_policy` use).

What `--resume` keeps (Brax's trainers restart only from parameters: `restore_params` for
PPO, `restore_checkpoint_path` for SAC):
- PPO: the observation normalizer, the policy and the value network, the evaluations done
  and the best parameters so far. The rest starts afresh: Adam's moments, the envs' states
  (episodes under way start over) and the random key stream (Brax draws it from the run's
  seed again). The resumed run makes the evaluations that remain, each after as many env
  steps as in an uninterrupted run, so both end at the same env step with the same
  metrics.jsonl steps; their parameters differ.
- SAC: nothing to resume from, with brax 0.14.2: its `restore_checkpoint_path` puts the
  loaded (unreplicated) arrays into its device-replicated training state and fails at its
  first evaluation (`'numpy.ndarray' object has no attribute 'addressable_shards'`), so a
  SAC run with a checkpoint is refused by `--resume` (before anything compiles). Its
  checkpoint still holds the best parameters for `eval`, `rollout` and `load_policy`; a SAC
  run killed before its first checkpoint resumes from the start. The code that would hand
  the parameters over (`_sac_restore_point`) stays for a Brax that restores correctly: the
  policy and normalizer only (Q networks, temperature, optimizers and buffer start afresh).
"""

from __future__ import annotations

import dataclasses
import shutil
import time
from pathlib import Path
from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

import envs
from agents import brax_agents, checkpoint, driver, signals
from agents.brax_agents import PPOConfig, SACConfig
from agents.driver import CHECKPOINT_EVERY, CHECKPOINT_SECONDS
from agents.rollouts import checked_observations

# Whether Brax's SAC restores a checkpoint (see the module docstring): not in brax 0.14.2.
SAC_RESTORES = False
SCRATCH_DIR = "brax_checkpoints"  # SAC's own checkpoints, read back after each evaluation


class BraxState(NamedTuple):
    """What a PPO/SAC checkpoint holds (train_state.msgpack): what a resume restarts from."""

    params: Any  # the latest parameters: PPO (normalizer, policy, value), SAC (normalizer, policy)
    best_params: Any  # the parameters with the best deterministic evaluation so far
    best_return: np.ndarray  # (1,): that evaluation's return (-inf before the first)
    env_steps: np.ndarray  # env steps done at the latest evaluation


@dataclasses.dataclass
class BraxRunResult:
    params: Any  # the best parameters (None if interrupted)
    history: list[dict] = dataclasses.field(default_factory=list)  # one record per evaluation
    mean_return: list[float] = dataclasses.field(default_factory=list)  # our evaluation of `params`, one seed
    solve_step: list[int | None] = dataclasses.field(default_factory=lambda: [None])
    solve_wall_s: list[float | None] = dataclasses.field(default_factory=lambda: [None])
    wall_s: float = 0.0
    compile_s: float = 0.0  # seconds to Brax's first evaluation (compiling its programs)
    interrupted: bool = False  # SIGINT or SIGTERM (see agents.signals)
    stop_signal: str | None = None
    saved_chunks: int | None = None  # evaluations the run directory's checkpoint holds (None: no directory)
    total_chunks: int = 0  # evaluations of the whole run
    chunk_unit: str = "evaluations"
    devices: int = 1
    eval_episodes: int = 0


class _Stop(Exception):
    """Raised from `progress_fn` to end Brax's training early (`stop_after_evals`)."""


def agent_name(config: PPOConfig | SACConfig) -> str:
    return "ppo" if isinstance(config, PPOConfig) else "sac"


def check_continuous(env: envs.Env, env_name: str, agent: str) -> None:
    if env.action_size is None:
        raise ValueError(f"--agent {agent} needs a continuous task; {env_name} is discrete "
                         f"({env.num_actions} actions): train it with --agent dqn")


def train_brax(
    env_name: str,
    config: PPOConfig | SACConfig,
    seed: int = 0,
    out_dir: str | Path | None = None,
    resume: bool = False,
    progress: bool = True,
    env_options: dict | None = None,
    on_eval: Callable[[int, Any, dict], None] | None = None,  # (evaluation index, params, record + "eval_rollout")
    checkpoint_every: int = CHECKPOINT_EVERY,  # evaluations between checkpoints in `out_dir`...
    checkpoint_seconds: float = CHECKPOINT_SECONDS,  # ...and at least these seconds (see driver.SaveClock)
    stop_after_evals: int | None = None,  # end after this many evaluations of this call (tests)
    overwrite: bool = False,  # replace a run that `out_dir` holds (without `resume`); else ValueError
) -> BraxRunResult:
    """Train Brax's PPO or SAC (as `config`'s type says) on `env_name`; the files written to
    `out_dir` are DQN's (docs/training.md). With `resume`, continue the run in `out_dir`
    from its last checkpoint (see the module docstring for what that keeps)."""
    start = time.perf_counter()
    agent = agent_name(config)
    clock = driver.SaveClock(checkpoint_every, checkpoint_seconds)
    run = checkpoint.SavedRun(env_name, 1, config, env_options or {}, seed, None, agent)
    out = driver.open_run_dir(out_dir, run, resume, overwrite=overwrite)
    env = envs.make(env_name, **(env_options or {}))
    check_continuous(env, env_name, agent)
    template = params_template(config, env)
    state = BraxState(template, template, np.full(1, -np.inf, np.float32), np.zeros((), np.int64))
    evals_done = 0  # evaluations recorded in metrics.jsonl, Brax's first (before training) included
    if resume and (out / checkpoint.STATE_FILE).is_file():
        if agent == "sac" and not SAC_RESTORES:
            raise ValueError(f"--resume: {out} holds a SAC checkpoint, and brax 0.14.2's SAC cannot restart from one "
                             "(its restore_checkpoint_path fails: docs/brax.md); its best parameters still work with "
                             f"`mjxsuite eval --checkpoint {out}`; start the run again in a new --out")
        state, evals_done = checkpoint.load_state(out, env_name, jax.eval_shape(lambda s: s, state))
    else:
        state = state._replace(params=None, best_params=None)
        if out is not None:
            checkpoint.start_run(out, run)
    if out is not None:
        checkpoint.keep_metrics(out, evals_done)
    clock.last = evals_done
    epochs_left = config.num_evals - max(evals_done, 1)  # training epochs, one before each later evaluation
    restarting = evals_done > 0
    # Brax counts a resumed run's steps from 0 (SAC's fresh first fill of its buffer included):
    # the run's step is the checkpoint's plus Brax's after that fill.
    step_offset = int(state.env_steps) - config.prefill_steps if restarting else 0

    result = BraxRunResult(params=None, eval_episodes=config.num_eval_envs)
    total = config.prefill_steps + (config.num_evals - 1) * config.steps_per_epoch
    bar = driver.progress_bar(total, int(state.env_steps), env_name, enabled=progress)
    policy = brax_agents.deterministic_policy(config, env.observation_size, env.action_size)
    evaluated = {}  # PPO: the parameters of the evaluation under way, from policy_params_fn

    overflow_told = False

    def progress_fn(brax_step: int, metrics: dict) -> None:
        nonlocal state, evals_done, overflow_told
        if restarting and brax_step == 0:
            return  # Brax re-evaluates the restored parameters first: that record exists already
        steps = step_offset + brax_step
        params = _evaluated_params(config, out, evaluated, brax_step)
        record = {**_record(metrics, evals_done, steps), "wall_s": time.perf_counter() - start}
        overflow_told = _check_overflow(env, record, config.num_eval_envs, bar, overflow_told)
        if params is not None and (state.best_params is None or record["eval_return"] > float(state.best_return[0])):
            state = state._replace(best_params=params, best_return=np.full(1, record["eval_return"], np.float32))
        if params is not None:
            state = state._replace(params=params)
        state = state._replace(env_steps=np.asarray(steps, np.int64))
        best = float(state.best_return[0])
        record["best_return"] = best if np.isfinite(best) else None  # none before the first trained evaluation
        evals_done += 1
        if result.compile_s == 0.0:
            result.compile_s = time.perf_counter() - start
        result.history.append(record)
        if config.solve_return is not None and result.solve_step[0] is None and record["eval_return"] >= config.solve_return:
            result.solve_step, result.solve_wall_s = [steps], [time.perf_counter() - start]
        driver.append_metrics(out, record)
        driver.show(bar, steps - bar.n, record)
        if on_eval is not None:
            episode = (lambda p=state.params: greedy_episode(env, policy, p)) if params is not None else None
            on_eval(evals_done - 1, state.params, {**record, "eval_rollout": episode})
        if out is not None and state.params is not None and clock.due(evals_done):
            save_start = time.perf_counter()
            checkpoint.save_state(out, env_name, state, evals_done)
            clock.saved(evals_done, save_start)
        if stop_after_evals is not None and len(result.history) >= stop_after_evals:
            raise _Stop
        if stop.requested is not None:  # Brax calls progress_fn from its Python loop: raising here is safe
            result.interrupted = True
            raise _Stop

    finished = epochs_left <= 0
    result.total_chunks = config.num_evals
    stop = signals.StopSignals()
    try:
        with stop:  # SIGINT/SIGTERM: stop at Brax's next evaluation, save, return
            if not finished:
                _call_brax(config, env, seed, out, state if restarting else None, epochs_left, progress_fn, evaluated)
                finished = True
    except _Stop:
        pass
    except KeyboardInterrupt:  # only where no handler could be installed (not the main thread)
        result.interrupted = True
    finally:
        bar.close()
        if out is not None:
            shutil.rmtree(out / SCRATCH_DIR, ignore_errors=True)
    # Not after other errors: the last periodic checkpoint stands.
    if out is not None and state.params is not None and clock.last != evals_done:
        checkpoint.save_state(out, env_name, state, evals_done)
        clock.last = evals_done
    result.saved_chunks = clock.last if out is not None else None
    result.interrupted = result.interrupted or stop.requested is not None
    result.stop_signal = stop.name or ("SIGINT" if result.interrupted else None)
    if not finished or result.interrupted:
        return result

    result.params = state.best_params
    returns = evaluate(env, policy, state.best_params, jax.random.fold_in(jax.random.PRNGKey(seed), 1),
                       config.num_eval_envs)
    result.mean_return = [float(np.mean(returns))]
    result.wall_s = time.perf_counter() - start
    driver.write_eval(out, {"env": env_name, "agent": agent, "seeds": 1, "mean_return": result.mean_return,
                            "solve_step": result.solve_step, "solve_wall_s": result.solve_wall_s,
                            "wall_s": result.wall_s, "compile_s": result.compile_s, "devices": 1})
    return result


def _call_brax(config, env, seed, out, restored: BraxState | None, epochs: int, progress_fn, evaluated: dict) -> None:
    """Brax's `train` for `epochs` training epochs (each followed by an evaluation), from the
    restored parameters if given, with epochs as long as an uninterrupted run's."""
    kwargs = brax_agents.trainer_kwargs(config)
    kwargs.update(num_timesteps=config.prefill_steps + epochs * config.steps_per_epoch, num_evals=epochs + 1,
                  seed=seed, progress_fn=progress_fn)
    brax_env = envs.to_brax(env)
    if isinstance(config, PPOConfig):
        kwargs["policy_params_fn"] = lambda step, make_policy, params: evaluated.update(step=step, params=params)
        if restored is not None:
            kwargs["restore_params"] = restored.params
    else:
        kwargs["checkpoint_logdir"] = str(_scratch(out))
        if restored is not None:
            kwargs["restore_checkpoint_path"] = str(_sac_restore_point(config, env, out, restored.params))
    brax_agents.trainer(config)(brax_env, episode_length=brax_env.episode_length, **kwargs)


def _record(metrics: dict, index: int, steps: int) -> dict:
    """A metrics.jsonl record from Brax's evaluation metrics."""
    record = {"evaluation": index, "env_steps": steps, "eval_return": float(metrics["eval/episode_reward"]),
              "eval_return_std": float(metrics.get("eval/episode_reward_std", np.nan))}
    for name, value in metrics.items():
        if name.startswith("training/") and np.ndim(value) == 0:
            record[name.removeprefix("training/")] = float(value)
    record["steps_per_s"] = record.pop("sps", None)
    for buffer in ("contacts", "constraints"):  # MJX tasks (envs.interop.brax): shares of evaluation episodes
        if f"eval/episode_overflow_{buffer}" in metrics:
            record[f"eval_overflow_{buffer}"] = float(metrics[f"eval/episode_overflow_{buffer}"])
    return record


def _check_overflow(env: envs.Env, record: dict, episodes: int, bar, told: bool) -> bool:
    """`driver.check_overflow` for an evaluation's record. Brax's trainers report no overflow of
    their training steps; the evaluation's episodes, run by the policy under training (its
    deterministic actions), stand in for them."""
    count = lambda buffer: round(record.get(f"eval_overflow_{buffer}", 0.0) * episodes)
    return driver.check_overflow(env, count("contacts"), count("constraints"), episodes, "evaluation episodes",
                                 f"evaluation {record['evaluation']}", "each ended its episode with reward 0, in "
                                 "training as in evaluation, where Brax's trainer learns from it", bar, told)


def _scratch(out: Path | None) -> Path:
    if out is None:
        raise ValueError("SAC's parameters reach the driver through Brax's checkpoint folder: give out_dir")
    return out / SCRATCH_DIR


def _evaluated_params(config, out, evaluated: dict, brax_step: int) -> Any:
    """The parameters Brax has just evaluated at `brax_step` (None for its first evaluation,
    before training, whose parameters PPO reports only afterwards and SAC never saves)."""
    if brax_step == 0:
        return None
    if isinstance(config, PPOConfig):
        assert evaluated.get("step") == brax_step, (evaluated.get("step"), brax_step)
        return jax.device_get(evaluated.pop("params"))
    from brax.training import checkpoint as brax_checkpoint

    folder = _scratch(out) / f"{brax_step:012d}"
    params = brax_checkpoint.load(folder)
    shutil.rmtree(_scratch(out), ignore_errors=True)  # one at a time: they would pile up
    return tuple(params)


def _sac_restore_point(config: SACConfig, env: envs.Env, out: Path, params: Any) -> Path:
    """The restored parameters in Brax's SAC checkpoint format (what `restore_checkpoint_path` reads)."""
    from brax.training.agents.sac import checkpoint as sac_checkpoint

    folder = out / SCRATCH_DIR / "restore"
    shutil.rmtree(folder, ignore_errors=True)
    network_config = sac_checkpoint.network_config(env.observation_size, env.action_size,
                                                   config.normalize_observations, brax_agents.network_factory(config))
    sac_checkpoint.save(folder, 0, params, network_config)
    return folder / f"{0:012d}"


def params_template(config: PPOConfig | SACConfig, env: envs.Env) -> Any:
    """Zeros shaped like the parameters Brax returns for `config` on `env`."""
    shapes = brax_agents.params_template(config, env.observation_size, env.action_size)
    return jax.tree.map(lambda s: np.zeros(s.shape, s.dtype), shapes)


# ---- acting and evaluating with the trained policy, in our own env ------------------------
# (envs.recording, which imports rerun, is imported where it is used: `import agents` stays light.)
def greedy_episode(env: envs.Env, policy: Callable, params: Any, key: jax.Array | None = None):
    """One episode of the deterministic policy in `env` (a one-env host `envs.recording.Rollout`), for Rerun."""
    from envs import recording

    steps = env.episode_length
    rollout = recording.collect_rollout(env, policy, jax.random.PRNGKey(0) if key is None else key,
                                        num_envs=1, steps=steps, params=params)
    return jax.device_get(recording.trim_to_episodes(rollout, 1))


def evaluate(env: envs.Env, policy: Callable, params: Any, key: jax.Array, episodes: int) -> np.ndarray:
    """The returns of `episodes` episodes of the deterministic policy in `env` (time limit included)."""
    from envs.rollouts import collect_rollout

    rollout = collect_rollout(env, policy, key, num_envs=episodes, steps=env.episode_length,
                                        params=params, scene_envs=0)
    return first_episode_returns(rollout)


def first_episode_returns(rollout) -> np.ndarray:
    """Each env's first finished episode's return in a rollout at least one time limit long."""
    done = np.asarray(rollout.done) > 0
    first = np.argmax(done, axis=0)
    return np.asarray(rollout.episode_return)[first, np.arange(done.shape[1])]


# ---- loading a saved run -----------------------------------------------------------------
def load_agent(out_dir: str | Path, env: envs.Env | None = None) -> tuple[str, envs.Env, PPOConfig | SACConfig, Any]:
    """`(env_name, env, config, best_params)` of a PPO/SAC run directory (`env`: as `agents.run.load_agent`)."""
    saved = checkpoint.load_config(out_dir)
    env = env or checkpoint.saved_env(out_dir)[1]
    params = checkpoint.load_best_params(out_dir, params_template(saved.config, env))
    return saved.env, env, saved.config, params


def action_bounds(env: envs.Env) -> tuple[np.ndarray, np.ndarray]:
    """Gymnasium's action space of `env` (`Env.action_low`/`action_high`: for an MJX task each
    actuator's ctrlrange, which `MjxEnv.action_to_ctrl` scales [-1, 1] to)."""
    return np.asarray(env.action_low, np.float32), np.asarray(env.action_high, np.float32)


def to_action_space(action: jax.Array, low: np.ndarray, high: np.ndarray) -> jax.Array:
    """A policy action in [-1, 1] as the control the task applies: `MjxEnv.action_to_ctrl`'s
    arithmetic (centre + a * half-range), so the two agree to the bit."""
    return 0.5 * (high + low) + jnp.clip(action, -1.0, 1.0) * 0.5 * (high - low)


def load_policy(out_dir: str | Path) -> Callable[[np.ndarray], np.ndarray]:
    """The deterministic policy of a PPO/SAC run: `policy(obs) -> action` in the task's
    Gymnasium action space (one observation or a batch, numpy in, float32 numpy out)."""
    env_name, env, config, params = load_agent(out_dir)
    act = brax_agents.deterministic_policy(config, env.observation_size, env.action_size)
    low, high = action_bounds(env)
    key = jax.random.PRNGKey(0)
    mapped = jax.jit(lambda obs: to_action_space(act(params, obs, key), low, high))

    def policy(obs):
        obs = checked_observations(obs, env_name, env.observation_size)
        return np.asarray(mapped(obs), np.float32)

    return policy
