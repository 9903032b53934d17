"""Seeds and sweeps spread over devices and hosts (agents/sharding.py): the same agents as on one device.

Every multi-device case runs in a subprocess of its own with 4 forced host devices
(`--xla_force_host_platform_device_count`), which must be set before JAX starts; one
subprocess runs all the single-host cases, so they share its start-up.
"""

import dataclasses
import json
import os
import re
import socket
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SMALL = dict(total_steps=2000, eval_every=1000, learning_starts=200, batch_size=32, buffer_size=2000, eval_episodes=8)
SMALL_FLAGS = [word for name, value in SMALL.items() for word in (f"--{name}", str(value))]
SEEDS = 8


def environment(devices: int) -> dict:
    flags = f"{os.environ.get('XLA_FLAGS', '')} --xla_force_host_platform_device_count={devices}".strip()
    return {**os.environ, "XLA_FLAGS": flags,
            "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}


SINGLE_HOST = textwrap.dedent("""
    import dataclasses, json, shutil, sys
    from pathlib import Path
    import jax, numpy as np
    from agents import DQNConfig
    from agents.cli import main
    from agents.run import CLOCK_KEYS, load_agent, train_run

    out = Path(sys.argv[1])
    config = DQNConfig(**json.loads(sys.argv[2]))
    seeds = int(sys.argv[3])
    assert jax.local_device_count() == 4

    def equal(a, b):
        return all(np.array_equal(np.asarray(x), np.asarray(y)) for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)))

    def kept(run):  # eval.json without its timings
        record = json.loads((out / run / "eval.json").read_text())
        return {k: v for k, v in record.items() if k not in ("wall_s", "compile_s", "solve_wall_s", "devices", "wall_parts_s")}

    found = {}
    # The judged chunks pinned (the default budget reads the clock); a resumed run reads them from its --out.
    one = train_run("cartpole", config, seeds=seeds, devices=1, out_dir=out / "one", progress=False, judge_every=1)
    four = train_run("cartpole", config, seeds=seeds, devices=4, out_dir=out / "four", progress=False, judge_every=1)
    found["devices"] = [one.devices, four.devices, json.loads((out / "four/eval.json").read_text())["devices"]]
    found["four_equals_one"] = {"params": equal(one.params, four.params),
                                "train_state": equal(one.train_state, four.train_state),
                                "eval_json": kept("one") == kept("four"),
                                "metrics": [{k: v for k, v in json.loads(line).items() if k not in CLOCK_KEYS}
                                            for line in (out / "one/metrics.jsonl").read_text().splitlines()]
                                == [{k: v for k, v in json.loads(line).items() if k not in CLOCK_KEYS}
                                    for line in (out / "four/metrics.jsonl").read_text().splitlines()]}

    # Saved on 2 devices after one chunk, resumed on 1 and on 4.
    train_run("cartpole", config, seeds=seeds, devices=2, out_dir=out / "part", progress=False, stop_after_chunks=1,
              judge_every=1)
    shutil.copytree(out / "part", out / "part_copy")
    found["resumed"] = {}
    for devices, run in ((1, "part"), (4, "part_copy")):
        resumed = train_run("cartpole", config, seeds=seeds, devices=devices, out_dir=out / run, progress=False,
                            resume=True)
        found["resumed"][devices] = equal(resumed.params, one.params) and equal(resumed.train_state, one.train_state)

    # A sweep member (config 1, both seeds) against a separate `mjxsuite train` of that config.
    grid = ["--learning_rate", "1e-3,2e-3", "--polyak_tau", "0.02"]
    flags = [w for name, value in json.loads(sys.argv[2]).items() for w in (f"--{name}", str(value))]
    found["sweep_exit"] = main(["sweep", "--env", "cartpole", "--seeds", "2", "--devices", "4", "--out",
                                str(out / "sweep"), "--judge-every", "1", *grid, *flags])
    found["train_exit"] = main(["train", "--env", "cartpole", "--seeds", "2", "--out", str(out / "member"), "--judge-every", "1",
                                "--learning_rate", "2e-3", "--polyak_tau", "0.02", *flags])
    swept, member = json.loads((out / "sweep/eval.json").read_text()), kept("member")
    found["sweep_member_eval"] = [swept["mean_return"][2:4], swept["solve_step"][2:4]] == \\
        [member["mean_return"], member["solve_step"]]
    sweep_params, member_params = load_agent(out / "sweep")[3], load_agent(out / "member")[3]
    found["sweep_member_params"] = equal(jax.tree.map(lambda x: x[2:4], sweep_params), member_params)
    found["sweep_json"] = json.loads((out / "sweep/sweep.json").read_text())

    # The tie-break's program for every seed, compiled for the agents spread over the 4 devices
    # (as a GPU run compiles it beside training), measures as the tied seeds' own on one device.
    import envs
    from agents import DQN
    from agents.run import break_ties, every_seed_tie_break, seed_keys, tie_break_keys
    from agents.sharding import Placement
    dqn, options = DQN(DQNConfig(hidden=(8,), eval_episodes=2), envs.make("cartpole", episode_length=20)), {"episode_length": 20}
    placement = Placement(jax.local_devices())
    params = jax.device_get(jax.vmap(dqn.init)(seed_keys(0, 4)).params)
    keys = jax.eval_shape(lambda: tie_break_keys(0, np.arange(4)))
    every_seed = every_seed_tie_break(dqn, "cartpole", options, placement, params, keys)
    returns = [20.0, 3.0, 20.0, 20.0]
    spread = break_ties(dqn, "cartpole", options, placement.put(params), returns, 0, first=8, every_seed=every_seed)
    alone = break_ties(dqn, "cartpole", options, params, returns, 0, first=8)
    found["spread_tie_break"] = [spread[0] == alone[0], sorted(spread[1]) == sorted(alone[1]),
                                 max(abs(spread[1][i] - alone[1][i]) for i in alone[1])]

    # The seeds must split evenly over the devices asked for.
    try:
        train_run("cartpole", config, seeds=6, devices=4, progress=False)
    except ValueError as err:
        found["uneven"] = str(err)
    found["default_devices"] = train_run("cartpole", config, seeds=2, progress=False, stop_after_chunks=1).devices
    print("RESULT " + json.dumps(found))
""")


@pytest.fixture(scope="module")
def single_host(tmp_path_factory):
    """Everything the single-host tests check, from one subprocess with 4 CPU devices."""
    out = tmp_path_factory.mktemp("sharding")
    done = subprocess.run([sys.executable, "-c", SINGLE_HOST, str(out), json.dumps(SMALL), str(SEEDS)],
                          env=environment(4), capture_output=True, text=True, timeout=900, cwd=out)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-5000:]
    line = next(line for line in done.stdout.splitlines() if line.startswith("RESULT "))
    return out, json.loads(line[len("RESULT "):])


