"""PPO in PyTorch on `mjxsuite/Hopper-v5`, single file, CleanRL style (after CleanRL's
ppo_continuous_action.py), with thousands of envs stepped on the GPU by MJX.

The envs come from Gymnasium's own API: `gymnasium.make_vec("mjxsuite/Hopper-v5", num_envs=N)`
is one JAX vector env; Gymnasium's `JaxToTorch` hands its arrays to PyTorch through DLPack, so
observations, rewards and actions never leave the GPU. Autoreset is `SAME_STEP`: a truncated
episode's last observation comes in `info["final_obs"]` and is bootstrapped with the critic.

At the end the policy (mean action) plays Gymnasium's own `Hopper-v5` (C MuJoCo, float64) and
the script prints its mean return over `--eval-episodes` episodes.

    pip install -e ".[torch,warp]"
    python examples/ppo_torch_hopper.py --impl warp             # GPU: 12 minutes of training at most
    python examples/ppo_torch_hopper.py --num-envs 8 --num-steps 8 --total-timesteps 256 \\
        --num-minibatches 2 --update-epochs 2 --eval-episodes 1 --eval-max-steps 20 --device cpu  # a CPU smoke run
"""

from __future__ import annotations

import argparse
import os
import time

# JAX (the envs) and PyTorch (the learner) share the GPU: JAX must not reserve 75% of it up front.
os.environ.setdefault("XLA_PYTHON_CLIENT_MEM_FRACTION", "0.5")

import gymnasium
import numpy as np
import torch
from gymnasium.vector import AutoresetMode
from gymnasium.wrappers.vector import JaxToTorch
from torch import nn
from torch.distributions import Normal


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    # The defaults are MuJoCo Playground's PPO recipe for 2,048 envs (the `hopper` row of
    # agents/brax_defaults.py, which trains this task to Gymnasium's Hopper-v5 threshold with Brax's
    # PPO on one GPU) in CleanRL's terms: each iteration unrolls every env 16 x 30 steps, then
    # makes 16 passes over the batch in 32 minibatches of 1,024 x 30 steps; discount 0.99 (the row's:
    # Playground's 0.995 left policies standing still, here and in our PPO), learning
    # rate 1e-3, entropy bonus 1e-2, 64 x 64 networks; 60M env steps. CleanRL's own choices stay
    # where Brax has no equivalent: a state-independent Gaussian policy, tanh layers, advantage
    # normalization, the clipped value loss, gradient clipping at 0.5, a linearly annealed learning
    # rate and rewards divided by the running std of the discounted return (Brax multiplies by 10).
    p.add_argument("--env-id", default="mjxsuite/Hopper-v5")
    p.add_argument("--eval-env-id", default="Hopper-v5", help="Gymnasium's own env the trained policy plays")
    p.add_argument("--impl", default=None, choices=["jax", "warp"],
                   help="MJX's implementation (default: the task's, jax; warp needs the [warp] extra and a GPU)")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--num-envs", type=int, default=2048)
    p.add_argument("--num-steps", type=int, default=480, help="steps of every env per rollout (one iteration)")
    p.add_argument("--total-timesteps", type=int, default=60_000_000)
    p.add_argument("--max-minutes", type=float, default=12.0,
                   help="stop training after this long (wall clock, compile included); the learning rate anneals "
                        "over whichever of this and --total-timesteps comes first")
    p.add_argument("--learning-rate", type=float, default=1e-3)
    p.add_argument("--gamma", type=float, default=0.99)
    p.add_argument("--gae-lambda", type=float, default=0.95)
    p.add_argument("--num-minibatches", type=int, default=32)
    p.add_argument("--update-epochs", type=int, default=16)
    p.add_argument("--clip-coef", type=float, default=0.2)
    p.add_argument("--ent-coef", type=float, default=1e-2)
    p.add_argument("--vf-coef", type=float, default=0.5)
    p.add_argument("--max-grad-norm", type=float, default=0.5)
    p.add_argument("--hidden", type=int, default=64)
    p.add_argument("--eval-episodes", type=int, default=10)
    p.add_argument("--eval-max-steps", type=int, default=1000)
    p.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    return p.parse_args(argv)


