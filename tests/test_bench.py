"""`mjxsuite bench` machinery on tiny sizes, its JSON records, the compile cache, and no
retracing between training chunks."""

import json
import os
import subprocess
import sys
from pathlib import Path

import jax
import numpy as np
import pytest

import envs
from agents import benchmark
from agents.cli import main as cli_main
from agents.compile_cache import CompileCounter, configured_dir, default_dir
from agents.dqn import DQNConfig
from agents.run import train_run
from envs import bench, bench_peers

ROOT = Path(__file__).resolve().parents[1]
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
    records = bench.throughput_records(ours=(), batch=[2, 8], repeats=1, print_rows=False)
    assert [(r["lib"], r["num_envs"]) for r in records] == [("gymnax", 2), ("playground", 2)]  # stops after one
    for r in records:
        assert r["steps_per_s"] is None and "is not usable" in r["skipped"] and "pip install --no-deps" in r["skipped"]
    assert bench.ratio_records(records) == []


def test_batch_sizes_depend_on_the_device():
    assert bench.batch_sizes("cartpole", on="cpu")[0] == 1 and max(bench.batch_sizes("cartpole", on="cpu")) <= 16384
    assert max(bench.batch_sizes("cartpole", on="gpu")) == 2**20
    assert max(bench.batch_sizes("cartpole-mjx", on="gpu")) >= 131072
    assert 4096 in bench.batch_sizes("cartpole", quick=True, on="cpu")
    assert 131072 in bench.batch_sizes("cartpole-mjx", quick=True, on="gpu")
    assert 2**20 in bench.batch_sizes("gymnax", quick=True, on="gpu")


def test_random_actions_are_uniform_over_the_action_indices():
    actions = np.asarray(bench_peers.random_actions(jax.random.PRNGKey(0), 100_000, 3))
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
    table = benchmark.tables(records)
    assert "| 4,096 | 16,384,000,000 | 8,192,000,000 | 2.00x | 1,228,800,000 | 819,200,000 | 1.50x |" in table
    with pytest.raises(ValueError, match="not a list of mjxsuite bench records"):
        (tmp_path / "bad.json").write_text('{"a": 1}')
        benchmark.load_records(tmp_path / "bad.json")


def test_startup_figure_is_the_median_of_the_warm_runs():
    runs = [("cold", 9.5), ("warm", 1.2), ("warm", 0.5), ("warm", 0.6)]
    records = [{"kind": "startup", "lib": "mjxsuite", "env": "cartpole-mjx", "steps": 2000, "run": i + 1,
                "cache": cache, "compile_s": s, "device": "cpu"} for i, (cache, s) in enumerate(runs)]
    line = "compile_s 9.50 with a cold compile cache, 0.60 warm (median of 1.20, 0.50, 0.60)."
    assert line in benchmark.startup_line(records)
    assert line in benchmark.tables(records)
    assert benchmark.startup_line(records[:2]).endswith("compile_s 9.50 with a cold compile cache, 1.20 warm.")


def test_batched_auto_reset_gives_the_same_states_as_vmapped_auto_reset():
    """Every branch (no env ended, a few reset by index, all) against VmapWrapper(AutoReset)."""
    num_envs = 64
    env = envs.make("cartpole")
    reference = envs.VmapWrapper(envs.AutoReset(env), num_envs)
    by_index = envs.BatchedAutoReset(env, num_envs, max_resets=2, reset_by_index=True)
    selected = envs.BatchedAutoReset(env, num_envs, reset_by_index=False)

    def run(wrapped):
        def body(state, key):
            action = jax.random.randint(key, (num_envs,), 0, 2)
            state = wrapped.step(state, action)
            return state, (state.obs, state.info["final_obs"], state.done)

        keys = jax.random.split(jax.random.PRNGKey(1), 200)
        return jax.jit(lambda: jax.lax.scan(body, wrapped.reset(jax.random.PRNGKey(0)), keys))()

    expected = run(reference)
    ended = np.asarray(expected[1][2]).sum(axis=1)
    assert (ended == 0).any() and ((ended > 0) & (ended <= 2)).any() and (ended > 2).any()
    for wrapped in (by_index, selected):
        for a, b in zip(jax.tree.leaves(run(wrapped)), jax.tree.leaves(expected)):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_compile_cache_location_and_opt_out(monkeypatch, tmp_path):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    monkeypatch.delenv("MJXSUITE_COMPILE_CACHE", raising=False)
    assert default_dir() == tmp_path / "xdg" / "mjxsuite" / "jax" == configured_dir()
    monkeypatch.setenv("MJXSUITE_COMPILE_CACHE", "0")
    assert configured_dir() is None
    monkeypatch.setenv("MJXSUITE_COMPILE_CACHE", str(tmp_path / "elsewhere"))
    assert configured_dir() == tmp_path / "elsewhere"


