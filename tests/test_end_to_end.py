"""benchmarks.end_to_end: our command is the issue's (PureJaxRL's settings, our defaults, --out),
the peer gets the same work, both orders run with a warm-up before every timed process, and
`--tiny` runs both whole processes on a CPU."""

import json
from pathlib import Path

import pytest

from benchmarks import end_to_end

# The peer lives outside the project (never copied in): the workspace's shared/peers beside the checkout.
PEER = next((p for p in (Path(__file__).resolve().parents[i] / "shared" / "peers" / "purejaxrl_dqn.py" for i in (2, 3))
             if p.is_file()), Path("shared/peers/purejaxrl_dqn.py"))
ISSUE_COMMAND = ("train --env cartpole --seeds 2048 --steps 500000 --num_envs 10 --batch_size 128 --buffer_size 10000 "
                 "--hidden 120,84 --learning_rate 0.00025 --learning_starts 10000 --exploration_steps 250000 "
                 "--target_update hard --target_period 50 --max_grad_norm none --double_dqn false --out RUN --overwrite")


def test_the_full_size_commands_are_pure_jax_rl_settings_with_our_defaults():
    """No --eval_every, no --no-compile-cache: the judge and save clocks are the command's own."""
    assert " ".join(end_to_end.our_command(2048, 500_000, 10_000, 250_000, "RUN")) == ISSUE_COMMAND
    peer = end_to_end.peer_config(2048, 500_000, 10_000, 250_000)
    assert peer["TARGET_UPDATE_INTERVAL"] == 500 and peer["TOTAL_TIMESTEPS"] == 500_000 and peer["NUM_ENVS"] == 10
    assert peer["NUM_SEEDS"] == 2048


def _peer_file(tmp_path):
    path = tmp_path / "peer.py"
    path.write_text("def make_train(config): ...\n")
    return path


def test_tiny_sets_the_cpu_sizes_and_too_few_steps_are_refused(tmp_path, capsys):
    args = end_to_end.parse_args(["--peer", str(_peer_file(tmp_path)), "--tiny"])
    assert (args.seeds, args.steps, args.learning_starts, args.exploration_steps) == (2, 2000, 200, 200)
    assert end_to_end.parse_args(["--peer", str(_peer_file(tmp_path))]).seeds == 2048
    with pytest.raises(SystemExit):
        end_to_end.parse_args(["--peer", str(_peer_file(tmp_path)), "--tiny", "--steps", "500"])
    assert "give at least 1000" in capsys.readouterr().err


def test_both_orders_run_with_a_warm_up_before_every_timed_process(tmp_path, monkeypatch):
    happened = []
    monkeypatch.setattr(end_to_end, "_run", lambda command, *a, **k: happened.append("warm-up") or (None, 0.0))

    def side(name, seconds):
        def run(args, work):
            happened.append(name)
            return {"process_s": seconds, "device": "cpu"}
        return run

    args = end_to_end.parse_args(["--peer", str(_peer_file(tmp_path)), "--tiny"])
    record = end_to_end.compare(args, {"ours": side("ours", 2.0), "peer": side("peer", 3.0)})
    assert happened == ["warm-up", "ours", "warm-up", "peer", "warm-up", "peer", "warm-up", "ours"]
    assert [r["order"] for r in record["rounds"]] == ["ours first", "peer first"]
    assert record["ratio"] == pytest.approx(1.5) and record["ours_process_s"] == 4.0
    happened.clear()
    args = end_to_end.parse_args(["--peer", str(_peer_file(tmp_path)), "--tiny", "--no-warm-up", "--orders",
                                  "peer first"])
    assert end_to_end.compare(args, {"ours": side("ours", 2.0), "peer": side("peer", 3.0)})["warm_up"] == "none"
    assert happened == ["peer", "ours"]


def test_the_breakdown_is_read_from_our_last_line():
    line = "wall 12.3s = start-up 1.0 + compile 4.0 + train 6.0 + judge 0.5 + saves 0.3 + evaluation 0.2 + other 0.3 s; wrote r"
    assert end_to_end.wall_parts(line) == {"start-up": 1.0, "compile": 4.0, "train": 6.0, "judge": 0.5, "saves": 0.3,
                                           "evaluation": 0.2, "other": 0.3}


@pytest.mark.slow  # four processes that compile (about a minute on 2 cores)
def test_tiny_runs_both_whole_processes_in_both_orders(tmp_path):
    pytest.importorskip("gymnax")
    pytest.importorskip("flashbax")
    if not PEER.is_file():
        pytest.skip(f"no peer file at {PEER}")
    record = end_to_end.main(["--peer", str(PEER), "--tiny", "--json", str(tmp_path / "e.json")])
    assert json.loads((tmp_path / "e.json").read_text()) == record
    for round in record["rounds"]:
        ours, peer = round["ours"], round["peer"]
        assert ours["agents"] == 2 and {"start-up", "compile", "train", "judge", "saves", "evaluation",
                                        "other"} == set(ours["parts_s"])
        assert sum(ours["parts_s"].values()) <= ours["process_s"] + 0.5  # the parts are inside the process's time
        assert 0 < peer["make_train_s"] < peer["process_s"] and peer["config"]["NUM_SEEDS"] == 2
        assert 0 <= ours["judge_and_saves_share"] < 1 and ours["judged_chunks"] >= 1
    assert record["ratio"] == pytest.approx(record["peer_process_s"] / record["ours_process_s"])