# Slow (make test-slow, which CI runs): each of these starts processes that train on 2 or 4 CPU devices.
@pytest.mark.slow
def test_eight_seeds_on_four_devices_equal_the_same_seeds_on_one(single_host):
    _, found = single_host
    assert found["devices"] == [1, 4, 4]
    assert found["four_equals_one"] == {"params": True, "train_state": True, "eval_json": True, "metrics": True}


@pytest.mark.slow
def test_saved_on_two_devices_resumes_on_one_and_on_four_as_the_uninterrupted_run(single_host):
    _, found = single_host
    assert found["resumed"] == {"1": True, "4": True}


@pytest.mark.slow
def test_a_sweep_member_equals_a_separate_train_of_its_config_and_seed(single_host):
    _, found = single_host
    assert found["sweep_exit"] == 0 and found["train_exit"] == 0
    assert found["sweep_member_eval"] and found["sweep_member_params"]
    summary = found["sweep_json"]
    assert summary["swept"] == ["learning_rate", "polyak_tau"] and summary["devices"] == 4
    assert [(c["learning_rate"], c["polyak_tau"]) for c in summary["configs"]] == [(1e-3, 0.02), (2e-3, 0.02)]
    assert all(len(c["mean_return"]) == len(c["solve_step"]) == 2 for c in summary["configs"])


@pytest.mark.slow
def test_the_tie_break_for_every_seed_spread_over_devices_measures_as_the_tied_seeds_program(single_host):
    best_same, rows_same, largest_difference = single_host[1]["spread_tie_break"]
    assert best_same and rows_same and largest_difference < 1e-5


@pytest.mark.slow
def test_uneven_seeds_are_refused_naming_what_works_and_the_default_uses_the_devices_that_fit(single_host):
    _, found = single_host
    assert found["uneven"] == "6 seeds do not split evenly over 4 devices: use --seeds 4 or 8, or --devices 3"
    assert found["default_devices"] == 2  # 2 seeds on a 4-device host: the 2 devices that split them evenly