_CACHED_PROGRAM = """
import sys
from agents import compile_cache
print(compile_cache.enable())
import jax, numpy
with compile_cache.CompileCounter() as counter:
    jax.block_until_ready(jax.jit(lambda x: jax.numpy.sin(x) * 2 + 1)(numpy.arange(3.0)))
print(counter.compiles, counter.cache_hits)
"""


def _run_cached(env_vars: dict) -> list[str]:
    environ = {**os.environ, "JAX_PLATFORMS": "cpu", **env_vars}
    environ.pop("JAX_COMPILATION_CACHE_DIR", None)
    done = subprocess.run([sys.executable, "-c", _CACHED_PROGRAM], env=environ, cwd=ROOT, capture_output=True,
                          text=True, check=True)
    return done.stdout.split("\n")


def test_a_second_process_loads_small_programs_from_the_cache(tmp_path):
    cache = tmp_path / "cache"
    first = _run_cached({"MJXSUITE_COMPILE_CACHE": str(cache)})
    compiles, hits = map(int, first[1].split())
    assert first[0] == str(cache) and compiles >= 1 and hits == 0
    assert any(cache.iterdir())  # written, although the program compiles in far less than a second
    second = _run_cached({"MJXSUITE_COMPILE_CACHE": str(cache)})
    assert second[1] == f"{compiles} {compiles}"  # every program loaded from the cache
    off = _run_cached({"MJXSUITE_COMPILE_CACHE": "0", "XDG_CACHE_HOME": str(tmp_path / "unused")})
    assert off[0] == "None" and off[1] == f"{compiles} 0" and not (tmp_path / "unused").exists()


def test_no_compile_cache_flag_is_accepted_by_every_command(monkeypatch, tmp_path):
    from agents import cli

    calls = []
    monkeypatch.setattr(cli, "_use_compile_cache", lambda args: calls.append(args.no_compile_cache))
    with pytest.raises(SystemExit, match="unknown env"):
        cli_main(["rollout", "--no-compile-cache", "--env", "no-such-env", "--rerun", str(tmp_path / "x.rrd")])
    with pytest.raises(SystemExit, match="unknown env"):
        cli_main(["train", "--no-compile-cache", "--env", "no-such-env"])
    assert cli_main(["eval", "--checkpoint", str(tmp_path / "missing")]) != 0
    assert calls == [True, True, False]


def test_training_chunks_compile_once(tmp_path):
    """Nothing is traced or compiled again after the first chunk, Rerun logging included."""
    pytest.importorskip("rerun")
    from agents.recording import TrainingLogger

    config = DQNConfig(total_steps=400, learning_starts=64, batch_size=32, buffer_size=256, eval_every=100,
                       eval_episodes=4, hidden=(16,))
    logger = TrainingLogger(tmp_path / "train.rrd", "cartpole", config)
    counts = []

    def on_chunk(index, train_state, record):
        logger(index, train_state, record)
        counts.append((counter.traces, counter.compiles))

    with CompileCounter() as counter:
        try:
            train_run("cartpole", config, progress=False, on_chunk=on_chunk)
        finally:
            logger.close()
    assert len(counts) == config.num_chunks == 4
    assert counts[1:] == [counts[0]] * 3, counts
    assert counter.compiles >= 2  # the counter does see compiles (init, chunk, final evaluation)


def test_bench_refuses_an_unwritable_json_path_before_running_and_creates_nothing(tmp_path, monkeypatch):
    from agents import benchmark

    monkeypatch.setattr(benchmark, "run_bench", lambda *a, **k: pytest.fail("benchmarked before checking the path"))
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    for target in (blocker / "out.json", tmp_path):  # parent is a file; the path is a directory
        with pytest.raises(SystemExit, match="cannot write"):
            cli_main(["bench", "--json", str(target)])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a-file"]
