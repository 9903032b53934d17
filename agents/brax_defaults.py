"""Per-task settings of PPO, SAC and TD3: the one table `mjxsuite train --agent ppo|sac|td3` reads.

`SETTINGS[task][agent][preset]` holds the fields that differ from the agent's base recipe
(`PPOConfig()` in `agents/ppo.py`, `SACConfig()` in `agents/sac.py`, `TD3Config()` in `agents/td3.py`,
sized for small tasks on a CPU);
`--FIELD VALUE` options then change the result. A task without a row trains with the base
recipe. Gymnasium's MuJoCo tasks also have "cpu", their row resized for a CPU (`cpu_settings`). Rows are keyed by name only, so a row for a task that is not registered (yet) costs
nothing and breaks nothing. `--preset NAME` picks a recipe other than "default"; without it a
run on camera images (`--env-opt observation=pixels`) takes the task's "pixels" recipe where it
has one (`default_preset`), and the task's `PIXEL_ENV_OPTIONS` (e.g. `frame_stack`) where
`--env-opt` does not give them (`pixel_env_options`).

Where each row comes from:
- "measured here": run with `mjxsuite train` on a CPU; docs/agents.md has the results.
- "Brax notebook": the settings of Brax's training notebook (google/brax,
  notebooks/training.ipynb) for its look-alike of the Gymnasium task (same robot, its own
  MJCF and reward), as published; sized for an accelerator (thousands of envs).
- "Playground": MuJoCo Playground's `dm_control_suite_params.py` (`brax_ppo_config`,
  `brax_sac_config`, `brax_vision_ppo_config`) for the dm_control look-alike; every dmc-* task's
  rows (`_DMC_TASKS`) are Playground's recipe for its look-alike of that task (quadruped and fish
  upright, which Playground lacks: its base recipes).
- "FastTD3": FastTD3's hyperparams.py (`_FASTTD3`), for a GPU.
Rows run on a GPU (`python -m benchmarks.gym_training`) say "run"; docs/agents.md, "Per-task
recipes", has each run (machine, time, steps, score on Gymnasium's env; records "gym-training" in
docs/bench-gpu.json). The others have not been run here on the Gymnasium tasks: treat them as
starting points.
"""

from __future__ import annotations

from typing import Any

# Brax's notebook recipe for its inverted pendulums and ant (PPO), shared by three rows.
_BRAX_NOTEBOOK_PENDULUMS = dict(num_evals=20, reward_scaling=10.0, unroll_length=5, num_minibatches=32,
                                num_updates_per_batch=4, discounting=0.97, learning_rate=3e-4, entropy_cost=1e-2,
                                num_envs=2048, batch_size=1024)
# Playground's dm_control PPO recipe (60M steps over 2048 envs) and SAC recipe. Playground's
# num_resets_per_eval=10 is left out: our envs draw a fresh episode at every auto-reset already.
_PLAYGROUND_PPO = dict(num_timesteps=60_000_000, num_evals=10, reward_scaling=10.0, unroll_length=30,
                       num_minibatches=32, num_updates_per_batch=16, discounting=0.995, learning_rate=1e-3,
                       entropy_cost=1e-2, num_envs=2048, batch_size=1024)
# The cart-pole's recipe from camera images, for one GPU: the base recipe (the config's defaults)
# with 256 envs and batches of 256, the one that learned balance and swing-up from 64x64 pixels
# with `PIXEL_ENV_OPTIONS` (docs/agents.md, "PPO from pixels"; docs/bench-gpu.json records
# "pixels-training"). MuJoCo Playground's vision recipe (1,024 envs, reward scaling 0.1, discount
# 0.97) stayed at the zero-force level, with one frame and with three.
_PIXEL_PPO = dict(num_envs=256, batch_size=256)
# The env options a run on camera images takes by default, per task (`pixel_env_options`). Three
# frames, as Playground's vision CartpoleBalance stacks: one frame shows where the pole and cart
# are but not how fast they move. Four task steps per env step (dm_control's pixel benchmarks
# repeat actions too): three frames 10 ms apart move the 1-2 px pole by hundredths of a pixel, and
# no recipe balanced from them (docs/agents.md); 40 ms apart they show its velocity. The episode
# keeps its 10 s (250 env steps, `envs.make`).
PIXEL_ENV_OPTIONS: dict[str, dict[str, Any]] = {
    "cartpole-balance-mjx": {"frame_stack": 3, "action_repeat": 4},
    "cartpole-swingup-mjx": {"frame_stack": 3, "action_repeat": 4},
}
_PLAYGROUND_SAC = dict(num_timesteps=5_000_000, num_evals=10, discounting=0.99, learning_rate=1e-3, num_envs=128,
                       batch_size=512, grad_updates_per_step=8, max_replay_size=4 * 1048576, min_replay_size=8192)