def test_an_mjx_task_stays_on_one_gpu(monkeypatch):
    """MJX over several GPUs crashes XLA (sharding.MJX_OVER_GPUS): the default takes one GPU and
    says why; asking for more is refused naming the option and the fix. The analytic tasks and
    CPU devices spread as ever."""
    import types

    import jax

    from agents import sharding

    gpus = [types.SimpleNamespace(platform="gpu", id=i) for i in range(2)]
    monkeypatch.setattr(jax, "local_devices", lambda: gpus)
    with pytest.warns(UserWarning, match=r"cartpole-mjx: training on 1 of 2 GPUs: an MJX task's step"):
        assert sharding.choose_devices(4, mjx_task="cartpole-mjx") == gpus[:1]
    with pytest.raises(ValueError, match=r"--devices 2: an MJX task's step, spread over several GPUs .* use --devices 1"):
        sharding.choose_devices(4, 2, mjx_task="cartpole-mjx")
    assert sharding.choose_devices(4, 1, mjx_task="cartpole-mjx") == gpus[:1]
    assert sharding.choose_devices(4) == gpus  # the analytic CartPole
    cpus = [types.SimpleNamespace(platform="cpu", id=i) for i in range(2)]
    monkeypatch.setattr(jax, "local_devices", lambda: cpus)
    assert sharding.choose_devices(4, mjx_task="cartpole-mjx") == cpus


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def without_gloo_logs(stdout: str) -> str:
    """`stdout` less the lines JAX's CPU collectives (Gloo) print from their own threads, such
    as `[Gloo] Rank 2 is connected to 3 peer ranks. ...`; they can arrive split in two and
    interleaved with the process's own lines, so they are cut out piece by piece."""
    for piece in (r"Expected number of connected peer ranks is : ?\d*", r"\[Gloo\] Rank ",
                  r"\d* ?is connected to ?\d*", r" ?peer ranks\. ?"):  # seen split after each, the numbers too
        stdout = re.sub(piece, "", stdout)
    return stdout


@pytest.mark.slow
def test_two_processes_with_jax_distributed_train_and_write_one_output_directory(tmp_path, single_host):
    out = tmp_path / "run"
    port = free_port()
    command = [sys.executable, "-m", "agents.cli", "train", "--distributed", "--env", "cartpole", "--seeds", str(SEEDS),
               "--out", str(out), "--rerun", str(tmp_path / "train.rrd"), "--rerun-every", "1", "--judge-every", "1",
               *SMALL_FLAGS]
    processes = [subprocess.Popen(command, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                  env={**environment(2), "JAX_COORDINATOR_ADDRESS": f"127.0.0.1:{port}",
                                       "JAX_NUM_PROCESSES": "2", "JAX_PROCESS_ID": str(index)})
                 for index in range(2)]
    outputs = []
    for process in processes:
        try:
            outputs.append(process.communicate(timeout=600))
        finally:
            process.kill()
    for process, (stdout, stderr) in zip(processes, outputs):
        assert process.returncode == 0, stdout[-2000:] + stderr[-4000:]
    reports = [[line for line in without_gloo_logs(stdout).splitlines()
                if line.strip() and not line.startswith("[Gloo]") and not line.strip().isdigit()]  # a Gloo count, split off
               for stdout, _ in outputs]
    assert "spread over 4 of 4 devices" in reports[0] and reports[1] == []  # process 0 reports, for both
    result = json.loads((out / "eval.json").read_text())
    assert result["devices"] == 4 and len(result["mean_return"]) == SEEDS
    # The same agents as the 8 seeds on one device.
    one = json.loads((single_host[0] / "one/eval.json").read_text())
    assert (result["mean_return"], result["solve_step"]) == (one["mean_return"], one["solve_step"])
    assert len((out / "metrics.jsonl").read_text().splitlines()) == 2
    assert (tmp_path / "train.rrd").stat().st_size > 0


def test_sweep_refuses_shape_fields_and_resume_of_the_other_kind(tmp_path, capsys):
    from agents import DQNConfig
    from agents.cli import main

    with pytest.raises(SystemExit) as refused:
        main(["sweep", "--env", "cartpole", "--batch_size", "32,64", "--learning_rate", "1e-3,2e-3"])
    assert refused.value.code == 2
    assert "--batch_size cannot be swept" in str(refused.value) and "learning_rate, gamma, polyak_tau" in str(refused.value)
    with pytest.raises(SystemExit, match="needs at least one field"):
        main(["sweep", "--env", "cartpole", "--seeds", "2"])
    run = tmp_path / "run"
    run.mkdir()
    config = dataclasses.asdict(DQNConfig(**SMALL))
    (run / "config.json").write_text(json.dumps({"env": "cartpole", "seeds": 1, "seed": 0, "config": config}))
    with pytest.raises(SystemExit, match="holds a `mjxsuite train` run; continue it with `mjxsuite train"):
        main(["sweep", "--out", str(run), "--resume"])