class RunningMeanStd(nn.Module):
    """Running mean and variance of a stream of batches (Chan et al.'s parallel update), on the device."""

    def __init__(self, shape, device):
        super().__init__()
        self.register_buffer("mean", torch.zeros(shape, device=device))
        self.register_buffer("var", torch.ones(shape, device=device))
        self.register_buffer("count", torch.tensor(1e-4, device=device))

    def update(self, x: torch.Tensor) -> None:
        batch_mean, batch_var, batch_count = x.mean(0), x.var(0, unbiased=False), x.shape[0]
        delta, total = batch_mean - self.mean, self.count + batch_count
        self.mean += delta * batch_count / total
        self.var = (self.var * self.count + batch_var * batch_count + delta**2 * self.count * batch_count / total) / total
        self.count = total

    def normalize(self, x: torch.Tensor) -> torch.Tensor:
        return torch.clamp((x - self.mean) / torch.sqrt(self.var + 1e-8), -10.0, 10.0)


def layer(n_in, n_out, std=np.sqrt(2)):
    linear = nn.Linear(n_in, n_out)
    nn.init.orthogonal_(linear.weight, std)
    nn.init.constant_(linear.bias, 0.0)
    return linear


class Agent(nn.Module):
    def __init__(self, obs_size: int, action_size: int, hidden: int, device):
        super().__init__()
        self.obs_rms = RunningMeanStd((obs_size,), device)
        self.critic = nn.Sequential(layer(obs_size, hidden), nn.Tanh(), layer(hidden, hidden), nn.Tanh(), layer(hidden, 1, 1.0))
        self.actor_mean = nn.Sequential(layer(obs_size, hidden), nn.Tanh(), layer(hidden, hidden), nn.Tanh(),
                                        layer(hidden, action_size, 0.01))
        self.actor_logstd = nn.Parameter(torch.full((1, action_size), -0.5))

    def value(self, obs):
        return self.critic(self.obs_rms.normalize(obs)).squeeze(-1)

    def act(self, obs, action=None):
        x = self.obs_rms.normalize(obs)
        mean = self.actor_mean(x)
        dist = Normal(mean, self.actor_logstd.expand_as(mean).exp())
        if action is None:
            action = dist.sample()
        return action, dist.log_prob(action).sum(-1), dist.entropy().sum(-1), self.critic(x).squeeze(-1)