# FastTD3's recipe (github.com/younggyoseo/FastTD3, fast_td3/hyperparams.py at commit 229ed59):
# BaseArgs (its HumanoidBench defaults: discount 0.99, batches of 32,768, 2 updates per env step,
# an actor update every 2, tau 0.1, AdamW with weight decay 0.1, noise std in [0.001, 0.4], smoothing
# 0.001, 101 atoms, networks 512 / 1024 wide, bf16 AMP) with MuJoCoPlaygroundArgs' 1,024 envs; its
# learning_starts (10 env-step batches) as min_replay_size. Ours: a replay of 1M transitions per seed
# (FastTD3 keeps 10,240 steps of each of 1,024 envs; several seeds share one GPU here), the critic's
# support per task (below: about the task's per-step reward bound over 1 - discount, as FastTD3's
# v_min/v_max bound its tasks' returns) and the run's length. Not run yet: starting points.
_FASTTD3 = dict(num_envs=1024, batch_size=32768, num_updates=2, policy_frequency=2, actor_learning_rate=3e-4,
                critic_learning_rate=3e-4, weight_decay=0.1, discounting=0.99, tau=0.1, policy_noise=0.001,
                noise_clip=0.5, std_min=0.001, std_max=0.4, num_atoms=101, init_scale=0.01,
                actor_hidden=(512, 256, 128), critic_hidden=(1024, 512, 256), compute_dtype="bfloat16",
                min_replay_size=10 * 1024, max_replay_size=1 << 20, num_evals=11)
# The agent `mjxsuite train` picks on a continuous task without --agent: "ppo" unless a row here
# says otherwise: on half-cheetah, walker2d and swimmer SAC's row beat Gymnasium's goal where PPO's
# fell far short or was not needed (docs/agents.md, "Per-task recipes").
DEFAULT_AGENT: dict[str, str] = {"half-cheetah": "sac", "walker2d": "sac", "swimmer": "sac"}

