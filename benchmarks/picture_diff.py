"""How far MuJoCo Warp's pictures are from dm_control's, per part of the picture, on states of a dm_control task.

    MUJOCO_GL=egl python -m benchmarks.picture_diff --env dmc-cheetah-run [--states 24] [--floor ground]
        [--variants warp,shadows,no_spotlight,no_spotlight_reflection] [--json FILE]

dm_control's env is reset and stepped with uniform random actions; every few control steps its physics state is
pictured by dm_control's renderer (OpenGL, the judge's pictures) and by MuJoCo Warp's (the pictures a pixel run
trains on), at the task's pixel size and camera. Reported per variant: the mean absolute difference of the uint8
RGB values over the sky, the floor, the body (by Warp's segmentation) and the whole picture. Variants:
`warp` (as `observation=pixels` trains), `shadows` (`--env-opt shadows=true`), and two that say where a difference
comes from, the model's lights made inactive in both renderers (`no_spotlight`; the headlight stays) and also the
floor's reflectance off in dm_control's (`no_spotlight_reflection`). Warp's pictures come from mujoco_warp on
warp-lang's default device (this machine's CPU where there is no GPU: `pip install warp-lang`).
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from benchmarks.picture_swap import chosen_variants, warp_pictures
from benchmarks.suite import append_record

VARIANTS = ("warp", "shadows", "no_spotlight", "no_spotlight_reflection")
PARTS = ("sky", "floor", "body", "all")


def dm_control_states(dm_env, states: int, every: int, seed: int):
    """`states` (qpos, qvel) of dm_control's env under uniform random actions, one every `every` control steps
    (at most 200 steps an episode, then a new one)."""
    rng, found, data = np.random.default_rng(seed), [], dm_env.physics.data
    while len(found) < states:
        dm_env.reset()
        for step in range(1, 201):
            timestep = dm_env.step(rng.uniform(-1, 1, dm_env.physics.model.nu))
            if step % every == 0 and len(found) < states:
                found.append((data.qpos.copy(), data.qvel.copy()))
            if timestep.last():
                break
    return found


def differences(task: str, variants: list[str], states: int, floor: str, seed: int = 0) -> dict:
    """{variant: {part: mean |Warp - dm_control|}} over `states` states of `task`'s dm_control env."""
    import envs
    from envs import DmControlCamera as Camera, load_dm_control

    env = envs.make(task, observation="pixels")
    camera, mjm = Camera.of(env), env.unwrapped.mj_model
    dm_env = load_dm_control(env.unwrapped.domain, env.unwrapped.task, seed, renders=True)
    physics = dm_env.physics
    reflectance, active = physics.model.mat_reflectance.copy(), mjm.light_active.copy()
    found = dm_control_states(dm_env, states, every=10, seed=seed)
    table = {}
    for variant in variants:
        spotlight = not variant.startswith("no_spotlight")
        mjm.light_active[:] = physics.model.light_active[:] = active * spotlight
        physics.model.mat_reflectance[:] = reflectance * (variant != "no_spotlight_reflection")
        picture = warp_pictures(env, camera, variant == "shadows", floor)
        sums = {part: [] for part in PARTS}
        for qpos, qvel in found:
            physics.data.qpos[:], physics.data.qvel[:] = qpos, qvel
            physics.forward()
            theirs = physics.render(camera.height, camera.width, camera_id=camera.camera).astype(int)
            ours, masks = picture(physics)
            gap = np.abs(ours.astype(int) - theirs).mean(-1)
            for part in PARTS:
                mask = np.ones(gap.shape, bool) if part == "all" else masks["dm_" + part][..., 0]
                if mask.any():
                    sums[part].append(float(gap[mask].mean()))
        table[variant] = {part: round(float(np.mean(v)), 2) if v else None for part, v in sums.items()}
    mjm.light_active[:] = active
    return table


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.picture_diff", description=__doc__.splitlines()[0])
    parser.add_argument("--env", required=True, help="a dm_control task (dmc-*)")
    parser.add_argument("--states", type=int, default=24)
    parser.add_argument("--variants", default=",".join(VARIANTS))
    parser.add_argument("--floor", default="floor", help="the floor geom's name (cheetah's: ground)")
    parser.add_argument("--json", metavar="FILE", help="append the record to FILE (a JSON list)")
    args = parser.parse_args(argv)
    variants = chosen_variants(parser, args.variants, VARIANTS)
    if not args.env.startswith("dmc-"):
        parser.error(f"--env {args.env!r}: not a dm_control task; give a dmc-* task (e.g. dmc-cheetah-run)")
    table = differences(args.env, variants, args.states, args.floor)
    for variant, row in table.items():
        print(json.dumps({variant: row}), flush=True)
    if args.json:
        append_record(args.json, {"kind": "picture-diff", "env": args.env, "states": args.states, "variants": table})


if __name__ == "__main__":
    main()
