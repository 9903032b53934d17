"""PPO in PyTorch on `mjxsuite/Hopper-v5`, single file, CleanRL style: Brax's PPO algorithm
(brax/training/agents/ppo: train.py, losses.py, networks.py) written in plain PyTorch, with
thousands of envs stepped on the GPU by MJX.

The envs come from Gymnasium's own API: `gymnasium.make_vec("mjxsuite/Hopper-v5", num_envs=N)`
is one JAX vector env; Gymnasium's `JaxToTorch` hands its arrays to PyTorch through DLPack, so
observations, rewards and actions never leave the GPU. Autoreset is `SAME_STEP`: the step that
ends an episode returns the next episode's first observation, as Brax's auto-reset does, so every
step of an unroll is a real transition.

What the learner does, as Brax's PPO does it (our JAX PPO, agents/ppo.py, is built from those parts
and trains this env to 3,589 on Hopper-v5 with the same recipe):
- policy: an MLP gives loc and raw scale per action dimension (a state-dependent Gaussian,
  scale = softplus(raw) + 0.001) and the action is tanh of a Gaussian sample; log-probs carry the
  tanh's log-det-Jacobian, the entropy is the Gaussian's plus the log-det at a sampled action;
- networks: 64 x 64 MLPs with swish (SiLU), lecun_uniform weights and zero biases;
- observations: Brax's running mean/std (Welford), updated with each collected batch before the
  SGD passes on it, not clipped;
- data: each iteration unrolls every env `batch_size * num_minibatches / num_envs` times for
  `unroll_length` steps; a minibatch is `batch_size` whole unrolls;
- loss, per minibatch: values and GAE recomputed with the current value network over each unroll
  (bootstrapped from its last next-observation), rewards x `reward_scaling`, advantages normalized
  per minibatch, clipped surrogate (epsilon 0.3), value loss mean(err^2) * 0.5 * 0.5, entropy bonus;
  Adam at a constant learning rate, no gradient clipping.

At the end the deterministic policy (tanh of the Gaussian's loc, as Brax evaluates) plays
Gymnasium's own `Hopper-v5` (C MuJoCo, float64) and the script prints its mean return over
`--eval-episodes` episodes.

    pip install -e ".[torch,warp]"
    python examples/ppo_torch_hopper.py --impl warp             # GPU: 12 minutes of training at most
    python examples/ppo_torch_hopper.py --num-envs 8 --unroll-length 8 --batch-size 4 --num-minibatches 2 \\
        --update-epochs 2 --total-timesteps 128 --eval-episodes 1 --eval-max-steps 20 --device cpu  # a CPU smoke run
"""

from __future__ import annotations

import argparse
import itertools
import math
import os
import time

# JAX (the envs) and PyTorch (the learner) share the GPU: JAX must not reserve 75% of it up front.
os.environ.setdefault("XLA_PYTHON_CLIENT_MEM_FRACTION", "0.5")

import gymnasium
import numpy as np
import torch
import torch.nn.functional as F
from gymnasium.vector import AutoresetMode
from gymnasium.wrappers.vector import JaxToTorch
from torch import nn