@pytest.mark.heavy
def test_the_gpu_scaling_benchmark_runs_at_tiny_sizes_on_two_cpu_devices(tmp_path):
    tiny = ["--total_steps", "400", "--eval_every", "200", "--learning_starts", "64", "--batch_size", "32",
            "--buffer_size", "256", "--eval_episodes", "2", "--hidden", "16"]
    done = subprocess.run([sys.executable, "-m", "benchmarks.scaling", "--env", "cartpole", "--seeds", "4",
                           "--sweep-configs", "4", "--sweep-seeds", "2", "--chunks", "1", "--json", "out.json", *tiny],
                          env=environment(2), cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    records = json.loads((tmp_path / "out.json").read_text())
    assert [(r["workload"], r["agents"], r["devices"]) for r in records] == \
        [("seeds", 4, 1), ("seeds", 4, 2), ("sweep", 8, 1), ("sweep", 8, 2)]
    assert all(r["agent_steps_per_s"] > 0 for r in records) and records[0]["ratio_to_one_device"] == 1.0


@pytest.mark.heavy
def test_the_whole_process_benchmark_records_a_warm_caches_run_in_processes_with_each_process_breakdown():
    """`--whole-process --warm-cache` times the second of two identical processes, whose first filled the
    compilation cache, and a run in processes records each process's own breakdown."""
    from benchmarks.scaling import whole_process

    tiny = ("--env cartpole --seeds 2 --processes 2 --steps 400 --eval_every 200 --learning_starts 64 --batch_size 32 "
            "--buffer_size 256 --eval_episodes 2 --hidden 16")
    fresh, warm = (whole_process(tiny, 1, 600.0, warm_cache=warm) for warm in (False, True))
    assert (fresh["compile_cache"], warm["compile_cache"]) == ("fresh", "warm")
    assert warm["agents"] == 2 and len(warm["processes_parts_s"]) == 2
    assert all(parts["wall"] > parts["compile"] > 0 for parts in warm["processes_parts_s"])
    # the warm processes load what the first compiled instead of compiling it
    assert max(p["compile"] for p in warm["processes_parts_s"]) < min(p["compile"] for p in fresh["processes_parts_s"])
    assert warm["most_overflowed_steps"] == {"contacts": 0, "constraints": 0}


def test_the_whole_process_benchmark_records_the_most_overflowed_steps_of_any_process(tmp_path):
    """A figure of a MuJoCo Warp run carries how many steps overflowed Warp's buffers, read from
    every process's metrics (chunks the judge skipped record none)."""
    from benchmarks.scaling import most_overflowed_steps

    lines = {"p0": [{"chunk": 0, "overflow_contacts": [0, 3], "overflow_constraints": [1, 0]}, {"chunk": 1}],
             "p1": [{"chunk": 0, "overflow_contacts": [2, 0], "overflow_constraints": [0, 7]}]}
    for name, records in lines.items():
        (tmp_path / name).mkdir()
        (tmp_path / name / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))
    assert most_overflowed_steps([tmp_path / "p0", tmp_path / "p1"]) == {"contacts": 3, "constraints": 7}


def test_the_whole_process_benchmark_times_each_counts_share_of_the_seeds_on_one_device(monkeypatch):
    """`--shares`: beside K devices' run, one device trains a K-th of the seeds, the best K devices can give."""
    from benchmarks import scaling

    timed = []  # (seeds, devices) of every process timed

    def fake(train_args, devices, timeout, warm_cache=False):
        words = train_args.split()
        seeds = int(words[words.index("--seeds") + 1])
        timed.append((seeds, devices))
        return {"process_s": 10.0 + seeds / devices, "agents": seeds, "parts_s": {}}

    monkeypatch.setattr(scaling, "whole_process", fake)
    records = scaling.whole_process_scaling("--env cartpole --seeds 80 --steps 400", [1, 2, 4], 60.0, shares=True)
    assert timed == [(80, 1), (80, 2), (40, 1), (80, 4), (20, 1)]
    two, four = records[1], records[2]
    assert two["best_ratio"] == 90.0 / 50.0 and two["of_best"] == 1.0  # 80 seeds over 2 devices cost what 40 on one do
    assert four["best_ratio"] == 90.0 / 30.0 and four["one_device_share"]["agents"] == 20
    assert scaling.with_seeds("--env cartpole --seeds 80 --steps 400", 20) == "--env cartpole --seeds 20 --steps 400"
    with pytest.raises(SystemExit, match="--seeds"):
        scaling.with_seeds("--env cartpole", 2)


@pytest.mark.heavy
def test_the_two_gpu_mjx_reproducer_runs_its_cases_on_two_cpu_devices():
    """benchmarks.two_gpu_mjx's bare case (what goes upstream) compiles and runs where XLA does not crash."""
    from benchmarks import two_gpu_mjx

    status, output = two_gpu_mjx.run_case("bare-step", 4)
    assert status == 0, output
    assert "CpuDevice(id=1)" in output