SETTINGS: dict[str, dict[str, dict[str, dict[str, Any]]]] = {
    # Gymnasium's Pendulum-v1 (solved at -200). Measured here.
    "pendulum-mjx": {
        "ppo": {"default": dict(num_timesteps=1_500_000, discounting=0.95, reward_scaling=0.1, solve_return=-200.0)},
        "sac": {"default": dict(num_timesteps=30_000, num_evals=4, solve_return=-200.0)},
        # TD3: the base recipe, rewards scaled into the critic's support (returns of -1,600 to 0)
        "td3": {"default": dict(num_timesteps=20_000, num_evals=4, reward_scaling=0.1, v_min=-200.0, v_max=50.0,
                                solve_return=-200.0)},
    },
    # dm_control's cartpole swing-up. default: measured here (SAC learns it in 100k steps on a
    # CPU; PPO needs an accelerator's budget). playground: Playground's recipe, for a GPU. pixels:
    # from camera images, for a GPU (`_PIXEL_PPO`).
    "cartpole-swingup-mjx": {
        "ppo": {"default": dict(num_timesteps=5_000_000, num_envs=256, batch_size=256, num_minibatches=16,
                                learning_rate=3e-4, discounting=0.99, entropy_cost=1e-2, solve_return=800.0),
                "playground": dict(_PLAYGROUND_PPO, solve_return=800.0),
                "pixels": dict(_PIXEL_PPO, num_timesteps=11_000_000, num_evals=8, solve_return=800.0)},
        "sac": {"default": dict(num_timesteps=100_000, hidden=(128, 128), solve_return=800.0),
                "playground": dict(_PLAYGROUND_SAC, solve_return=800.0)},
    },
    # dm_control's cartpole balance. default: the base recipe. pixels: from camera images, for a
    # GPU (`_PIXEL_PPO`).
    "cartpole-balance-mjx": {
        "ppo": {"default": {}, "pixels": dict(_PIXEL_PPO, num_timesteps=8_000_000, num_evals=15)},
    },
    # Gymnasium's MuJoCo tasks (v5). Brax notebook rows; SAC rows from Playground's SAC recipe.
    # default: the base recipe (64 envs), measured here: it solves Gymnasium's InvertedPendulum-v5 on
    # a CPU. brax-notebook: Brax's GPU recipe (2,048 envs).
    "inverted-pendulum": {
        "ppo": {"default": dict(num_timesteps=300_000, num_evals=7, solve_return=950.0),
                "brax-notebook": dict(_BRAX_NOTEBOOK_PENDULUMS, num_timesteps=2_000_000, solve_return=950.0)},
        "sac": {"default": dict(_PLAYGROUND_SAC, num_timesteps=1_000_000, solve_return=950.0)},
    },
    "inverted-double-pendulum": {  # PPO run, impl="warp"
        "ppo": {"default": dict(_BRAX_NOTEBOOK_PENDULUMS, num_timesteps=20_000_000, solve_return=9100.0)},
        "sac": {"default": dict(_PLAYGROUND_SAC, solve_return=9100.0)},
    },
    "ant": {  # PPO run, impl="warp"
        "ppo": {"default": dict(_BRAX_NOTEBOOK_PENDULUMS, num_timesteps=50_000_000, num_evals=10, num_envs=4096,
                                batch_size=2048, solve_return=6000.0)},
        "sac": {"default": dict(_PLAYGROUND_SAC, solve_return=6000.0)},
        "td3": {"default": dict(_FASTTD3, num_timesteps=15_360_000, v_min=-300.0, v_max=800.0, solve_return=6000.0)},
    },
    "humanoid": {  # PPO run, impl="warp"; SAC run once, a starting point.
        # PPO: Brax's training notebook recipe for its humanoid look-alike (google/brax
        # notebooks/training.ipynb, train_fn['humanoid'], read at commit 0b96d05: 50M steps,
        # reward_scaling 0.1, unroll 10, 8 updates per batch, entropy 1e-3, 2,048 envs); SAC: Playground's
        "ppo": {"default": dict(num_timesteps=50_000_000, num_evals=10, reward_scaling=0.1, unroll_length=10,
                                num_minibatches=32, num_updates_per_batch=8, discounting=0.97, learning_rate=3e-4,
                                entropy_cost=1e-3, num_envs=2048, batch_size=1024)},
        "sac": {"default": dict(_PLAYGROUND_SAC)},
        "td3": {"default": dict(_FASTTD3, num_timesteps=20_480_000, v_min=-100.0, v_max=1200.0)},
    },
    "half-cheetah": {  # SAC run, impl="warp"; PPO's row fell far short of Gymnasium's goal
        "ppo": {"default": dict(num_timesteps=50_000_000, num_evals=20, reward_scaling=1.0, unroll_length=20,
                                num_minibatches=32, num_updates_per_batch=8, discounting=0.95, learning_rate=3e-4,
                                entropy_cost=1e-3, num_envs=2048, batch_size=512, solve_return=4800.0)},
        "sac": {"default": dict(_PLAYGROUND_SAC, solve_return=4800.0)},
        "td3": {"default": dict(_FASTTD3, num_timesteps=15_360_000, v_min=-300.0, v_max=1500.0, solve_return=4800.0)},
    },
    "hopper": {  # Brax's notebook trains its hopper with SAC. PPO: Playground's recipe with the discount 0.99,
        # where its 0.995 left some seeds standing still (docs/agents.md, "GPU results")
        "ppo": {"default": dict(_PLAYGROUND_PPO, discounting=0.99, solve_return=3800.0)},
        "sac": {"default": dict(num_timesteps=6_553_600, num_evals=20, reward_scaling=30.0, discounting=0.997,
                                learning_rate=6e-4, num_envs=128, batch_size=512, grad_updates_per_step=64,
                                max_replay_size=1048576, min_replay_size=8192, solve_return=3800.0)},
        # TD3: FastTD3's recipe with a quarter of its envs per seed, so that eight seeds fit issue 65's ten
        # minutes on one GPU with impl="jax": acting, not learning, is the larger part of a chunk at 1,024
        # envs (record "td3-speed"); fewer envs keep every update. Not trained yet: a starting point.
        "td3": {"default": dict(_FASTTD3, num_envs=256, min_replay_size=10 * 256, num_timesteps=1_843_200,
                                v_min=-100.0, v_max=500.0, solve_return=3800.0)},
    },
    "walker2d": {  # SAC run, impl="warp"
        "ppo": {"default": dict(num_timesteps=7_864_320, num_evals=20, reward_scaling=5.0, unroll_length=20,
                                num_minibatches=32, num_updates_per_batch=8, discounting=0.97, learning_rate=6e-4,
                                entropy_cost=1e-2, num_envs=128, batch_size=128)},
        "sac": {"default": dict(_PLAYGROUND_SAC)},
        "td3": {"default": dict(_FASTTD3, num_timesteps=15_360_000, v_min=-100.0, v_max=700.0)},
    },
    "reacher": {  # PPO run, impl="warp". Brax's notebook also repeats
        # each action 4 times (not offered here)
        "ppo": {"default": dict(num_timesteps=50_000_000, num_evals=20, reward_scaling=5.0, unroll_length=50,
                                num_minibatches=32, num_updates_per_batch=8, discounting=0.95, learning_rate=3e-4,
                                entropy_cost=1e-3, num_envs=2048, batch_size=256, solve_return=-3.75)},
        "sac": {"default": dict(_PLAYGROUND_SAC, solve_return=-3.75)},
    },
    "pusher": {  # Starting points, PPO and SAC run once each (impl="warp").
        # PPO: Brax's notebook recipe for its pusher (Brax trains 1000-step episodes, Pusher-v5 truncates at 100).
        # Pusher-v5's reward_threshold is 0 (its returns are negative); no solve_return until measured
        "ppo": {"default": dict(num_timesteps=50_000_000, num_evals=20, reward_scaling=5.0, unroll_length=30,
                                num_minibatches=16, num_updates_per_batch=8, discounting=0.95, learning_rate=3e-4,
                                entropy_cost=1e-2, num_envs=2048, batch_size=512)},
        "sac": {"default": dict(_PLAYGROUND_SAC)},
    },
    "swimmer": {  # SAC run, impl="warp", discounting 0.9999 (as the SB3 zoo trains Swimmer). PPO
        # (Playground's recipe, or SB3-like) stayed far below Gymnasium's goal
        "ppo": {"default": dict(_PLAYGROUND_PPO, num_timesteps=100_000_000, solve_return=360.0)},
        "sac": {"default": dict(num_timesteps=480_000, num_evals=4, discounting=0.9999, learning_rate=3e-4,
                                num_envs=32, batch_size=256, grad_updates_per_step=32, hidden=(256, 256),
                                min_replay_size=10_000, solve_return=360.0)},
    },
}

