"""Which part of our pictures a pixel policy cannot do without: a seed of a pixel run on a dm_control task, driven on
dm_control's own env as the judge does, seeing composites of MuJoCo Warp's pictures and dm_control's.

    MUJOCO_GL=egl python -m benchmarks.picture_swap --run DIR [--seed 0] [--episodes 2]
        [--variants warp,dm_control,dm_plain,dm_sky,dm_floor,dm_body] [--json FILE]

Variants: `warp` (MuJoCo Warp's pictures of dm_control's physics state, as the run trained on), `dm_control` (the
judge's pictures), `dm_plain` (dm_control's with every material's reflectance and every light's shadows off, as
Warp draws them by default), and `dm_sky` / `dm_floor` / `dm_body`: Warp's picture with the pixels of that part taken from
dm_control's (the part by Warp's segmentation: no geom hit, the geom named by `--floor`, every other geom). A
return that holds under `warp` and falls under `dm_floor` says the policy reads something of the floor that the two
renderers draw differently. Warp's pictures come from mujoco_warp itself on warp-lang's default device: a CUDA GPU,
or this machine's CPU (warp-lang installed: `pip install warp-lang`).
"""

from __future__ import annotations

import argparse
import dataclasses
import json

import numpy as np

from benchmarks.suite import append_record

VARIANTS = ("warp", "dm_control", "dm_plain", "dm_sky", "dm_floor", "dm_body")


def chosen_variants(parser: argparse.ArgumentParser, text: str, choices: tuple[str, ...]) -> list[str]:
    """`--variants`' comma-separated names, each one of `choices` (else the parser's error naming them)."""
    variants = text.split(",")
    if unknown := set(variants) - set(choices):
        parser.error(f"--variants: {sorted(unknown)} unknown; choose from {','.join(choices)}")
    return variants


def warp_pictures(env, camera, shadows: bool, floor: str):
    """`picture(physics)`: Warp's uint8 picture of dm_control's physics state, rendered as the run's
    `envs.pixels.WarpRenderer` renders, and its sky, floor and body masks (H, W, 1)."""
    import mujoco
    import warp as wp
    from mujoco.mjx.third_party import mujoco_warp as mjw

    from envs.pixels import WarpRenderer

    task = env.unwrapped
    mjm, size = task.mj_model, (camera.height, camera.width)
    floor_id = mujoco.mj_name2id(mjm, mujoco.mjtObj.mjOBJ_GEOM, floor)
    if floor_id < 0:
        raise SystemExit(f"picture_swap: --floor {floor!r} names no geom of {task.name}; give the floor geom's name")
    renderer = WarpRenderer(task, camera.camera, camera.width, camera.height, False, shadows)
    mjd, model = mujoco.MjData(mjm), mjw.put_model(mjm)
    context = mjw.create_render_context(mjm, 1, **renderer.context_options(render_seg=True))
    rgb, seg = wp.zeros((1, *size), dtype=wp.vec3), wp.zeros((1, *size), dtype=wp.vec2i)

    def picture(physics):
        mjd.qpos[:], mjd.qvel[:] = physics.data.qpos, physics.data.qvel
        mujoco.mj_forward(mjm, mjd)
        data = mjw.put_data(mjm, mjd, nworld=1)
        mjw.refit_bvh(model, data, context)
        mjw.render(model, data, context)
        mjw.get_rgb(context, 0, rgb)
        mjw.get_segmentation(context, 0, seg)
        geom = seg.numpy()[0][..., :1]
        masks = {"dm_sky": geom < 0, "dm_floor": geom == floor_id, "dm_body": (geom >= 0) & (geom != floor_id)}
        return np.round(np.clip(rgb.numpy()[0], 0, 1) * 255).astype(np.uint8), masks
    return picture


def swap_returns(run: str, seed: int, variants: list[str], episodes: int, floor: str):
    """Yields (variant, returns) for each of `variants`: the run, its policy and Warp's renderer loaded once."""
    import agents
    import envs
    from agents import checkpoint
    from envs import DmControlCamera as Camera, returns_on_dm_control
    from envs.pixels import PIXEL_OPTIONS

    config = checkpoint.load_config(run)
    options = {k: v for k, v in config.env_options.items() if k in PIXEL_OPTIONS}
    env = envs.make(config.env, **options)
    judge = Camera.of(env)
    if judge is None:
        raise SystemExit(f"picture_swap: {run} was trained on state observations; give a run on camera images")
    policy = agents.load_policy(run, seed)
    needs_warp = set(variants) - {"dm_control", "dm_plain"}
    warp = warp_pictures(env, judge, options.get("shadows", False), floor) if needs_warp else None
    for variant in variants:

        @dataclasses.dataclass
        class Composite(Camera):
            renders = variant != "warp"  # dm_control's picture is needed

            def picture(self, physics, variant=variant):
                if variant == "dm_plain":
                    physics.model.mat_reflectance[:], physics.model.light_castshadow[:] = 0.0, False
                if variant in ("dm_control", "dm_plain"):
                    return super().picture(physics)
                ours, masks = warp(physics)
                return ours if variant == "warp" else np.where(masks[variant], super().picture(physics), ours)

        yield variant, returns_on_dm_control(policy, env, episodes, camera=Composite(*dataclasses.astuple(judge)[:5]))


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.picture_swap", description=__doc__.splitlines()[0])
    parser.add_argument("--run", required=True, help="a run directory trained with observation=pixels")
    parser.add_argument("--seed", type=int, default=0, help="which seed's policy")
    parser.add_argument("--episodes", type=int, default=2)
    parser.add_argument("--variants", default=",".join(VARIANTS))
    parser.add_argument("--floor", default="ground", help="the floor geom's name (dm_control's: ground, floor)")
    parser.add_argument("--json", metavar="FILE", help="append the record to FILE (a JSON list)")
    args = parser.parse_args(argv)
    variants = chosen_variants(parser, args.variants, VARIANTS)
    record = {"kind": "picture-swap", "run": args.run, "seed": args.seed, "episodes": args.episodes, "variants": {}}
    for variant, found in swap_returns(args.run, args.seed, variants, args.episodes, args.floor):
        record["variants"][variant] = {"returns": found, "mean": float(np.mean(found))}
        print(json.dumps({variant: record["variants"][variant]}), flush=True)
    if args.json:
        append_record(args.json, record)


if __name__ == "__main__":
    main()
