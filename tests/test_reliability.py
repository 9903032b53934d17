"""Reliability over seeds (`benchmarks.reliability`): the median, the interquartile mean and the
worst seed, checked against cases computed by hand, and the two benchmark reports that print them."""

import pytest

from benchmarks import gym_training, learning, reliability


def test_eight_seeds_by_hand():
    # sorted: 1 2 3 4 5 6 7 100; the IQM keeps the middle four (3, 4, 5, 6): one far seed moves nothing
    assert reliability.over_seeds([100, 1, 7, 3, 5, 2, 6, 4]) == {"seeds": 8, "median": 4.5, "iqm": 4.5, "worst": 1.0}


def test_five_seeds_by_hand():
    # sorted: 0 2 4 10 1000; int(0.25 * 5) = 1 seed cut from each end, so the IQM is (2 + 4 + 10) / 3
    found = reliability.over_seeds([10, 0, 4, 2, 1000])
    assert found["median"] == 4.0 and found["worst"] == 0.0
    assert found["iqm"] == pytest.approx(16 / 3)


def test_one_seed_is_its_own_median_iqm_and_worst():
    assert reliability.over_seeds([3.5]) == {"seeds": 1, "median": 3.5, "iqm": 3.5, "worst": 3.5}


@pytest.mark.parametrize("returns", [[], [[1.0, 2.0]]])
def test_anything_but_one_return_per_seed_is_refused(returns):
    with pytest.raises(ValueError, match="one return per seed"):
        reliability.over_seeds(returns)


def test_the_reports_print_the_iqm():
    seeds = [3100.0, 2900.0, 3300.0, 3500.0]
    trained = {"command": "mjxsuite train --env hopper --agent td3 --seeds 4", "env": "Hopper-v5", "agent": "td3",
               "wall_s": 500.0, "return_here": 3400.0, "return_on_gymnasium": 3500.0, "seeds_on_gymnasium": seeds,
               "median_on_gymnasium": 3200.0, "iqm_on_gymnasium": 3200.0, "worst_on_gymnasium": 2900.0}
    assert "(median 3200, IQM 3200, worst 2900)" in gym_training.line(trained)
    case = {"case": "td3-hopper", "solved": 3, "seeds": 4, "goal": 3000.0, "must_solve": 4, "median": 3200.0,
            "iqm": 3200.0, "worst": 2900.0, "wall_s": 500.0, "solve_steps": [None] * 4}
    assert "median 3200.0, IQM 3200.0, worst 2900.0" in learning.line(case)
    assert learning._spread(seeds) == {"median": 3200.0, "iqm": 3200.0, "worst": 2900.0}


def test_gym_training_keeps_the_records_when_a_second_interrupt_arrives_while_the_runs_save():
    """An outer time bound's SIGINT reaches the benchmark while it waits for its Ctrl-C'd trainings to
    save: every record still comes back, with its wall time and why it ended, for `describe` to read."""
    import subprocess

    class Training:  # still running at its time; then saving, where the second interrupt may find it
        def __init__(self, interrupt):
            self.interrupt, self.returncode, self.waits = interrupt, None, 0

        def wait(self, timeout=None):
            self.waits += 1
            if self.waits == 1:
                raise subprocess.TimeoutExpired("train", timeout)
            if self.waits == 2 and self.interrupt:
                raise KeyboardInterrupt
            self.returncode = -2

        def send_signal(self, signal):
            pass

    trainings = [Training(interrupt=True), Training(interrupt=False)]
    started = [({"out": f"run{i}", "started": 0.0}, t) for i, t in enumerate(trainings)]
    try:
        records = gym_training.stop(started, timeout=0.0)
    except KeyboardInterrupt:
        pytest.fail("the second interrupt escaped gym_training.stop, and with it every record")
    assert [r["out"] for r in records] == ["run0", "run1"] and all(r["wall_s"] > 0 for r in records)
    assert "second interrupt" in records[0]["interrupted"] and records[1]["interrupted"] == "stopped after 0 s"
    assert not any("skipped" in r for r in records)


def test_gym_training_kills_a_training_that_does_not_stop_and_keeps_its_stacks(monkeypatch):
    """A training stuck where its Python handlers never run (here: one that ignores SIGINT) would hold
    the benchmark, and the GPU, for good: after SAVE_WAIT_S it prints its threads' stacks through
    `agents.signals.dump_stacks_on_signal` (faulthandler's C handler) and is killed, its record saying so."""
    import signal
    import subprocess
    import sys
    import time

    child = ("import signal, time\nfrom agents import signals\nsignals.dump_stacks_on_signal()\n"
             "signal.signal(signal.SIGINT, signal.SIG_IGN)\n"
             "def stuck_in_a_device_call():\n    while True: time.sleep(0.05)\n"
             "print('ready', flush=True)\nstuck_in_a_device_call()\n")
    training = subprocess.Popen([sys.executable, "-c", child], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert training.stdout.readline() == "ready\n"
    monkeypatch.setattr(gym_training, "SAVE_WAIT_S", 0.5)
    monkeypatch.setattr(gym_training, "STACKS_WAIT_S", 1.0)
    start = time.perf_counter()
    [record] = gym_training.stop([({"out": "run0", "started": start}, training)], timeout=0.0)
    assert training.returncode == -signal.SIGKILL and time.perf_counter() - start < 30
    assert "did not stop when asked" in record["interrupted"] and "skipped" not in record
    assert "stuck_in_a_device_call" in training.stderr.read()