# The DeepMind Control Suite's tasks (dmc-*): MuJoCo Playground's recipes for its look-alikes of
# them (google-deepmind/mujoco_playground, mujoco_playground/config/dm_control_suite_params.py at
# commit 0b06a59; Playground's envs differ from dm_control's, docs/tasks.md). PPO: `brax_ppo_config`
# with Brax's default PPO networks, which Playground's training script builds for it (policy 4 x 32,
# value 5 x 256); SAC: `brax_sac_config` with Brax's default SAC networks (2 x 256). Left out:
# num_resets_per_eval (our envs draw a fresh episode at every auto-reset), PendulumSwingup's PPO
# action_repeat 4 (an env option here, not a recipe field; its num_updates_per_batch 4 is kept) and
# SAC's q_network_layer_norm (our SAC has none). Playground's SAC exception for "PendulumSwingUp"
# matches none of its registered names (it registers "PendulumSwingup"), so pendulum's SAC keeps the
# base 5M steps, as it does in Playground. solve_return: the goal where it sets one (the
# median of 4 seeds on dm_control's own env: 900, or 700). Not run on dm_control's tasks yet unless
# docs/tasks.md's training table shows a run: starting points.
_DMC_PPO = dict(_PLAYGROUND_PPO, policy_hidden=(32,) * 4, value_hidden=(256,) * 5)
_DMC_SAC = dict(_PLAYGROUND_SAC, hidden=(256, 256))
# task: (PPO's fields over _DMC_PPO, SAC's over _DMC_SAC, the goal or None), Playground's exceptions.
_DMC_TASKS: dict[str, tuple[dict[str, Any], dict[str, Any], float | None]] = {
    "dmc-acrobot-swingup": (dict(num_timesteps=100_000_000), dict(num_timesteps=10_000_000), None),
    "dmc-acrobot-swingup-sparse": (dict(num_timesteps=100_000_000), dict(num_timesteps=10_000_000), None),
    "dmc-ball-in-cup-catch": (dict(discounting=0.95), {}, 900.0),
    "dmc-cartpole-balance": ({}, {}, 900.0),
    "dmc-cartpole-balance-sparse": ({}, {}, None),
    "dmc-cartpole-swingup": ({}, {}, 900.0),
    "dmc-cartpole-swingup-sparse": ({}, {}, None),
    "dmc-cheetah-run": ({}, dict(num_timesteps=10_000_000), 700.0),
    "dmc-finger-spin": (dict(discounting=0.95), dict(num_timesteps=10_000_000), 900.0),
    "dmc-finger-turn-easy": ({}, dict(num_timesteps=10_000_000), 700.0),
    "dmc-finger-turn-hard": ({}, dict(num_timesteps=10_000_000), None),
    "dmc-fish-swim": ({}, {}, None),
    "dmc-fish-upright": ({}, {}, None),  # Playground registers no fish upright: its base recipes
    "dmc-hopper-hop": ({}, dict(num_timesteps=10_000_000), None),
    "dmc-hopper-stand": ({}, dict(num_timesteps=10_000_000), 700.0),
    "dmc-humanoid-run": ({}, {}, None),
    "dmc-humanoid-stand": ({}, {}, None),
    "dmc-humanoid-walk": ({}, dict(num_timesteps=10_000_000), None),
    "dmc-pendulum-swingup": (dict(num_updates_per_batch=4), {}, 700.0),
    "dmc-point-mass-easy": ({}, {}, None),
    "dmc-quadruped-run": ({}, {}, 700.0),  # Playground has no quadruped: its base recipes
    "dmc-quadruped-walk": ({}, {}, 700.0),
    "dmc-reacher-easy": ({}, {}, 900.0),
    "dmc-reacher-hard": ({}, {}, None),
    "dmc-swimmer-swimmer6": (dict(num_timesteps=100_000_000), dict(num_timesteps=10_000_000), None),
    "dmc-walker-stand": ({}, {}, 900.0),
    "dmc-walker-walk": ({}, {}, 900.0),
    "dmc-walker-run": (dict(num_timesteps=100_000_000), dict(num_timesteps=10_000_000), 700.0),
}
for _task, (_ppo, _sac, _goal) in _DMC_TASKS.items():
    _solve = {} if _goal is None else {"solve_return": _goal}
    SETTINGS[_task] = {"ppo": {"default": {**_DMC_PPO, **_ppo, **_solve}},
                       "sac": {"default": {**_DMC_SAC, **_sac, **_solve}}}
