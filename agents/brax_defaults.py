"""Per-task settings of PPO, SAC and TD3: the one table `mjxsuite train --agent ppo|sac|td3` reads.

`SETTINGS[task][agent][preset]` holds the fields that differ from the agent's base recipe (its
config class's defaults, sized for small tasks on a CPU); `--FIELD VALUE` options then change the
result. Rows are keyed by name only, so a row of an unregistered task breaks nothing. Gymnasium's
MuJoCo tasks also have "cpu" (`cpu_settings`); camera images take the task's "pixels" recipe and
`PIXEL_ENV_OPTIONS` by default (`default_preset`, `pixel_env_options`).

Where each row comes from: "measured here" (`mjxsuite train` on a CPU); "Brax notebook" (google/brax
notebooks/training.ipynb, for its look-alike of the Gymnasium task, sized for an accelerator);
"Playground" (MuJoCo Playground's dm_control_suite_params.py, for the dm_control look-alike; every
dmc-* row); "FastTD3" (its hyperparams.py, for a GPU). Rows marked "run" were run on a GPU
(docs/agents.md, "Per-task recipes"); the others are starting points.
"""

from __future__ import annotations

from typing import Any

import envs

# Brax's notebook recipe for its inverted pendulums and ant (PPO), shared by three rows.
_BRAX_NOTEBOOK_PENDULUMS = dict(num_evals=20, reward_scaling=10.0, unroll_length=5, num_minibatches=32,
                                num_updates_per_batch=4, discounting=0.97, learning_rate=3e-4, entropy_cost=1e-2,
                                num_envs=2048, batch_size=1024)
# Playground's dm_control PPO and SAC recipes, less num_resets_per_eval (our envs reset every episode).
_PLAYGROUND_PPO = dict(num_timesteps=60_000_000, num_evals=10, reward_scaling=10.0, unroll_length=30,
                       num_minibatches=32, num_updates_per_batch=16, discounting=0.995, learning_rate=1e-3,
                       entropy_cost=1e-2, num_envs=2048, batch_size=1024)
# The cart-pole's recipe from camera images, for one GPU: it learned where Playground's vision recipe
# did not (docs/agents.md, "PPO from pixels").
_PIXEL_PPO = dict(num_envs=256, batch_size=256)
# The env options of a run on camera images (`pixel_env_options`): three frames, four task steps apart,
# so that they show the pole's velocity (docs/agents.md, "PPO from pixels"). dm_control's swing-up acts every 8
# control steps, its cheetah, quadruped and hopper hop every 4, as PlaNet and DrQ ran the first two (DrQ-v2: 2), the
# cheetah and the hopper with Warp's shadows (docs/agents.md, "The swing-up at action repeat 8", "Cheetah run from
# pixels with shadows", "Quadruped run from pixels", "Hopper hop from pixels").
PIXEL_ENV_OPTIONS: dict[str, dict[str, Any]] = {task: {"frame_stack": 3, "action_repeat": 4} for task in (
    "cartpole-balance-mjx", "cartpole-swingup-mjx")} | {"dmc-cartpole-swingup": {"action_repeat": 8},
                                                        "dmc-cheetah-run": {"action_repeat": 4, "shadows": True},
                                                        "dmc-quadruped-walk": {"action_repeat": 4},
                                                        "dmc-quadruped-run": {"action_repeat": 4},
                                                        "dmc-hopper-hop": {"action_repeat": 4, "shadows": True}}
_PLAYGROUND_SAC = dict(num_timesteps=5_000_000, num_evals=10, discounting=0.99, learning_rate=1e-3, num_envs=128,
                       batch_size=512, grad_updates_per_step=8, max_replay_size=4 * 1048576, min_replay_size=8192)