def evaluate(agent: Agent, env_id: str, episodes: int, max_steps: int, seed: int, low, high) -> list[float]:
    """Returns of the mean action on Gymnasium's own env (its TimeLimit, shortened to max_steps)."""
    env = gymnasium.make(env_id, max_episode_steps=max_steps)
    returns = []
    for episode in range(episodes):
        obs, _ = env.reset(seed=seed + episode)
        total, done = 0.0, False
        while not done:
            with torch.no_grad():
                x = agent.obs_rms.normalize(torch.as_tensor(obs, dtype=torch.float32, device=low.device)[None])
                action = torch.clamp(agent.actor_mean(x)[0], low, high).cpu().numpy()
            obs, reward, terminated, truncated, _ = env.step(action.astype(np.float64))
            total += float(reward)
            done = terminated or truncated
        returns.append(total)
    return returns


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
    low = torch.as_tensor(envs.single_action_space.low, device=device)
    high = torch.as_tensor(envs.single_action_space.high, device=device)
    agent = Agent(obs_size, action_size, args.hidden, device).to(device)
    optimizer = torch.optim.Adam(agent.parameters(), lr=args.learning_rate, eps=1e-5)
    reward_rms = RunningMeanStd((), device)  # of the discounted return: rewards are divided by its std

    n, t = args.num_envs, args.num_steps
    batch_size = n * t
    minibatch_size = batch_size // args.num_minibatches
    num_iterations = max(1, args.total_timesteps // batch_size)
    obs_buf = torch.zeros((t, n, obs_size), device=device)
    actions_buf = torch.zeros((t, n, action_size), device=device)
    logprobs_buf, rewards_buf, dones_buf, values_buf = (torch.zeros((t, n), device=device) for _ in range(4))

    next_obs, _ = envs.reset(seed=args.seed)
    next_done = torch.zeros(n, device=device)
    discounted = torch.zeros(n, device=device)
    episode_return, episode_length = torch.zeros(n, device=device), torch.zeros(n, device=device)
    finished_returns: list[float] = []
    global_step, last_print = 0, time.time()
    for iteration in range(1, num_iterations + 1):
        minutes = (time.time() - start) / 60
        if minutes > args.max_minutes:
            print(f"stopping: --max-minutes {args.max_minutes} reached")
            break
        # Annealed to 0 at the end of training, whether the step budget or the clock ends it.
        progress = max((iteration - 1.0) / num_iterations, minutes / args.max_minutes)
        optimizer.param_groups[0]["lr"] = args.learning_rate * (1.0 - progress)
        for step in range(t):
            obs_buf[step], dones_buf[step] = next_obs, next_done
            with torch.no_grad():
                action, logprob, _, value = agent.act(next_obs)
            actions_buf[step], logprobs_buf[step], values_buf[step] = action, logprob, value
            next_obs, reward, terminated, truncated, info = envs.step(torch.clamp(action, low, high))
            reward, terminated, truncated = reward.float(), terminated.float(), truncated.float()
            episode_return += reward
            episode_length += 1
            ended = torch.maximum(terminated, truncated)
            if step % 8 == 0:  # a host sync: only now and then
                done_ids = ended.nonzero().squeeze(-1)
                finished_returns += episode_return[done_ids].tolist()
            episode_return *= 1 - ended
            episode_length *= 1 - ended
            discounted = discounted * args.gamma + reward  # the return so far, discounted backwards
            reward_rms.update(discounted)
            discounted = discounted * (1 - ended)
            scaled = reward / torch.sqrt(reward_rms.var + 1e-8)
            # A truncated episode did not end in the task: its last observation's value is bootstrapped.
            with torch.no_grad():
                final_value = agent.value(info["final_obs"].float())
            scaled = scaled + args.gamma * final_value * truncated * (1 - terminated)
            rewards_buf[step] = scaled
            next_done = ended
            global_step += n

        with torch.no_grad():  # GAE
            next_value = agent.value(next_obs)
            advantages = torch.zeros_like(rewards_buf)
            last = torch.zeros(n, device=device)
            for step in reversed(range(t)):
                nonterminal = 1.0 - (next_done if step == t - 1 else dones_buf[step + 1])
                following = next_value if step == t - 1 else values_buf[step + 1]
                delta = rewards_buf[step] + args.gamma * following * nonterminal - values_buf[step]
                last = delta + args.gamma * args.gae_lambda * nonterminal * last
                advantages[step] = last
            returns = advantages + values_buf

        b_obs, b_actions = obs_buf.reshape(-1, obs_size), actions_buf.reshape(-1, action_size)
        b_logprobs, b_advantages = logprobs_buf.reshape(-1), advantages.reshape(-1)
        b_returns, b_values = returns.reshape(-1), values_buf.reshape(-1)
        for _ in range(args.update_epochs):
            order = torch.randperm(batch_size, device=device)
            for begin in range(0, batch_size, minibatch_size):
                idx = order[begin:begin + minibatch_size]
                _, newlogprob, entropy, newvalue = agent.act(b_obs[idx], b_actions[idx])
                ratio = (newlogprob - b_logprobs[idx]).exp()
                adv = b_advantages[idx]
                adv = (adv - adv.mean()) / (adv.std() + 1e-8)
                pg_loss = torch.max(-adv * ratio, -adv * torch.clamp(ratio, 1 - args.clip_coef, 1 + args.clip_coef)).mean()
                v_clipped = b_values[idx] + torch.clamp(newvalue - b_values[idx], -args.clip_coef, args.clip_coef)
                v_loss = 0.5 * torch.max((newvalue - b_returns[idx]) ** 2, (v_clipped - b_returns[idx]) ** 2).mean()
                loss = pg_loss - args.ent_coef * entropy.mean() + args.vf_coef * v_loss
                optimizer.zero_grad()
                loss.backward()
                nn.utils.clip_grad_norm_(agent.parameters(), args.max_grad_norm)
                optimizer.step()

        # After the update, so that a rollout and the update on it see the same normalization.
        agent.obs_rms.update(b_obs)

        if time.time() - last_print > 10 or iteration == num_iterations:
            last_print = time.time()
            recent = finished_returns[-200:]
            mean = f"{np.mean(recent):.0f}" if recent else "-"
            print(f"iter {iteration}/{num_iterations} steps {global_step:,} "
                  f"({global_step / (time.time() - start):,.0f}/s) mean episode return (last 200) {mean}", flush=True)

    train_s = time.time() - start
    scores = evaluate(agent, args.eval_env_id, args.eval_episodes, args.eval_max_steps, args.seed, low, high)
    result = {"env_steps": global_step, "train_s": train_s, "wall_s": time.time() - start, "eval_env": args.eval_env_id,
              "eval_mean_return": float(np.mean(scores)), "eval_returns": scores}
    print(f"trained {global_step:,} env steps in {train_s / 60:.1f} min (compile included; "
          f"{result['wall_s'] / 60:.1f} min with the evaluation); "
          f"{args.eval_env_id} (Gymnasium's own env), mean action: mean return {result['eval_mean_return']:.0f} "
          f"over {len(scores)} episodes")
    return result


if __name__ == "__main__":
    main()
