"""`mjxsuite bench` machinery on tiny sizes (`benchmarks`), its JSON records, tables and plot."""

import json
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from benchmarks import env_throughput, peers, suite
from benchmarks.cli import main as cli_main

THROUGHPUT_KEYS = {"kind", "lib", "env", "num_envs", "steps_per_s", "compile_s", "device"}


def test_bench_command_writes_records_for_ours_and_each_peer(tmp_path):
    out = tmp_path / "bench.json"
    code = cli_main(["bench", "--sections", "env", "--envs", "cartpole", "--batch", "4", "--repeats", "1",
                     "--peers", "gymnax", "--json", str(out)])
    assert code == 0
    records = json.loads(out.read_text())
    meta, *rest = records
    assert meta["kind"] == "meta" and meta["platform"] == "cpu" and meta["sections"] == ["env"]
    ours = [r for r in rest if r["kind"] == "env-throughput" and r["lib"] == "mjxsuite"]
    assert [(r["env"], r["num_envs"]) for r in ours] == [("cartpole", 4)]
    for r in ours:
        assert THROUGHPUT_KEYS <= set(r) and r["steps_per_s"] > 0 and r["compile_s"] > 0
        assert r["steps_per_s"] == pytest.approx(r["num_envs"] * r["steps"] / np.median(r["run_s"]))
    peer = [r for r in rest if r["kind"] == "env-throughput" and r["lib"] == "gymnax"]
    assert peer and all(THROUGHPUT_KEYS <= set(r) for r in peer)
    if peer[0].get("skipped"):  # gymnax is optional: a missing one is recorded, with the reason
        assert "gymnax==1.0.1" in peer[0]["skipped"] and peer[0]["steps_per_s"] is None
    else:
        ratios = {r["num_envs"]: r["ratio"] for r in rest if r["kind"] == "env-ratio"}
        speed = {(r["lib"], r["num_envs"]): r["steps_per_s"] for r in ours + peer}
        assert ratios[4] == pytest.approx(speed["mjxsuite", 4] / speed["gymnax", 4])


def test_a_missing_peer_is_skipped_with_the_reason(monkeypatch):
    monkeypatch.setitem(sys.modules, "gymnax", None)  # makes `import gymnax` raise ImportError
    monkeypatch.setitem(sys.modules, "mujoco_playground", None)
    records = env_throughput.throughput_records(ours=(), batch=[2, 8], repeats=1, print_rows=False)
    assert [(r["lib"], r["num_envs"]) for r in records] == [("gymnax", 2), ("playground", 2)]  # stops after one
    for r in records:
        assert r["steps_per_s"] is None and "is not usable" in r["skipped"] and "pip install --no-deps" in r["skipped"]
    assert env_throughput.ratio_records(records) == []


def test_batch_sizes_depend_on_the_device():
    batch_sizes = env_throughput.batch_sizes
    assert batch_sizes("cartpole", on="cpu")[0] == 1 and max(batch_sizes("cartpole", on="cpu")) <= 16384
    assert max(batch_sizes("cartpole", on="gpu")) == 2**20
    assert max(batch_sizes("cartpole-mjx", on="gpu")) >= 131072
    assert 4096 in batch_sizes("cartpole", quick=True, on="cpu")
    assert 131072 in batch_sizes("cartpole-mjx", quick=True, on="gpu")
    assert 2**20 in batch_sizes("gymnax", quick=True, on="gpu")


def test_random_actions_are_uniform_over_the_action_indices():
    actions = np.asarray(peers.random_actions(jax.random.PRNGKey(0), 100_000, 3))
    assert actions.dtype == np.int32 and set(np.unique(actions)) == {0, 1, 2}
    np.testing.assert_allclose(np.bincount(actions) / actions.size, 1 / 3, atol=0.01)


