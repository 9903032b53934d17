"""benchmarks.network_traffic at tiny sizes: XLA's byte counts are at least what the
programs must move by their arrays' sizes, and each floor is those bytes at the measured bandwidth."""

import json

import jax
import pytest

from benchmarks import network_traffic


@pytest.mark.heavy  # a benchmark script end to end (make test-slow, which CI runs)
def test_network_traffic_counts_at_least_the_arrays_each_program_must_move(tmp_path, capsys):
    target = tmp_path / "traffic.json"
    network_traffic.main(["--agents", "3", "--stream-mib", "4", "--json", str(target)])
    rows = {r["program"]: r for r in json.loads(target.read_text())}
    bandwidth = rows.pop("stream x * 2 + 1")["bytes_per_s"]
    assert set(rows) == {"act forward", "target forward", "update forward+backward", "adam"}
    _, programs = network_traffic.programs("10 envs", 3)
    params = programs["act forward"][1][0]
    param_bytes = sum(leaf.nbytes for leaf in jax.tree.leaves(params))
    # Lower bounds by array sizes: a forward reads every parameter; the gradient also writes
    # one per parameter; Adam reads parameters, gradients and both moments and writes three.
    must_move = {"act forward": param_bytes, "target forward": param_bytes,
                 "update forward+backward": 2 * param_bytes, "adam": 7 * param_bytes}
    for name, row in rows.items():
        assert row["bytes_accessed"] >= must_move[name], name
        assert row["floor_us"] == pytest.approx(row["bytes_accessed"] / bandwidth * 1e6)
        assert row["us"] > 0 and row["agents"] == 3 and row["hidden"] == [120, 84]
    assert "| update forward+backward |" in capsys.readouterr().out


def test_network_traffic_rejects_a_bad_agent_count(capsys):
    with pytest.raises(SystemExit):
        network_traffic.main(["--agents", "0"])
    assert "--agents 0" in capsys.readouterr().err
