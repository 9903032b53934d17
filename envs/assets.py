"""Finding and loading MJCF models.

Installed from a wheel, the models live in `envs/assets/` (the build maps the
checkout's top-level `assets/` there); in a source checkout they are read from
`assets/` directly.
"""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path

import mujoco

_PACKAGE_DIR = Path(__file__).resolve().parent
ASSET_DIRS = (_PACKAGE_DIR / "assets", _PACKAGE_DIR.parent / "assets")


def asset_path(name: str | os.PathLike) -> Path:
    """Resolve a model file: an existing path as given, else a file name in the suite's assets."""
    path = Path(name)
    if path.is_file():
        return path
    for directory in ASSET_DIRS:
        if (directory / path).is_file():
            return directory / path
    available = sorted({p.name for d in ASSET_DIRS if d.is_dir() for p in d.glob("*.xml")})
    raise FileNotFoundError(f"MJCF file {str(name)!r} not found; the suite's assets are {available}")


def gymnasium_asset(file_name: str) -> Path:
    """An MJCF file of Gymnasium's MuJoCo tasks, read from the installed `gymnasium` package
    (never copied into this repo). Found without importing Gymnasium's MuJoCo envs, which need
    imageio even when nothing is rendered."""
    spec = importlib.util.find_spec("gymnasium")
    if spec is None or spec.origin is None:
        raise ModuleNotFoundError(f"Gymnasium's MuJoCo tasks load {file_name} from the installed gymnasium "
                                  "package: pip install gymnasium==1.4.0")
    path = Path(spec.origin).parent / "envs" / "mujoco" / "assets" / file_name
    if not path.is_file():
        raise FileNotFoundError(f"{file_name} is not in the installed gymnasium package ({path.parent}); "
                                "mjxsuite is checked with gymnasium==1.4.0")
    return path


def load_model(name: str | os.PathLike) -> mujoco.MjModel:
    """Load an MJCF model; a parse or compile error names the file and gives MuJoCo's reason."""
    path = asset_path(name)
    try:
        return mujoco.MjModel.from_xml_path(str(path))
    except ValueError as err:
        raise ValueError(f"MuJoCo could not load {path}: {err}") from err


def dm_control_asset(file_name: str) -> Path:
    """An MJCF file of dm_control's suite (`dm_control/suite/<file_name>`), read from the installed
    `dm_control` package (never copied into this repo). Found without importing dm_control, which
    needs its mujoco 4 shim (`envs.interop.dm_control`) before it loads a model: MuJoCo reads the
    file and its `./common/*.xml` includes itself."""
    spec = importlib.util.find_spec("dm_control")
    if spec is None or spec.origin is None:
        raise ModuleNotFoundError(f"the DeepMind Control Suite tasks load {file_name} from the installed "
                                  "dm_control package: pip install 'mjxsuite[dmc]' (dm-control==1.0.50)")
    path = Path(spec.origin).parent / "suite" / file_name
    if not path.is_file():
        raise FileNotFoundError(f"{file_name} is not in the installed dm_control package ({path.parent}); "
                                "mjxsuite is checked with dm-control==1.0.50")
    return path