# FastTD3's recipe (github.com/younggyoseo/FastTD3, fast_td3/hyperparams.py at commit 229ed59): BaseArgs
# with MuJoCoPlaygroundArgs' 1,024 envs. Ours: a replay of 1M transitions per seed, the critic's support
# per task (about the per-step reward bound over 1 - discount), the run's length. Starting points.
_FASTTD3_LEARNING = dict(policy_frequency=2, actor_learning_rate=3e-4, critic_learning_rate=3e-4, weight_decay=0.1,
                         discounting=0.99, tau=0.1, policy_noise=0.001, noise_clip=0.5, std_min=0.001, std_max=0.4,
                         num_atoms=101, init_scale=0.01)
_FASTTD3 = dict(_FASTTD3_LEARNING, num_envs=1024, batch_size=32768, num_updates=2, actor_hidden=(512, 256, 128),
                critic_hidden=(1024, 512, 256), compute_dtype="bfloat16", min_replay_size=10 * 1024,
                max_replay_size=1 << 20, num_evals=11)
# Without --agent, where not "ppo": the agent whose row beat PPO's, met a goal PPO's missed, or alone ran (docs/agents.md).
DEFAULT_AGENT: dict[str, str] = {"half-cheetah": "sac", "swimmer": "sac", **dict.fromkeys(("hopper", "walker2d",
    "humanoid", "ant", "dmc-walker-stand", "dmc-walker-walk", "dmc-walker-run", "dmc-finger-spin",
    "dmc-finger-turn-easy", "dmc-finger-turn-hard", "dmc-cheetah-run", "dmc-pendulum-swingup", "dmc-cartpole-swingup",
    "dmc-quadruped-walk", "dmc-quadruped-run", "dmc-hopper-stand", "dmc-hopper-hop", "dmc-humanoid-walk",
    "dmc-acrobot-swingup", "dmc-fish-upright"), "td3")}

