"""benchmarks.picture_swap's and picture_diff's arguments (their pictures need warp-lang and headless OpenGL)."""

import pytest

from benchmarks import picture_swap


def test_an_unknown_variant_is_refused_naming_the_choices(capsys):
    with pytest.raises(SystemExit):
        picture_swap.main(["--run", "runs/x", "--variants", "warp,dm_floors"])
    err = capsys.readouterr().err
    assert "['dm_floors'] unknown" in err and "dm_floor" in err and "dm_plain" in err


def test_picture_diff_refuses_an_unknown_variant_and_a_task_outside_dm_control(capsys):
    from benchmarks import picture_diff

    with pytest.raises(SystemExit):
        picture_diff.main(["--env", "dmc-cheetah-run", "--variants", "warp,shadow"])
    assert "['shadow'] unknown" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        picture_diff.main(["--env", "hopper"])
    assert "--env 'hopper': not a dm_control task" in capsys.readouterr().err
