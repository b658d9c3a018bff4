"""`fetchbench envs ...`: list the registered env ids, render an episode's views."""
from __future__ import annotations


def _list(args) -> int:
    from . import ENV_KWARGS

    for env_id, kwargs in ENV_KWARGS.items():
        what = ", ".join(f"{k}={v}" for k, v in kwargs.items()) or "any scene type, any target"
        print(f"{env_id:36s} {what}")
    return 0


def _render(args) -> int:
    import numpy as np
    from PIL import Image

    from ..utils.io import atomic_write_bytes
    from . import make

    env = make(args.env_id, obs_mode="rgb", render_mode="rgb_array",
               camera_width=args.width, camera_height=args.height)
    try:
        obs, info = env.reset(seed=args.seed)
        views = [obs["sensor_data"][f"{side}_camera"]["rgb"][0].cpu().numpy() for side in ("left", "right")]
        human = np.asarray(Image.fromarray(env.render()[0].cpu().numpy()).resize((args.height, args.height)))
        sheet = np.concatenate([views[0], human, views[1]], axis=1)
        import io

        buffer = io.BytesIO()
        Image.fromarray(sheet).save(buffer, format="PNG")
        atomic_write_bytes(args.out, buffer.getvalue())
        task = env.unwrapped.tasks[0]
        print(f"wrote {args.out}: left camera | overview | right camera; {task.scene_type}, "
              f"target {task.target.object_id} ({task.target_label})")
    finally:
        env.close()
    return 0


def add_commands(subparsers) -> None:
    envs = subparsers.add_parser("envs", help="FetchBench-*-v0 environments: list, render")
    sub = envs.add_subparsers(dest="envs_command", required=True, metavar="ACTION")
    sub.add_parser("list", help="registered env ids and what they fix").set_defaults(func=_list)
    r = sub.add_parser("render", help="the two cameras and an overview of one episode, as a PNG")
    r.add_argument("--env-id", default="FetchBench-v0")
    r.add_argument("--seed", type=int, default=0)
    r.add_argument("--width", type=int, default=320)
    r.add_argument("--height", type=int, default=240)
    r.add_argument("--out", required=True)
    r.set_defaults(func=_render)
