"""benchmarks.warp_contact at tiny sizes: the GPU script runs; on a machine without MuJoCo Warp
its Warp rows say why they were skipped (tests/test_warp.py runs Warp itself on the CPU)."""

import json

import pytest

from benchmarks import warp_contact


@pytest.mark.heavy  # issue #29: out of the default run (make test <= 8 min); a GPU benchmark's smoke run (~17 s)
def test_warp_contact_runs_at_tiny_sizes(tmp_path, capsys):
    target = tmp_path / "warp.json"
    warp_contact.main(["--envs", "2", "--steps", "2", "--sizes", "2", "--scan-steps", "2", "--repeats", "1",
                       "--ppo-steps", "0", "--json", str(target)])
    records = json.loads(target.read_text())
    rates = {(r["env"], r["impl"]): r.get("physics_steps_per_s") for r in records
             if r["kind"] == "warp-contact-throughput"}
    assert rates[("cartpole-mjx", "jax")] > 0 and rates[(warp_contact.contact_task_name(), "jax")] > 0
    # MJX's JAX implementation has no buffers to overflow: its rows count none
    assert all(r["overflow_steps"] == 0 for r in records
               if r["kind"] == "warp-contact-throughput" and r["impl"] == "jax")
    missing = warp_contact.warp_missing()
    if missing:
        assert all(r["skipped"] == missing for r in records if r.get("impl", "warp") == "warp")
    assert "(c) cartpole-mjx" in capsys.readouterr().out
