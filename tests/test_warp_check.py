"""benchmarks.warp_check at tiny sizes: the GPU check script runs, and on a machine without
MuJoCo Warp its Warp rows say why they were skipped."""

import json

import pytest

from benchmarks import warp_check


@pytest.mark.heavy  # a benchmark script end to end (make test-slow, which CI runs)
def test_warp_check_runs_at_tiny_sizes(tmp_path, capsys):
    target = tmp_path / "warp.json"
    warp_check.main(["--sizes", "4", "--steps", "3", "--repeats", "1", "--json", str(target)])
    records = json.loads(target.read_text())
    rates = {r["label"]: r.get("steps_per_s") for r in records if r["kind"] == "warp-throughput"}
    assert rates["cartpole-mjx impl=jax"] > 0 and rates["cartpole-mjx randomized"] > 0
    assert {r["env"] for r in records if r["kind"] == "warp-vs-jax"} == {"cartpole-mjx", "acrobot-mjx"}
    missing = warp_check.warp_missing()
    for r in records:
        if "warp" in r.get("label", r["kind"]) and missing:
            assert r["skipped"] == missing
    assert "randomized / plain cost" in capsys.readouterr().out
