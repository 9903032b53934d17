"""benchmarks.end_to_end at tiny sizes: both processes run, our command is the issue's at full
size, the peer gets the same work, and the record holds our wall time's parts."""

from pathlib import Path

import pytest

from benchmarks import end_to_end

# The peer lives outside the project (never copied in): the workspace's shared/peers beside the checkout.
PEER = next((p for p in (Path(__file__).resolve().parents[i] / "shared" / "peers" / "purejaxrl_dqn.py" for i in (2, 3))
             if p.is_file()), Path("shared/peers/purejaxrl_dqn.py"))
ISSUE_COMMAND = ("train --env cartpole --seeds 2048 --steps 500000 --num_envs 10 --batch_size 128 --buffer_size 10000 "
                 "--hidden 120,84 --learning_rate 0.00025 --learning_starts 10000 --exploration_steps 250000 "
                 "--target_update hard --target_period 50 --max_grad_norm none --double_dqn false --eval_every 50000 "
                 "--no-compile-cache")


def test_the_full_size_commands_are_pure_jax_rl_settings():
    assert " ".join(end_to_end.our_command(2048, 500_000, 50_000, 10_000, 250_000)) == ISSUE_COMMAND
    peer = end_to_end.peer_config(2048, 500_000, 10_000, 250_000)
    assert peer["TARGET_UPDATE_INTERVAL"] == 500 and peer["TOTAL_TIMESTEPS"] == 500_000 and peer["NUM_ENVS"] == 10


@pytest.mark.slow  # issue #29: two training processes (~22 s); the commands' settings stay checked above
def test_both_sides_run_at_tiny_sizes(tmp_path):
    pytest.importorskip("gymnax")
    pytest.importorskip("flashbax")
    if not PEER.is_file():
        pytest.skip(f"no peer file at {PEER}")
    record = end_to_end.main(["--peer", str(PEER), "--seeds", "2", "--steps", "400", "--eval-every", "200",
                              "--learning-starts", "200", "--exploration-steps", "200", "--json", str(tmp_path / "e.json")])
    ours, peer = record["ours"], record["peer"]
    assert ours["agents"] == 2 and set(ours["parts_s"]) == {"start-up", "compile", "train", "saves", "evaluation", "other"}
    assert sum(ours["parts_s"].values()) <= ours["process_s"] + 0.5  # the parts are inside the process's time
    assert 0 < peer["compile_s"] < peer["make_train_s"] < peer["process_s"]
    assert record["ratio"] == pytest.approx(peer["make_train_s"] / ours["process_s"])