def test_plot_and_tables_come_from_saved_records(tmp_path):
    pytest.importorskip("matplotlib")
    records = [{"kind": "meta", "lib": "mjxsuite", "device": "cpu", "cpu_count": 2, "jax": "x", "python": "3"}]
    for lib, env, speed in [("mjxsuite", "cartpole", 4e6), ("gymnax", "CartPole-v1", 2e6),
                            ("mjxsuite", "cartpole-mjx", 3e5), ("playground", "CartpoleBalance", 2e5)]:
        for n in (1, 4096):
            records.append({"kind": "env-throughput", "lib": lib, "env": env, "num_envs": n, "steps_per_s": speed * n,
                            "compile_s": 1.0, "device": "cpu"})
    saved = tmp_path / "records.json"
    saved.write_text(json.dumps(records))
    png = tmp_path / "docs" / "throughput.png"
    assert cli_main(["bench", "--plot", str(saved), "--out", str(png)]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    table = suite.tables(records)
    assert "| 4,096 | 16,384,000,000 | 8,192,000,000 | 2.00x | 1,228,800,000 | 819,200,000 | 1.50x |" in table
    with pytest.raises(ValueError, match="not a list of mjxsuite bench records"):
        (tmp_path / "bad.json").write_text('{"a": 1}')
        suite.load_records(tmp_path / "bad.json")


def test_startup_figure_is_the_median_of_the_warm_runs():
    runs = [("cold", 9.5), ("warm", 1.2), ("warm", 0.5), ("warm", 0.6)]
    records = [{"kind": "startup", "lib": "mjxsuite", "env": "cartpole-mjx", "steps": 2000, "run": i + 1,
                "cache": cache, "compile_s": s, "device": "cpu"} for i, (cache, s) in enumerate(runs)]
    line = "compile_s 9.50 with a cold compile cache, 0.60 warm (median of 1.20, 0.50, 0.60)."
    assert line in suite.startup_line(records)
    assert line in suite.tables(records)
    assert suite.startup_line(records[:2]).endswith("compile_s 9.50 with a cold compile cache, 1.20 warm.")


def test_bench_refuses_an_unwritable_json_path_before_running_and_creates_nothing(tmp_path, monkeypatch):
    monkeypatch.setattr(suite, "run_bench", lambda *a, **k: pytest.fail("benchmarked before checking the path"))
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    for target in (blocker / "out.json", tmp_path):  # parent is a file; the path is a directory
        with pytest.raises(SystemExit, match="cannot write"):
            cli_main(["bench", "--json", str(target)])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a-file"]


# ---- benchmarks.gym_mujoco ---------------------------------------------------------------
def test_gym_mujoco_finds_every_gymnasium_task():
    from benchmarks import gym_mujoco

    tasks = gym_mujoco.gymnasium_tasks()
    assert {"half-cheetah", "hopper", "walker2d", "swimmer"} <= set(tasks) and "cartpole-mjx" not in tasks


def test_gym_mujoco_compares_with_brax_only_at_equal_solver_options():
    from benchmarks import gym_mujoco

    gymnasium_solver = {"solver": 2, "iterations": 100, "ls_iterations": 50, "tolerance": 1e-8, "integrator": 0}
    brax_solver = {**gymnasium_solver, "iterations": 4}
    record = lambda lib, speed, num_envs=4096, **extra: {"lib": lib, "env": "half-cheetah", "num_envs": num_envs,
                                                         "steps_per_s": speed, "device": "d", **extra}
    records = [record("mjxsuite", 1e6, impl="jax", solver=gymnasium_solver),
               record("brax", 4e6, solver=brax_solver), record("brax", 5e5, solver=gymnasium_solver),
               record("brax", 9e5, num_envs=32768, solver=gymnasium_solver), record("gymnasium", 1e4, num_envs=16)]
    ratios = {(r["peer"], r["peer_num_envs"]): r["ratio"] for r in gym_mujoco.ratio_records(records)}
    assert ratios == {("brax", 4096): pytest.approx(2.0), ("gymnasium", 16): pytest.approx(100.0)}


@pytest.mark.heavy
def test_gym_mujoco_runs_on_the_cpu_with_tiny_sizes(tmp_path):
    from benchmarks import gym_mujoco

    out = tmp_path / "gym.json"
    gym_mujoco.main(["--tasks", "half-cheetah", "--sizes", "2", "--steps", "3", "--gymnasium-steps", "5",
                     "--repeats", "1", "--json", str(out)])
    meta, *records = json.loads(out.read_text())
    assert meta["kind"] == "meta"
    speeds = {(r["lib"], r.get("impl") or r.get("solver_from")): r for r in records if r["kind"] == "gym-mujoco"}
    assert set(speeds) == {("gymnasium", None), ("mjxsuite", "jax"), ("brax", "own"), ("brax", "gymnasium")}
    assert all(r["steps_per_s"] > 0 for r in speeds.values())
    assert speeds["brax", "gymnasium"]["solver"] == speeds["mjxsuite", "jax"]["solver"] == speeds["gymnasium", None]["solver"]
    assert speeds["brax", "own"]["solver"]["iterations"] == 4
    assert {r["peer"] for r in records if r["kind"] == "gym-mujoco-ratio"} == {"brax", "gymnasium"}


def test_merge_replaces_only_the_kinds_a_run_wrote():
    from benchmarks.suite import merge_records

    old = [{"kind": "meta", "date": "d0"}, {"kind": "startup", "run": 1}, {"kind": "dqn-solve", "env": "cartpole"}]
    new = [{"kind": "meta", "date": "d1", "sections": ["first-second"]}, {"kind": "dqn-first-second", "met": True}]
    merged = merge_records(old, new)
    assert [r["kind"] for r in merged] == ["meta", "startup", "dqn-solve", "dqn-first-second"]
    assert merged[0]["note"] == "first-second re-run alone at d1" and "note" not in old[0]
    again = merge_records(merged, [{"kind": "dqn-first-second", "met": False}])
    assert [r.get("met") for r in again if r["kind"] == "dqn-first-second"] == [False]


def test_every_learning_case_builds_its_config_and_unknown_cases_are_refused():
    from benchmarks import learning

    for case in learning.CASES:
        config = learning.config_of(case)
        assert getattr(config, "solve_return", case.goal) == case.goal, case.name
        assert learning.config_of(case, tiny=True).total_steps < config.total_steps
    with pytest.raises(ValueError, match="unknown learning case"):
        learning.section(["no-such-case"])


@pytest.mark.heavy  # two tiny trainings, one judged on Gymnasium's own env
def test_the_learning_section_runs_at_tiny_sizes():
    from benchmarks import learning

    records = learning.section(["dqn-cartpole", "ppo-inverted-pendulum"], tiny=True)
    for record in records:
        assert record["kind"] == "learning" and record["tiny"] and len(record["final_returns"]) == record["seeds"]
        assert record["solved"] == sum(r >= record["goal"] for r in record["final_returns"])
        assert np.isfinite(record["final_returns"]).all() and record["wall_s"] > 0
    assert records[1]["judge"] == "gymnasium"


# ---- benchmarks.dmc_speed ----------------------------------------------------------------
def test_dmc_speed_compares_with_playground_at_the_same_impl_and_size_only():
    from benchmarks import dmc_speed

    record = lambda lib, speed, impl="warp", num_envs=4096: {"lib": lib, "env": "dmc-cheetah-run", "impl": impl,
                                                             "num_envs": num_envs, "steps_per_s": speed}
    records = [record("mjxsuite", 2e6), record("playground", 4e6), record("playground", 1e6, impl="jax"),
               record("playground", 9e6, num_envs=32768), record("dm_control", 1e4, impl=None, num_envs=16)]
    ratios = {r["peer"]: r["ratio"] for r in dmc_speed.ratios(records)}
    assert ratios == {"playground": pytest.approx(0.5), "dm_control": pytest.approx(200.0)}
    # A reset that costs (cheetah's settling steps) counts once an episode: the ratio is over whole
    # episodes, the stepping alone beside it.
    records[0]["episode_steps_per_s"] = 1e6
    found = {r["peer"]: r for r in dmc_speed.ratios(records)}
    assert found["playground"]["ratio"] == pytest.approx(0.25) and found["playground"]["step_ratio"] == pytest.approx(0.5)
    assert suite.without_options(["--sizes", "4", "8", "--tasks", "a", "b", "--json", "f", "--no-playground"],
                                 ("--tasks", "--json")) == ["--sizes", "4", "8", "--no-playground"]


@pytest.mark.slow  # two processes, each compiling a tiny pixel env
def test_each_task_alone_gathers_every_tasks_records_from_a_process_of_its_own(tmp_path):
    """How `benchmarks.pixels` and `benchmarks.dmc_speed` run several tasks under Warp: one process each,
    every task's records in the one file (here `benchmarks.pixels` with impl="jax", on the CPU)."""
    out = tmp_path / "pixels.json"
    suite.each_task_alone("benchmarks.pixels", ["--sizes", "2", "--steps", "2", "--size", "8", "--repeats", "1"],
                          ["cartpole-swingup-mjx", "pendulum-mjx"], str(out))
    records = json.loads(out.read_text())
    ratios = {r["env"]: r["pixels_over_state"] for r in records if r["kind"] == "pixels-ratio"}
    assert set(ratios) == {"cartpole-swingup-mjx", "pendulum-mjx"} and all(ratio > 0 for ratio in ratios.values())
    assert len([r for r in records if r["kind"] == "pixels"]) == 4 and not list(tmp_path.glob("*.tmp"))


@pytest.mark.heavy
def test_dmc_speed_runs_on_the_cpu_with_tiny_sizes(tmp_path):
    from benchmarks import dmc_speed

    out = tmp_path / "dmc.json"
    dmc_speed.main(["--tasks", "cheetah-run", "--sizes", "2", "--steps", "3", "--impls", "jax", "--repeats", "1",
                    "--no-playground", "--json", str(out), "--profile", str(tmp_path / "trace")])
    speeds = {r["lib"]: r for r in json.loads(out.read_text()) if r["kind"] == "dmc-speed"}
    assert set(speeds) == {"mjxsuite", "dm_control"} and all(r["steps_per_s"] > 0 for r in speeds.values())
    assert speeds["mjxsuite"]["control_timestep"] == 0.01 and speeds["mjxsuite"]["overflow_steps"] == 0
    assert speeds["mjxsuite"]["profile"] == {"error": "no device events in the trace", "processes": 0}  # a CPU has none
    assert list((tmp_path / "trace").rglob("*.trace.json.gz"))


def test_gpu_profile_sums_the_devices_kernels_by_name(tmp_path):
    """`gpu_profile.summary` reads a Perfetto trace: the GPU process's kernel events, summed by name,
    and how busy the span between the first kernel's start and the last one's end was."""
    import gzip

    from benchmarks import gpu_profile

    events = [{"ph": "M", "name": "process_name", "pid": 1, "args": {"name": "/device:GPU:0"}},
              {"ph": "M", "name": "process_name", "pid": 2, "args": {"name": "/host:CPU"}},
              {"ph": "X", "pid": 1, "name": "kinematics", "ts": 0, "dur": 1000},  # microseconds
              {"ph": "X", "pid": 1, "name": "kinematics", "ts": 2000, "dur": 1000},
              {"ph": "X", "pid": 1, "name": "memcpy32_post", "ts": 3500, "dur": 500},
              {"ph": "X", "pid": 2, "name": "host work", "ts": 0, "dur": 1000}]
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "x.trace.json.gz").write_bytes(gzip.compress(json.dumps({"traceEvents": events}).encode()))
    found = gpu_profile.summary(tmp_path)
    assert found["launches"] == 3 and found["kernel_s"] == 0.0025 and found["span_s"] == 0.004 and found["busy"] == 0.625
    assert [(k["name"], k["count"]) for k in found["top"]] == [("kinematics", 2), ("memcpy32_post", 1)]


def test_pixel_ppo_speed_counts_the_grouped_convolutions_that_vmapped_seeds_make():
    """A convolution vmapped over several seeds' kernels lowers to a grouped one (feature_group_count
    = seeds), and so do its gradients; one seed's stay plain. The benchmark counts them in a training
    step's HLO, beside its time."""
    from benchmarks.pixel_ppo_speed import grouped_convolutions

    def loss(kernel, images):
        return jnp.sum(jax.lax.conv_general_dilated(images, kernel, (2, 2), "VALID",
                                                    dimension_numbers=("NHWC", "HWIO", "NHWC")) ** 2)

    kernels, images = jnp.ones((3, 3, 3, 4, 8)), jnp.ones((3, 2, 9, 9, 4))
    both = jax.grad(loss, argnums=(0, 1))  # the forward pass, then the kernel's and the images' gradients
    plain = jax.jit(both).lower(kernels[0], images[0]).as_text()
    seeds = jax.jit(jax.vmap(both)).lower(kernels, images).as_text()
    assert grouped_convolutions(plain) == {"feature_group_count": 0, "batch_group_count": 0}
    assert grouped_convolutions(seeds) == {"feature_group_count": 3, "batch_group_count": 0}