MIN_STD = 1e-3  # Brax's NormalTanhDistribution: scale = softplus(raw) + min_std
HALF_LOG_2PI = 0.5 * math.log(2.0 * math.pi)


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    # The defaults are the `hopper` row of agents/brax_defaults.py: MuJoCo Playground's PPO recipe
    # (2,048 envs, unrolls of 30 steps, 16 passes over each batch in 32 minibatches of 1,024
    # unrolls, reward x10, learning rate 1e-3, entropy cost 1e-2, 60M steps) with the discount 0.99
    # (Playground's 0.995 left policies standing still, here and in our PPO), and Brax's PPO
    # defaults beside it (clipping 0.3, GAE lambda 0.95, 64 x 64 networks as PPOConfig has them).
    p.add_argument("--env-id", default="mjxsuite/Hopper-v5")
    p.add_argument("--eval-env-id", default="Hopper-v5", help="Gymnasium's own env the trained policy plays")
    p.add_argument("--impl", default=None, choices=["jax", "warp"],
                   help="MJX's implementation (default: the task's, jax; warp needs the [warp] extra and a GPU)")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--num-envs", type=int, default=2048)
    p.add_argument("--unroll-length", type=int, default=30, help="steps of one unroll (Brax's unroll_length)")
    p.add_argument("--batch-size", type=int, default=1024, help="unrolls per minibatch (Brax's batch_size)")
    p.add_argument("--num-minibatches", type=int, default=32,
                   help="minibatches per pass; an iteration collects batch-size * num-minibatches unrolls")
    p.add_argument("--update-epochs", type=int, default=16,
                   help="passes over each collected batch (Brax's num_updates_per_batch)")
    p.add_argument("--total-timesteps", type=int, default=60_000_000,
                   help="env steps, rounded up to whole iterations")
    p.add_argument("--max-minutes", type=float, default=12.0,
                   help="stop training after this long (wall clock, compile included)")
    p.add_argument("--learning-rate", type=float, default=1e-3)
    p.add_argument("--gamma", type=float, default=0.99)
    p.add_argument("--gae-lambda", type=float, default=0.95)
    p.add_argument("--clip-coef", type=float, default=0.3)
    p.add_argument("--ent-coef", type=float, default=1e-2)
    p.add_argument("--vf-coef", type=float, default=0.5, help="value loss: mean(err^2) * 0.5 * vf-coef, as Brax's")
    p.add_argument("--reward-scaling", type=float, default=10.0, help="rewards are multiplied by this in the loss")
    p.add_argument("--max-grad-norm", type=float, default=None, help="clip gradients (default: no clipping, as Brax)")
    p.add_argument("--hidden", type=int, nargs="+", default=[64, 64], help="hidden layer sizes of both networks")
    p.add_argument("--eval-episodes", type=int, default=10)
    p.add_argument("--eval-max-steps", type=int, default=1000)
    p.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    args = p.parse_args(argv)
    if args.batch_size * args.num_minibatches % args.num_envs:
        p.error(f"--batch-size * --num-minibatches ({args.batch_size * args.num_minibatches}) must be a multiple "
                f"of --num-envs ({args.num_envs}): each iteration unrolls every env the same number of times")
    return args


class RunningStatistics:
    """Brax's observation normalizer (acme/running_statistics.py, Welford's update): mean and std of
    every observation seen so far, std clipped to [1e-6, 1e6]; on the device, no host syncs."""

    def __init__(self, size: int, device):
        self.count = 0  # a Python int: the batch sizes are known on the host
        self.mean = torch.zeros(size, device=device)
        self.summed_variance = torch.zeros(size, device=device)
        self.std = torch.ones(size, device=device)

    def update(self, x: torch.Tensor) -> None:
        self.count += x.shape[0]
        diff_to_old_mean = x - self.mean
        self.mean = self.mean + diff_to_old_mean.sum(0) / self.count
        self.summed_variance = self.summed_variance + (diff_to_old_mean * (x - self.mean)).sum(0)
        self.std = torch.clamp(torch.sqrt(torch.clamp(self.summed_variance, min=0.0) / self.count), 1e-6, 1e6)

    def normalize(self, x: torch.Tensor) -> torch.Tensor:
        return (x - self.mean) / self.std  # not clipped, as Brax's PPO networks use it


def mlp(sizes: list[int]) -> nn.Sequential:
    """Brax's MLP (training/networks.py): swish between layers, none after the last; weights
    lecun_uniform (uniform in +-sqrt(3 / fan_in)), biases 0."""
    layers: list[nn.Module] = []
    for n_in, n_out in itertools.pairwise(sizes):
        linear = nn.Linear(n_in, n_out)
        bound = math.sqrt(3.0 / n_in)
        nn.init.uniform_(linear.weight, -bound, bound)
        nn.init.zeros_(linear.bias)
        layers += [linear, nn.SiLU()]
    return nn.Sequential(*layers[:-1])