# The "cpu" preset (`cpu_settings`, offered by `presets`): the default row resized by CPU_SIZES (its own fields stay).
# 16 episodes an evaluation: 64 of dm_control's 1,000-step episodes cost a CPU more than a chunk of training.
CPU_SIZES: dict[str, dict[str, Any]] = {
    "ppo": dict(num_timesteps=2_000_000, num_evals=21, num_eval_envs=16, num_envs=64, batch_size=64,
                num_minibatches=16, unroll_length=16, num_updates_per_batch=4),
    "sac": dict(num_timesteps=300_000, num_evals=11, num_eval_envs=16, num_envs=16, batch_size=256,
                grad_updates_per_step=8, min_replay_size=2_000, max_replay_size=300_000),
    "td3": dict(num_timesteps=300_000, num_evals=11, num_eval_envs=16, num_envs=16, batch_size=256, num_updates=4,
                min_replay_size=1_024, max_replay_size=300_000),
}
SETTINGS: dict[str, dict[str, dict[str, dict[str, Any]]]] = {
    # Gymnasium's Pendulum-v1 (solved at -200). Measured here.
    "pendulum-mjx": {
        "ppo": {"default": dict(num_timesteps=1_500_000, discounting=0.95, reward_scaling=0.1, solve_return=-200.0)},
        "sac": {"default": dict(num_timesteps=30_000, num_evals=4, solve_return=-200.0)},
        # TD3: the base recipe, rewards scaled into the critic's support (returns of -1,600 to 0)
        "td3": {"default": dict(num_timesteps=20_000, num_evals=4, reward_scaling=0.1, v_min=-200.0, v_max=50.0,
                                solve_return=-200.0)},
    },
    # dm_control's cartpole swing-up. default: measured here. playground: Playground's recipe, for a
    # GPU. pixels: from camera images, for a GPU (`_PIXEL_PPO`).
    "cartpole-swingup-mjx": {
        "ppo": {"default": dict(num_timesteps=5_000_000, num_envs=256, batch_size=256, num_minibatches=16,
                                learning_rate=3e-4, discounting=0.99, entropy_cost=1e-2, solve_return=800.0),
                "playground": dict(_PLAYGROUND_PPO, solve_return=800.0),
                "pixels": dict(_PIXEL_PPO, num_timesteps=11_000_000, num_evals=8, solve_return=800.0)},
        "sac": {"default": dict(num_timesteps=100_000, hidden=(128, 128), solve_return=800.0),
                "playground": dict(_PLAYGROUND_SAC, solve_return=800.0)},
    },
    # dm_control's cartpole balance. default: the base recipe. pixels: for a GPU (`_PIXEL_PPO`).
    "cartpole-balance-mjx": {"ppo": {"default": {}, "pixels": dict(_PIXEL_PPO, num_timesteps=8_000_000, num_evals=15)}},
    # Gymnasium's MuJoCo tasks (v5). Brax notebook rows; SAC rows from Playground's SAC recipe.
    # default: the base recipe, measured here (solves InvertedPendulum-v5 on a CPU). brax-notebook: Brax's.
    "inverted-pendulum": {
        "ppo": {"default": dict(num_timesteps=300_000, num_evals=7, solve_return=950.0),
                "brax-notebook": dict(_BRAX_NOTEBOOK_PENDULUMS, num_timesteps=2_000_000, solve_return=950.0)},
        "sac": {"default": dict(_PLAYGROUND_SAC, num_timesteps=1_000_000, solve_return=950.0)},
    },
    "inverted-double-pendulum": {  # PPO run, impl="warp"
        "ppo": {"default": dict(_BRAX_NOTEBOOK_PENDULUMS, num_timesteps=20_000_000, solve_return=9100.0)},
        "sac": {"default": dict(_PLAYGROUND_SAC, solve_return=9100.0)},
    },
    "ant": {  # PPO and TD3 run, impl="warp"; TD3 the default, as long as Gymnasium's goal in ten minutes allows
        "ppo": {"default": dict(_BRAX_NOTEBOOK_PENDULUMS, num_timesteps=50_000_000, num_evals=10, num_envs=4096,
                                batch_size=2048, solve_return=6000.0)},
        "sac": {"default": dict(_PLAYGROUND_SAC, solve_return=6000.0)},
        "td3": {"default": dict(_FASTTD3, num_timesteps=8_192_000, v_min=-300.0, v_max=800.0, solve_return=6000.0)},
    },
    "humanoid": {  # PPO and TD3 run, impl="warp" (TD3 the default: Gymnasium's goal in half the time); SAC run once
        # PPO: Brax's notebook recipe (train_fn['humanoid'], read at commit 0b96d05); SAC: Playground's
        "ppo": {"default": dict(num_timesteps=50_000_000, num_evals=10, reward_scaling=0.1, unroll_length=10,
                                num_minibatches=32, num_updates_per_batch=8, discounting=0.97, learning_rate=3e-4,
                                entropy_cost=1e-3, num_envs=2048, batch_size=1024)},
        "sac": {"default": dict(_PLAYGROUND_SAC)},
        "td3": {"default": dict(_FASTTD3, num_timesteps=20_480_000, v_min=-100.0, v_max=1200.0)},
    },
    "half-cheetah": {  # SAC run, impl="warp", for 10M env steps: Gymnasium's goal in ten minutes; PPO's fell far short
        "ppo": {"default": dict(num_timesteps=50_000_000, num_evals=20, reward_scaling=1.0, unroll_length=20,
                                num_minibatches=32, num_updates_per_batch=8, discounting=0.95, learning_rate=3e-4,
                                entropy_cost=1e-3, num_envs=2048, batch_size=512, solve_return=4800.0)},
        "sac": {"default": dict(_PLAYGROUND_SAC, num_timesteps=10_000_000, solve_return=4800.0)},
        "td3": {"default": dict(_FASTTD3, num_timesteps=15_360_000, v_min=-300.0, v_max=1500.0, solve_return=4800.0)},
    },
    "hopper": {  # PPO and TD3 run, impl="warp"; TD3 the default: every seed over 3,000 in ten minutes (docs/agents.md)
        "ppo": {"default": dict(_PLAYGROUND_PPO, discounting=0.99, solve_return=3800.0)},
        "sac": {"default": dict(num_timesteps=6_553_600, num_evals=20, reward_scaling=30.0, discounting=0.997,
                                learning_rate=6e-4, num_envs=128, batch_size=512, grad_updates_per_step=64,
                                max_replay_size=1048576, min_replay_size=8192, solve_return=3800.0)},
        "td3": {"default": {**_FASTTD3_LEARNING, **CPU_SIZES["td3"], "num_timesteps": 700_000, "critic_layer_norm": True,
                            "v_min": -100.0, "v_max": 500.0, "solve_return": 3800.0}},
    },
    "walker2d": {  # SAC and TD3 run, impl="warp"; TD3 the default: Gymnasium's goal in ten minutes (docs/agents.md)
        "ppo": {"default": dict(num_timesteps=7_864_320, num_evals=20, reward_scaling=5.0, unroll_length=20,
                                num_minibatches=32, num_updates_per_batch=8, discounting=0.97, learning_rate=6e-4,
                                entropy_cost=1e-2, num_envs=128, batch_size=128)},
        "sac": {"default": dict(_PLAYGROUND_SAC)},
        "td3": {"default": dict(_FASTTD3, num_timesteps=9_984_000, num_evals=14, v_min=-100.0, v_max=700.0)},
    },
    "reacher": {  # PPO run, impl="warp". Brax's notebook also repeats each action 4 times (not offered here)
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

# The dmc-* tasks: MuJoCo Playground's recipes for its look-alikes (google-deepmind/mujoco_playground,
# mujoco_playground/config/dm_control_suite_params.py at commit 0b06a59), `brax_ppo_config` and `brax_sac_config` with
# Brax's default networks, less num_resets_per_eval, PendulumSwingup's PPO action_repeat (an env option here) and
# SAC's q_network_layer_norm; pendulum's SAC keeps the base steps, as in Playground (its "PendulumSwingUp" exception
# names no task). solve_return: the goal. Starting points unless docs/tasks.md shows a run.
_DMC_PPO = dict(_PLAYGROUND_PPO, policy_hidden=(32,) * 4, value_hidden=(256,) * 5)
_DMC_SAC = dict(_PLAYGROUND_SAC, hidden=(256, 256))
# TD3: FastTD3's CheetahRunArgs, its DMC recipe (1,024 envs, discount 0.97, 3-step returns, noise 0.1), with the
# critic's support [0, 35]: every discounted return of rewards in [0, 1], where FastTD3's +-500 wastes all but 4 atoms;
# and the LayerNorm critic its authors suggest for DMC: without it, seeds' actors saturate and stand still (docs/tasks.md).
_DMC_TD3 = dict(_FASTTD3, discounting=0.97, num_steps=3, std_min=0.1, policy_noise=0.1, v_min=0.0, v_max=35.0,
                num_timesteps=10_240_000, critic_layer_norm=True)
# Per task over _DMC_TD3 (docs/tasks.md): lqr's rewards fall below 0; the swing-ups outlast discount 0.97's horizon;
# finger spin saturates without rlkit's pre-tanh penalty; the hoppers need correlated noise; hopper hop, humanoid walk
# and the acrobot, left near their floor by white noise at discount 0.97, learn with both.
_LONG = dict(discounting=0.99, v_max=100.0)
_DMC_TD3_TASKS = {"dmc-lqr-lqr-2-1": dict(v_min=-35.0), "dmc-lqr-lqr-6-2": dict(v_min=-35.0),
                  **dict.fromkeys(("dmc-pendulum-swingup", "dmc-cartpole-swingup"), _LONG),
                  "dmc-finger-spin": dict(pre_tanh_penalty=1e-3),
                  "dmc-hopper-stand": dict(noise_correlation=0.97, num_timesteps=13_312_000, num_evals=14),
                  **dict.fromkeys(("dmc-hopper-hop", "dmc-humanoid-walk", "dmc-acrobot-swingup"),
                                  dict(_LONG, noise_correlation=0.97))}
# TD3 from camera images: DrQ-v2's settings (facebookresearch/drqv2, cfgs/config.yaml, "medium" tasks: 1,024-wide
# layers, 3-step returns, discount 0.99, target step 0.01, batches of 256, 1M frames = 500k env steps at action repeat
# 2) at GPU scale: 64 envs per seed; a replay of 100k transitions, 4.2 GB per seed at 84x84x9; 16 updates per 64 env
# steps (half DrQ-v2's rate: four seeds step twice as far). Not DrQ-v2's: Adam's 3e-4, LayerNorm critics, bf16. Batches
# of 1,024 at 8 updates in float32 were 4x slower per update and showed no learning on the GPU; 2 updates at 1e-4
# learned nothing; without rlkit's pre-tanh penalty walker walk's actors saturated (docs/agents.md, "TD3 from pixels").
_PIXEL_TD3 = dict(num_timesteps=500_000, num_envs=64, batch_size=256, num_updates=16, actor_learning_rate=3e-4,
                  critic_learning_rate=3e-4, pre_tanh_penalty=1e-3, critic_layer_norm=True, weight_decay=0.0, tau=0.01,
                  discounting=0.99, num_steps=3, actor_hidden=(1024, 1024), critic_hidden=(1024, 1024), std_min=0.1,
                  std_max=0.4, policy_noise=0.2, v_min=0.0, v_max=200.0, min_replay_size=2048, max_replay_size=100_000,
                  num_evals=21, compute_dtype="bfloat16", encoder_dtype="bfloat16")
# The swing-up at action repeat 8, the cheetah at 4 (PIXEL_ENV_OPTIONS): 1M frames. Walker and quadruped run and
# hopper hop, issue 66's 20-minute tasks: their measured runs' lengths (docs/agents.md: "Walker run", "Quadruped run",
# "Hopper hop").
_PIXEL_TD3_TASKS = {"dmc-cartpole-swingup": dict(num_timesteps=125_000, num_evals=6),
                    "dmc-cheetah-run": dict(num_timesteps=250_000, num_evals=11),
                    "dmc-walker-run": dict(num_timesteps=200_000, num_evals=9),
                    "dmc-quadruped-run": dict(num_timesteps=225_000, num_evals=10),
                    "dmc-hopper-hop": dict(num_timesteps=250_000, num_evals=11)}
_SAC_10M = dict(num_timesteps=10_000_000)  # SAC's exception in most of Playground's tasks
_LONG_RUNS = (dict(num_timesteps=100_000_000), _SAC_10M, None)  # Playground's long runs
# task: (PPO's fields over _DMC_PPO, SAC's over _DMC_SAC, the goal or None), Playground's exceptions.
_DMC_TASKS: dict[str, tuple[dict[str, Any], dict[str, Any], float | None]] = {
    "dmc-acrobot-swingup": _LONG_RUNS, "dmc-acrobot-swingup-sparse": _LONG_RUNS,
    "dmc-ball-in-cup-catch": (dict(discounting=0.95), {}, 900.0),
    "dmc-cartpole-balance": ({}, {}, 900.0), "dmc-cartpole-swingup": ({}, {}, 900.0),
    "dmc-cartpole-balance-sparse": ({}, {}, None), "dmc-cartpole-swingup-sparse": ({}, {}, None),
    "dmc-cheetah-run": ({}, _SAC_10M, 700.0),
    "dmc-finger-spin": (dict(discounting=0.95), _SAC_10M, 900.0),
    "dmc-finger-turn-easy": ({}, _SAC_10M, 700.0), "dmc-finger-turn-hard": ({}, _SAC_10M, None),
    "dmc-fish-swim": ({}, {}, None),
    "dmc-hopper-hop": ({}, _SAC_10M, None), "dmc-hopper-stand": ({}, _SAC_10M, 700.0),
    "dmc-humanoid-run": ({}, {}, None), "dmc-humanoid-stand": ({}, {}, None), "dmc-humanoid-walk": ({}, _SAC_10M, None),
    "dmc-pendulum-swingup": (dict(num_updates_per_batch=4), {}, 700.0), "dmc-point-mass-easy": ({}, {}, None),
    "dmc-quadruped-run": ({}, {}, 700.0), "dmc-quadruped-walk": ({}, {}, 700.0),  # no quadruped in Playground
    "dmc-reacher-easy": ({}, {}, 900.0), "dmc-reacher-hard": ({}, {}, None),
    "dmc-swimmer-swimmer6": _LONG_RUNS, "dmc-swimmer-swimmer15": _LONG_RUNS,  # no swimmer15 in Playground: swimmer6
    "dmc-walker-stand": ({}, {}, 900.0), "dmc-walker-walk": ({}, {}, 900.0),
    "dmc-walker-run": (dict(num_timesteps=100_000_000), _SAC_10M, 700.0),
}
# Tasks Playground does not register (fish upright, the manipulator's, ...): its base recipes.
_DMC_TASKS |= {name: ({}, {}, None) for name, *_ in envs.TASKS if name.startswith("dmc-") and name not in _DMC_TASKS}
# Issue 66's goals from pixels: DrQ-v2's mean at 1M frames (3M: walker and quadruped run, hopper hop), drqv2 curves.
DRQV2_SCORES = {"dmc-cartpole-swingup": 863.0, "dmc-walker-walk": 765.0, "dmc-cheetah-run": 714.0, "dmc-walker-run": 680.0,
                "dmc-quadruped-walk": 711.0, "dmc-quadruped-run": 723.0, "dmc-hopper-hop": 354.0}
for _task, (_ppo, _sac, _goal) in _DMC_TASKS.items():
    _solve = {} if _goal is None else {"solve_return": _goal}
    # TD3's support from pixels: sums of rewards (at most 1 each) over the action repeat, _PIXEL_TD3's for DrQ-v2's 2.
    _pixel_v_max = _PIXEL_TD3["v_max"] / 2 * PIXEL_ENV_OPTIONS.get(_task, {}).get("action_repeat", 2)
    SETTINGS[_task] = {"ppo": {"default": {**_DMC_PPO, **_ppo, **_solve}, "pixels": dict(  # from camera images
                           _PIXEL_PPO, num_timesteps=10_000_000, num_evals=21, solve_return=DRQV2_SCORES.get(_task))},
                       "sac": {"default": {**_DMC_SAC, **_sac, **_solve}},
                       "td3": {"default": {**_DMC_TD3, **_solve, **_DMC_TD3_TASKS.get(_task, {})},
                               "pixels": dict(_PIXEL_TD3, solve_return=DRQV2_SCORES.get(_task), v_max=_pixel_v_max,
                                              **_PIXEL_TD3_TASKS.get(_task, {}))}}
del _task, _ppo, _sac, _goal, _solve, _pixel_v_max

GYMNASIUM_TASKS = ("inverted-pendulum", "inverted-double-pendulum", "ant", "humanoid", "half-cheetah", "hopper",
                   "walker2d", "reacher", "pusher", "swimmer")
# Accelerator-sized fields a row may set that CPU_SIZES leaves to the base recipe (its defaults).
CPU_DROPPED = ("hidden", "actor_hidden", "critic_hidden", "compute_dtype")
# A run of more env steps than these (all seeds together) is a GPU's work: on a CPU it takes hours. SAC and TD3 pay
# for their updates: over twice their "cpu" preset per seed. Camera images pay for the CPU's ray caster.
GPU_SIZED_STEPS, GPU_SIZED_PIXEL_STEPS = 10_000_000, 100_000
GPU_SIZED_OFF_POLICY_STEPS = 2 * CPU_SIZES["td3"]["num_timesteps"]


def cpu_settings(task: str, agent: str) -> dict[str, Any]:
    """The "cpu" preset's fields for `agent` on `task`, where `presets` offers it (see CPU_SIZES)."""
    row = dict(SETTINGS.get(task, {}).get(agent, {}).get("default", {}))
    if row.get("num_timesteps", 0) <= CPU_SIZES[agent]["num_timesteps"]:
        return row
    kept = {k: v for k, v in row.items() if k not in CPU_SIZES[agent] and k not in CPU_DROPPED}
    return {**kept, **CPU_SIZES[agent]}


def gpu_sized_note(task: str, agent: str, total_steps: int, seeds: int, pixels: bool = False) -> str | None:
    """The note for a run without a GPU of a recipe over a GPU_SIZED limit above, naming what fits a CPU; else None."""
    from agents import registry

    per_seed_limit = agent in ("sac", "td3") and not pixels
    limit = GPU_SIZED_OFF_POLICY_STEPS if per_seed_limit else GPU_SIZED_PIXEL_STEPS if pixels else GPU_SIZED_STEPS
    if total_steps * (1 if per_seed_limit else seeds) <= limit:
        return None
    per_seed = f" per seed ({seeds} seeds)" if seeds > 1 else ""
    cpu_agent = next((a for a in (agent, "td3") if "cpu" in presets(task, a)), None)  # PPO on dm_control: TD3's
    if pixels:
        smaller = ("camera images come from MJX's ray caster here, for tests and small images: --steps N trains "
                   "fewer, --env-opt width=16 --env-opt height=16 renders smaller (docs/agents.md)")
    elif cpu_agent:
        smaller = (f"{'' if cpu_agent == agent else '--agent td3 '}--preset cpu trains a smaller one "
                   f"({registry.config_class(cpu_agent)(**cpu_settings(task, cpu_agent)).total_steps:,} env steps)")
    else:
        smaller = "--steps N trains fewer"
    recipe = f"{task}'s {agent.upper()} recipe" + (" from camera images" if pixels else "")
    return (f"{recipe} trains {total_steps / 1e6:,.1f}M env steps{per_seed}, sized for a GPU: on this CPU that takes "
            f"hours; {smaller}. Ctrl-C stops it after the part of a chunk under way, keeping the chunks done")


def default_agent(task: str, pixels: bool = False) -> str:
    """The agent a continuous task trains with when --agent is not given. From camera images: TD3 where it has
    a pixel recipe (dm_control's tasks, DrQ-v2's benchmark: docs/agents.md, "TD3 from pixels"), else PPO."""
    if pixels:
        return "td3" if "pixels" in SETTINGS.get(task, {}).get("td3", {}) else "ppo"
    return DEFAULT_AGENT.get(task, "ppo")


def pixel_env_options(task: str, options: dict[str, Any]) -> dict[str, Any]:
    """The run's `envs.make` overrides, with the task's `PIXEL_ENV_OPTIONS` under them on camera images."""
    return {**PIXEL_ENV_OPTIONS.get(task, {}), **options} if options.get("observation") == "pixels" else options


def default_preset(task: str, agent: str, observation: str = "state") -> str:
    """The recipe without --preset: the task's "pixels" one on camera images where it has one, else "default"."""
    return "pixels" if observation == "pixels" and "pixels" in SETTINGS.get(task, {}).get(agent, {}) else "default"


def presets(task: str, agent: str) -> list[str]:
    """The recipes of `agent` on `task` ("default" always; "cpu" for every agent on Gymnasium's tasks, and for SAC
    and TD3 on dm_control's: PPO at CPU_SIZES did not learn there, docs/training.md)."""
    cpu = agent in CPU_SIZES and (task in GYMNASIUM_TASKS or (task in _DMC_TASKS and agent in ("sac", "td3")))
    return sorted({"default", *(("cpu",) if cpu else ()), *SETTINGS.get(task, {}).get(agent, {})})


def settings(task: str, agent: str, preset: str = "default") -> dict[str, Any]:
    """The table's fields for `agent` on `task` under `preset` ({} where the base recipe applies)."""
    if preset not in presets(task, agent):
        raise ValueError(f"--preset {preset!r} does not exist for --agent {agent} on {task}; "
                         f"choose one of {', '.join(presets(task, agent))}")
    if preset == "cpu":
        return cpu_settings(task, agent)
    return dict(SETTINGS.get(task, {}).get(agent, {}).get(preset, {}))
