"""benchmarks.picture_swap's arguments (its pictures need warp-lang and headless OpenGL: a diagnostic run by hand)."""

import pytest

from benchmarks import picture_swap


def test_an_unknown_variant_is_refused_naming_the_choices(capsys):
    with pytest.raises(SystemExit):
        picture_swap.main(["--run", "runs/x", "--variants", "warp,dm_floors"])
    err = capsys.readouterr().err
    assert "['dm_floors'] unknown" in err and "dm_floor" in err and "dm_plain" in err