del _task, _ppo, _sac, _goal, _solve


# The Gymnasium tasks' "cpu" preset (`--preset cpu`, `cpu_settings`): the task's default row with
# the fields that size a run for an accelerator (envs, batches, updates, networks, steps) replaced
# by CPU_SIZES, the base recipes' sizes (tens of envs, small batches) and a run of at most a few
# million env steps; the task's own fields (reward scaling, discount, the critic's support,
# solve_return) stay. A default row already that small is the cpu preset as it is. PPO's run is
# cut into 20 chunks, so its bar moves and a Ctrl-C is acted on every few minutes at most.
# Starting points: not run here to Gymnasium's goals.
GYMNASIUM_TASKS = ("inverted-pendulum", "inverted-double-pendulum", "ant", "humanoid", "half-cheetah", "hopper",
                   "walker2d", "reacher", "pusher", "swimmer")
CPU_SIZES: dict[str, dict[str, Any]] = {
    "ppo": dict(num_timesteps=2_000_000, num_evals=21, num_envs=64, batch_size=64, num_minibatches=16,
                unroll_length=16, num_updates_per_batch=4),
    "sac": dict(num_timesteps=300_000, num_evals=11, num_envs=16, batch_size=256, grad_updates_per_step=8,
                min_replay_size=2_000, max_replay_size=300_000),
    "td3": dict(num_timesteps=300_000, num_evals=11, num_envs=16, batch_size=256, num_updates=4,
                min_replay_size=1_024, max_replay_size=300_000),
}
# Accelerator-sized fields a row may set that CPU_SIZES leaves to the base recipe (its defaults).
CPU_DROPPED = ("hidden", "actor_hidden", "critic_hidden", "compute_dtype")
# A run of more env steps than this (all seeds together) is a GPU's work: on a CPU it takes hours.
GPU_SIZED_STEPS = 10_000_000


