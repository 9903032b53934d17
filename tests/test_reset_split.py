"""benchmarks.reset_split: each episode's start and return come from one dm_control seed, counted by side."""

import numpy as np
import pytest

import envs
from agents.checkpoint import SavedRun
from benchmarks import reset_split


def still(observation):  # hopper stand's actuators at rest: the return is what the fall from the reset earns
    return np.zeros(4)


def test_each_episodes_start_and_return_are_dm_controls_of_one_seed(monkeypatch):
    monkeypatch.setattr("agents.checkpoint.load_config", lambda run: SavedRun("dmc-hopper-stand", 1, None, {}, 0))
    monkeypatch.setattr("agents.load_policy", lambda run, seed_index=None: still)
    [(seed, episodes)] = reset_split.split_returns("runs/x", "rooty", 3, 2000)
    assert seed == 0 and len(episodes) == 3
    for first_seed, (start, total) in zip(range(2000, 2003), episodes):
        theirs = envs.load_dm_control("hopper", "stand", first_seed)
        step, expected = theirs.reset(), 0.0
        assert start == theirs.physics.named.data.qpos["rooty"][0]
        while not step.last():
            step = theirs.step(still(None))
            expected += step.reward
        assert total == pytest.approx(expected, abs=1e-9)
    assert len({start for start, _ in episodes}) == 3  # three draws


def test_the_sides_are_counted_apart_and_a_bad_joint_names_the_ones_to_give():
    counts = reset_split.tally([(-0.5, 930.0), (-2.0, 3.0), (0.0, 940.0), (1.2, 600.0), (2.0, 12.0)], 500.0)
    assert counts == {"below_0": 2, "succeeded_below_0": 1, "at_or_above_0": 3, "succeeded_at_or_above_0": 2}
    with pytest.raises(SystemExit, match=r"--joint 'thigh': give a hinge or slide joint of the model, one of "
                                         r"rootx, rootz, rooty, waist, hip, knee, ankle"):
        reset_split.joint_at_reset(envs.load_dm_control("hopper", "stand", 0), "thigh")


def test_a_pixel_run_is_judged_as_the_judge_judges_it_on_dm_controls_pictures(monkeypatch):
    options = {"observation": "pixels", "width": 32, "height": 32, "action_repeat": 4, "impl": "warp"}
    monkeypatch.setattr("agents.checkpoint.load_config", lambda run: SavedRun("dmc-hopper-stand", 1, None, options, 0))
    monkeypatch.setattr("agents.load_policy", lambda run, seed_index=None: still)
    judged = []  # the env each episode is judged with
    monkeypatch.setattr("envs.returns_on_dm_control", lambda policy, env, *_: judged.append(env) or [0.0])
    [(_, [(_, total)])] = reset_split.split_returns("runs/x", "rooty", 1, 2000)
    camera = envs.DmControlCamera.of(judged[0])
    assert total == 0.0 and (camera.width, camera.height, camera.action_repeat) == (32, 32, 4)