class Agent(nn.Module):
    def __init__(self, obs_size: int, action_size: int, hidden: list[int]):
        super().__init__()
        self.policy = mlp([obs_size, *hidden, 2 * action_size])  # loc and raw scale of each action dimension
        self.critic = mlp([obs_size, *hidden, 1])

    def distribution(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The Gaussian (before the tanh) at normalized observations x: loc, scale."""
        loc, raw_scale = self.policy(x).chunk(2, dim=-1)
        return loc, F.softplus(raw_scale) + MIN_STD

    def value(self, x: torch.Tensor) -> torch.Tensor:
        return self.critic(x).squeeze(-1)


def tanh_log_det_jacobian(u: torch.Tensor) -> torch.Tensor:
    """log |d tanh(u) / du|, computed stably as Brax's TanhBijector does."""
    return 2.0 * (math.log(2.0) - u - F.softplus(-2.0 * u))


def log_prob(loc: torch.Tensor, scale: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
    """Log-probability of the action tanh(u), from the pre-tanh sample u (summed over action dimensions)."""
    normal = -0.5 * ((u - loc) / scale) ** 2 - HALF_LOG_2PI - torch.log(scale)
    return (normal - tanh_log_det_jacobian(u)).sum(-1)


def entropy(loc: torch.Tensor, scale: torch.Tensor) -> torch.Tensor:
    """Brax's entropy estimate of the tanh-Gaussian: the Gaussian's entropy plus the log-det-Jacobian
    at one (reparametrized) sample."""
    u = loc + scale * torch.randn_like(loc)
    return (0.5 + HALF_LOG_2PI + torch.log(scale) + tanh_log_det_jacobian(u)).sum(-1)


@torch.no_grad()
def compute_gae(rewards, values, bootstrap, termination, truncation, gamma: float, lam: float):
    """Brax's compute_gae (ppo/losses.py) on (unrolls, time) tensors: the value targets vs and
    Brax's advantages r_t + gamma * vs_{t+1} - V(s_t). A truncated step (time limit) gets neither
    advantage nor TD error, and no later error flows past it: the env reset there, so its
    next observation is the next episode's first one, whose value must not be bootstrapped."""
    keep = 1.0 - truncation
    not_terminal = 1.0 - termination
    next_values = torch.cat([values[:, 1:], bootstrap[:, None]], dim=1)
    deltas = (rewards + gamma * not_terminal * next_values - values) * keep
    decay = gamma * lam * not_terminal * keep
    acc, vs_minus_v = torch.zeros_like(bootstrap), []
    for t in reversed(range(rewards.shape[1])):
        acc = deltas[:, t] + decay[:, t] * acc
        vs_minus_v.append(acc)
    vs = torch.stack(vs_minus_v[::-1], dim=1) + values
    next_vs = torch.cat([vs[:, 1:], bootstrap[:, None]], dim=1)
    advantages = (rewards + gamma * not_terminal * next_vs - values) * keep
    return vs, advantages


def ppo_loss(agent: Agent, normalizer: RunningStatistics, mb: dict, args) -> tuple[torch.Tensor, dict]:
    """Brax's compute_ppo_loss on a minibatch of whole unrolls (leading axes: unrolls, time)."""
    obs = normalizer.normalize(mb["obs"])  # (B, T + 1, obs): the last is the unroll's final next-observation
    loc, scale = agent.distribution(obs[:, :-1])
    values = agent.value(obs)
    baseline, bootstrap = values[:, :-1], values[:, -1]
    vs, advantages = compute_gae(mb["reward"] * args.reward_scaling, baseline.detach(), bootstrap.detach(),
                                 mb["termination"], mb["truncation"], args.gamma, args.gae_lambda)
    advantages = (advantages - advantages.mean()) / (advantages.std(unbiased=False) + 1e-8)
    ratio = torch.exp(log_prob(loc, scale, mb["raw_action"]) - mb["log_prob"])
    clipped = torch.clamp(ratio, 1.0 - args.clip_coef, 1.0 + args.clip_coef)
    policy_loss = -torch.minimum(ratio * advantages, clipped * advantages).mean()
    v_loss = ((vs - baseline) ** 2).mean() * 0.5 * args.vf_coef
    entropy_loss = -args.ent_coef * entropy(loc, scale).mean()
    total = policy_loss + v_loss + entropy_loss
    return total, {"policy_loss": policy_loss, "v_loss": v_loss, "entropy_loss": entropy_loss}


def by_unroll(x: torch.Tensor) -> torch.Tensor:
    """(unroll, time, env, ...) -> (unroll * env, time, ...): one row per unroll of one env, as in Brax."""
    return x.transpose(1, 2).flatten(0, 1)


def evaluate(agent: Agent, normalizer: RunningStatistics, env_id: str, episodes: int, max_steps: int, seed: int,
             center: torch.Tensor, half: torch.Tensor) -> list[float]:
    """Returns of the deterministic policy (tanh of the loc, as Brax evaluates) on Gymnasium's own env
    (its TimeLimit, shortened to max_steps)."""
    env = gymnasium.make(env_id, max_episode_steps=max_steps)
    returns = []
    for episode in range(episodes):
        obs, _ = env.reset(seed=seed + episode)
        total, done = 0.0, False
        while not done:
            with torch.no_grad():
                x = normalizer.normalize(torch.as_tensor(obs, dtype=torch.float32, device=center.device)[None])
                loc, _ = agent.distribution(x)
                action = (center + half * torch.tanh(loc[0])).cpu().numpy()
            obs, reward, terminated, truncated, _ = env.step(action.astype(np.float64))
            total += float(reward)
            done = terminated or truncated
        returns.append(total)
    env.close()
    return returns


class Rollouts:
    """One iteration's data, (unroll, time, env, ...), and the returns of the episodes that ended,
    summed on the device (no host sync while collecting). obs has t + 1 steps: the last is the
    unroll's final next-observation, whose value bootstraps the unroll (the next unroll's first)."""

    def __init__(self, unrolls: int, t: int, n: int, obs_size: int, action_size: int, device):
        self.obs = torch.zeros((unrolls, t + 1, n, obs_size), device=device)
        self.raw_action = torch.zeros((unrolls, t, n, action_size), device=device)
        self.log_prob, self.reward, self.termination, self.truncation = (
            torch.zeros((unrolls, t, n), device=device) for _ in range(4))
        self.episode_return = torch.zeros(n, device=device)
        self.ended_returns, self.ended_count = torch.zeros((), device=device), torch.zeros((), device=device)

    def data(self) -> dict:
        """The iteration's unrolls, one row each (`by_unroll`)."""
        return {"obs": by_unroll(self.obs), "raw_action": by_unroll(self.raw_action),
                "log_prob": by_unroll(self.log_prob), "reward": by_unroll(self.reward),
                "termination": by_unroll(self.termination), "truncation": by_unroll(self.truncation)}

    def mean_ended_return(self) -> str:
        """The mean return of the episodes ended since the last call (the host syncs here)."""
        count = int(self.ended_count.item())
        mean = f"{self.ended_returns.item() / count:.0f} ({count} episodes)" if count else "- (none ended)"
        self.ended_returns.zero_()
        self.ended_count.zero_()
        return mean


@torch.no_grad()
def collect(agent: Agent, normalizer: RunningStatistics, envs, next_obs, buf: Rollouts, center, half):
    """Every env unrolled `unrolls` times for t steps with the stochastic policy into `buf`; the
    normalizer then takes the batch's observations (Brax: before the SGD passes on it). Returns the
    last observation."""
    unrolls, t = buf.reward.shape[:2]
    for u in range(unrolls):
        buf.obs[u, 0] = next_obs
        for step in range(t):
            loc, scale = agent.distribution(normalizer.normalize(next_obs))
            raw_action = loc + scale * torch.randn_like(loc)  # the Gaussian sample; the env gets its tanh
            buf.raw_action[u, step] = raw_action
            buf.log_prob[u, step] = log_prob(loc, scale, raw_action)
            next_obs, reward, terminated, truncated, _ = envs.step(center + half * torch.tanh(raw_action))
            # Truncation (the time limit) is handled as Brax does, by masking the truncated step in
            # the GAE (compute_gae) rather than bootstrapping from info["final_obs"]: it is the
            # recipe that trains this task, it keeps the loss to one value pass over the unroll,
            # and it costs one step in 1,000 on Hopper. A step that both falls and hits the limit
            # counts as a fall.
            terminated, truncated = terminated.float(), truncated.float()
            buf.obs[u, step + 1] = next_obs
            buf.reward[u, step] = reward.float()
            buf.termination[u, step] = terminated
            buf.truncation[u, step] = truncated * (1.0 - terminated)
            buf.episode_return += reward.float()
            ended = torch.maximum(terminated, truncated)
            buf.ended_returns += (buf.episode_return * ended).sum()
            buf.ended_count += ended.sum()
            buf.episode_return *= 1.0 - ended
    normalizer.update(buf.obs[:, :t].reshape(-1, buf.obs.shape[-1]))
    return next_obs


def learn(agent: Agent, normalizer: RunningStatistics, optimizer, data: dict, args) -> dict:
    """`update_epochs` passes, each over the unrolls in shuffled minibatches of `batch_size` unrolls."""
    num_unrolls = data["reward"].shape[0]
    losses: dict = {}
    for _ in range(args.update_epochs):
        order = torch.randperm(num_unrolls, device=data["reward"].device)
        for begin in range(0, num_unrolls, args.batch_size):
            idx = order[begin:begin + args.batch_size]
            loss, losses = ppo_loss(agent, normalizer, {k: v[idx] for k, v in data.items()}, args)
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            if args.max_grad_norm is not None:
                nn.utils.clip_grad_norm_(agent.parameters(), args.max_grad_norm)
            optimizer.step()
    return losses


def main(argv=None) -> dict:
    args = parse_args(argv)
    torch.manual_seed(args.seed)
    device = torch.device(args.device)
    start = time.time()  # the time limit counts the envs' compile too
    env_kwargs = {} if args.impl is None else {"impl": args.impl}
    envs = JaxToTorch(gymnasium.make_vec(args.env_id, num_envs=args.num_envs, autoreset_mode=AutoresetMode.SAME_STEP,
                                         **env_kwargs), device=device)
    obs_size = envs.single_observation_space.shape[0]
    action_size = envs.single_action_space.shape[0]
    # tanh gives actions in [-1, 1]; the env's Box may be wider (InvertedPendulum: [-3, 3]).
    low = torch.as_tensor(envs.single_action_space.low, device=device)
    high = torch.as_tensor(envs.single_action_space.high, device=device)
    center, half = (high + low) / 2, (high - low) / 2
    agent = Agent(obs_size, action_size, args.hidden).to(device)
    normalizer = RunningStatistics(obs_size, device)
    # Brax: optax.adam(learning_rate), one optimizer over both networks, eps 1e-8, constant rate.
    optimizer = torch.optim.Adam(agent.parameters(), lr=args.learning_rate, eps=1e-8, fused=device.type == "cuda")

    n, t = args.num_envs, args.unroll_length
    unrolls = args.batch_size * args.num_minibatches // n  # per env and iteration
    num_iterations = max(1, math.ceil(args.total_timesteps / (unrolls * t * n)))
    buf = Rollouts(unrolls, t, n, obs_size, action_size, device)
    next_obs, _ = envs.reset(seed=args.seed)
    global_step, last_print = 0, time.time()
    for iteration in range(1, num_iterations + 1):
        if (time.time() - start) / 60 > args.max_minutes:
            print(f"stopping: --max-minutes {args.max_minutes} reached")
            break
        next_obs = collect(agent, normalizer, envs, next_obs, buf, center, half)
        global_step += unrolls * t * n
        losses = learn(agent, normalizer, optimizer, buf.data(), args)
        if time.time() - last_print > 10 or iteration == num_iterations:
            last_print = time.time()
            parts = " ".join(f"{k} {v.item():.3g}" for k, v in losses.items())
            rate = global_step / (time.time() - start)
            print(f"iter {iteration}/{num_iterations} steps {global_step:,} ({rate:,.0f}/s) mean return of the "
                  f"episodes ended since the last line {buf.mean_ended_return()}; {parts}", flush=True)

    train_s = time.time() - start
    scores = evaluate(agent, normalizer, args.eval_env_id, args.eval_episodes, args.eval_max_steps, args.seed,
                      center, half)
    result = {"env_steps": global_step, "train_s": train_s, "wall_s": time.time() - start, "eval_env": args.eval_env_id,
              "eval_mean_return": float(np.mean(scores)), "eval_returns": scores}
    print(f"trained {global_step:,} env steps in {train_s / 60:.1f} min (compile included; "
          f"{result['wall_s'] / 60:.1f} min with the evaluation); "
          f"{args.eval_env_id} (Gymnasium's own env), deterministic policy: mean return "
          f"{result['eval_mean_return']:.0f} over {len(scores)} episodes")
    return result


if __name__ == "__main__":
    main()
