"""Every benchmark of mjxsuite and the peer libraries it is compared with (`mjxsuite bench`).

- `suite`: the `bench` command's sections, its JSON records, tables and plot;
- `env_throughput`, `peers`: env-steps/s of our envs beside gymnax and MuJoCo Playground;
- `dqn`: DQN speed and time-to-solve; `replay`: our replay buffers against flashbax;
- `rerun_logging`: what Rerun logging costs;
- `cli`: the `mjxsuite` command (the library's commands plus `bench`).

Benchmarks sit above the library: they import `envs` and `agents`, which never import them.
"""