def cpu_settings(task: str, agent: str) -> dict[str, Any]:
    """The "cpu" preset's fields for `agent` on one of GYMNASIUM_TASKS (see CPU_SIZES)."""
    row = dict(SETTINGS.get(task, {}).get(agent, {}).get("default", {}))
    if row.get("num_timesteps", 0) <= CPU_SIZES[agent]["num_timesteps"]:
        return row
    kept = {k: v for k, v in row.items() if k not in CPU_SIZES[agent] and k not in CPU_DROPPED}
    return {**kept, **CPU_SIZES[agent]}


def gpu_sized_note(task: str, agent: str, total_steps: int, seeds: int) -> str | None:
    """What a run on a machine without a GPU says before anything compiles when its recipe is
    sized for one (more than GPU_SIZED_STEPS env steps over its seeds), naming the preset that
    fits a CPU where there is one; None for a CPU-sized run."""
    if total_steps * seeds <= GPU_SIZED_STEPS:
        return None
    per_seed = f" per seed ({seeds} seeds)" if seeds > 1 else ""
    smaller = (f"--preset cpu trains a smaller one ({cpu_total_steps(task, agent):,} env steps)"
               if "cpu" in presets(task, agent) else "--steps N trains fewer (e.g. --steps 200000 to see it learn)")
    return (f"{task}'s {agent.upper()} recipe trains {total_steps / 1e6:,.1f}M env steps{per_seed}, sized for a GPU: "
            f"on this CPU that takes hours; {smaller}. Ctrl-C stops it after the part of a chunk under way, saved")


def cpu_total_steps(task: str, agent: str) -> int:
    """The env steps per seed the "cpu" preset trains (its config's `total_steps`)."""
    from agents import registry

    return registry.config_class(agent)(**cpu_settings(task, agent)).total_steps


def default_agent(task: str) -> str:
    """The agent a continuous task trains with when --agent is not given."""
    return DEFAULT_AGENT.get(task, "ppo")


def pixel_env_options(task: str, options: dict[str, Any]) -> dict[str, Any]:
    """`options` (the run's `envs.make` overrides) with the task's `PIXEL_ENV_OPTIONS` added where
    it observes camera images (`observation="pixels"`) and the options do not say otherwise."""
    if options.get("observation") != "pixels":
        return options
    return {**PIXEL_ENV_OPTIONS.get(task, {}), **options}


def default_preset(task: str, agent: str, observation: str = "state") -> str:
    """The recipe a run takes without --preset: the task's "pixels" recipe for camera images
    (`observation="pixels"`) where it has one, else "default"."""
    if observation == "pixels" and "pixels" in SETTINGS.get(task, {}).get(agent, {}):
        return "pixels"
    return "default"


def presets(task: str, agent: str) -> list[str]:
    """The recipes the table holds for `agent` on `task` ("default" always exists; "cpu" for the
    Gymnasium tasks, `cpu_settings`)."""
    cpu = ("cpu",) if task in GYMNASIUM_TASKS and agent in CPU_SIZES else ()
    return sorted({"default", *cpu, *SETTINGS.get(task, {}).get(agent, {})})


def settings(task: str, agent: str, preset: str = "default") -> dict[str, Any]:
    """The table's fields for `agent` on `task` under `preset` ({} where the base recipe applies)."""
    if preset not in presets(task, agent):
        raise ValueError(f"--preset {preset!r} does not exist for --agent {agent} on {task}; "
                         f"choose one of {', '.join(presets(task, agent))}")
    if preset == "cpu" and task in GYMNASIUM_TASKS:
        return cpu_settings(task, agent)
    return dict(SETTINGS.get(task, {}).get(agent, {}).get(preset, {}))
