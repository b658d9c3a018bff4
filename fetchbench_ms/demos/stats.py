"""What a demonstration file holds (``fetchbench demos stats``) and a video of one of its
trajectories (``fetchbench demos show``)."""
from __future__ import annotations

import json
from collections import Counter
from pathlib import Path

import numpy as np

from ..tasks.spec import CATEGORY_LABELS

CATEGORY_ORDER = tuple(CATEGORY_LABELS.values())  # on_table, on_shelf, in_drawer, in_basket
#: Attribute of a merged .h5's root: the sha256 of the .json written with it. The two files
#: are renamed into place one after the other, so a kill between the renames leaves a new
#: .h5 beside the old .json; readers compare this to the .json and refuse such a pair.
PAIR_ATTR = "fetchbench_json_sha256"


def resolve(path: str | Path) -> Path:
    """The .h5 of a trajectory file given as .h5, .json or a folder holding exactly one."""
    path = Path(path)
    if path.is_dir():
        found = sorted(path.rglob("*.h5"))
        found = [p for p in found if not any(part.endswith(".parts") for part in p.parts)]
        if len(found) != 1:
            raise ValueError(f"{path} holds {len(found)} trajectory files"
                             + (f" ({', '.join(str(p) for p in found[:5])})" if found else "") + "; name one")
        return found[0]
    if path.suffix == ".json":
        path = path.with_suffix(".h5")
    if not path.exists() or not path.with_suffix(".json").exists():
        raise FileNotFoundError(f"no trajectory {path} with its .json beside it")
    return path


def _episodes(path: Path) -> list[dict]:
    return json.loads(path.with_suffix(".json").read_text())["episodes"]


def load_trajectory_json(path: str | Path) -> dict:
    """The .json of a trajectory file, or ValueError naming what is wrong with it."""
    json_path = Path(path).with_suffix(".json")
    try:
        data = json.loads(json_path.read_text())
    except (UnicodeDecodeError, json.JSONDecodeError) as error:
        raise ValueError(f"{json_path} is not a trajectory JSON ({error})") from None
    if not isinstance(data, dict) or not isinstance(data.get("episodes"), list):
        raise ValueError(f"{json_path} is not a ManiSkill trajectory JSON (no 'episodes' list)")
    return data


def check_trajectory_file(path: str | Path) -> dict:
    """The checked .json of trajectory file ``path`` (.h5, .json or a folder holding one):
    ValueError with the reason when the .h5 cannot be opened (truncated, not HDF5), when the
    pair was not written together (``PAIR_ATTR``), or when the .h5 lacks a trajectory the
    .json lists (or holds one it does not) or its actions are not the length the .json says."""
    import h5py

    from ..utils.io import sha256_file

    path = resolve(path)
    data = load_trajectory_json(path)
    try:
        f = h5py.File(path, "r")
    except OSError as error:  # truncated, not an HDF5 file at all, unreadable
        reason = str(error).split("(", 1)[-1].rstrip(")") if "(" in str(error) else str(error)
        raise ValueError(f"{path} is not a readable trajectory file ({reason}); regenerate it (`fetchbench demos "
                         "run` with the same flags resumes and rewrites it) or copy it again") from None
    with f:
        pair = f.attrs.get(PAIR_ATTR)
        if pair is not None and (pair.decode() if isinstance(pair, bytes) else str(pair)) != sha256_file(
                path.with_suffix(".json")):
            raise ValueError(f"{path} and its .json were not written together (a run stopped between writing "
                             "the two); rerun the same `fetchbench demos run` (or `demos merge`) command to "
                             "write them again")
        groups = {k for k in f.keys() if k.startswith("traj_")}
        listed = {f"traj_{e['episode_id']}": e for e in data["episodes"]}
        if groups != set(listed):
            missing, extra = sorted(set(listed) - groups), sorted(groups - set(listed))
            problems = []
            if missing:
                problems.append(f"{len(missing)} trajectories its .json lists are absent ({', '.join(missing[:3])})")
            if extra:
                problems.append(f"{len(extra)} trajectories are not in its .json ({', '.join(extra[:3])})")
            raise ValueError(f"{path} does not match its .json: {'; '.join(problems)}; rerun the command that "
                             "wrote them")
        for key, episode in listed.items():
            actions = f[key].get("actions")
            if actions is None or actions.shape[0] != episode.get("elapsed_steps", actions.shape[0]):
                raise ValueError(f"{path}: {key} holds {None if actions is None else actions.shape[0]} actions, "
                                 f"its .json says {episode.get('elapsed_steps')}; rerun the command that wrote it")
    return data


def episode_task_id(episode: dict):
    """A trajectory's task id: the generator's ``task_id``, or the one in its reset options
    (what the replay tool's conversions keep)."""
    options = (episode.get("reset_kwargs") or {}).get("options") or {}
    return episode.get("task_id") or options.get("task_id")


def _suite_labels(task_ids) -> dict:
    """(scene type, category) of each ``SUITE/NNNN`` task id found in its shipped suite."""
    from ..tasks.suite import load_suite, shipped_suite_file

    out = {}
    for name in sorted({str(t).split("/")[0] for t in task_ids if t and "/" in str(t)}):
        if shipped_suite_file(name) is None:
            continue
        suite = load_suite(name)
        for task_id in task_ids:
            if task_id in suite.tasks:
                task = suite.tasks[task_id]
                out[task_id] = (task.scene_type, task.target_label)
    return out


def demo_stats(path: str | Path) -> dict:
    """Counts of a trajectory file: trajectories, frames, tasks, by category and scene type
    (the .h5 is checked against its .json first: ``check_trajectory_file``). A FetchBench
    file only (``fetchbench demos run``'s, or the replay tool's conversion of one, whose
    trajectories carry their task in their reset options: scene type and category are then
    read from the task's suite); another env's file is a ValueError."""
    from ..envs import PLUGIN_MODULE, recorded_env_id

    path = resolve(path)
    data = check_trajectory_file(path)
    env_id = (data.get("env_info") or {}).get("env_id")
    if not isinstance(env_id, str) or not recorded_env_id(env_id).startswith(f"{PLUGIN_MODULE}:"):
        raise ValueError(f"{path} holds trajectories of {env_id or 'no env'!r}, not of a FetchBench env; valid: the "
                         "files `fetchbench demos run` writes and the replay tool's conversions of them")
    eps = data["episodes"]
    steps = np.array([e["elapsed_steps"] for e in eps], dtype=int)
    task_ids = [episode_task_id(e) for e in eps]
    tasks = Counter(task_ids)
    missing = [t for e, t in zip(eps, task_ids) if "scene_type" not in e or "category" not in e]
    labels = _suite_labels(missing) if missing else {}
    by_category = Counter(e.get("category", labels.get(t, (None, None))[1]) for e, t in zip(eps, task_ids))
    by_type = Counter(e.get("scene_type", labels.get(t, (None, None))[0]) for e, t in zip(eps, task_ids))
    cspace = np.array([e["cspace_length"] for e in eps if "cspace_length" in e], dtype=float)
    return {
        "path": str(path),
        "env_id": (data.get("env_info") or {}).get("env_id"),
        "control_mode": eps[0]["control_mode"] if eps else None,
        "trajectories": len(eps),
        "frames": int(steps.sum()),
        "tasks": len(tasks),
        "tasks_tried": (data.get("fetchbench") or {}).get("tasks"),
        "trajectories_per_task": round(len(eps) / len(tasks), 3) if tasks else 0.0,
        "mean_frames": round(float(steps.mean()), 1) if len(steps) else 0.0,
        "mean_cspace_length": round(float(cspace.mean()), 3) if len(cspace) else None,
        "success": int(sum(bool(e.get("success")) for e in eps)),
        "by_category": {c: by_category.get(c, 0) for c in CATEGORY_ORDER},
        "by_scene_type": dict(sorted(by_type.items(), key=lambda kv: str(kv[0]))),
    }


def format_stats(s: dict) -> str:
    lines = [f"{s['path']}: {s['trajectories']} trajectories ({s['success']} successful), {s['frames']} frames, "
             f"{s['tasks']} tasks" + (f" of {s['tasks_tried']} tried" if s.get("tasks_tried") else ""),
             f"  env {s['env_id']}, control mode {s['control_mode']}; {s['trajectories_per_task']} trajectories a "
             f"task, {s['mean_frames']} frames a trajectory, C-space length "
             + (f"{s['mean_cspace_length']} rad" if s["mean_cspace_length"] is not None else "not recorded")]
    lines.append("  by category:   " + ", ".join(f"{c} {n}" for c, n in s["by_category"].items()))
    lines.append("  by scene type: " + ", ".join(f"{'unknown' if t is None else t} {n}"
                                                 for t, n in s["by_scene_type"].items()))
    return "\n".join(lines)


def plot_stats(path: str | Path, png: str | Path) -> Path:
    """Histograms of trajectory length (frames) and C-space length (rad)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    eps = _episodes(resolve(path))
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.2))
    axes[0].hist([e["elapsed_steps"] for e in eps], bins=30, color="tab:blue")
    axes[0].set(xlabel="frames (control steps at 20 Hz)", ylabel="trajectories", title="trajectory length")
    axes[1].hist([e.get("cspace_length", np.nan) for e in eps], bins=30, color="tab:orange")
    axes[1].set(xlabel="C-space length (rad, 9 joints)", title="C-space length")
    fig.tight_layout()
    png = Path(png)
    png.parent.mkdir(parents=True, exist_ok=True)
    tmp = png.with_name(f".{png.stem}.tmp{png.suffix}")
    fig.savefig(tmp, dpi=100)
    plt.close(fig)
    tmp.replace(png)
    return png


def render_trajectory(path: str | Path, traj: int, out: str | Path, camera: str = "render_camera") -> Path:
    """A video of trajectory ``traj``: the env is reset as recorded and set to each recorded
    env state in turn (no physics), rendered by ``camera`` at the control rate."""
    import gymnasium as gym
    import h5py
    import imageio.v2 as imageio
    from mani_skill.trajectory.dataset import load_h5_data
    from mani_skill.trajectory.utils import dict_to_list_of_dicts

    import fetchbench_ms  # noqa: F401

    path = resolve(path)
    data = check_trajectory_file(path)
    episodes = {e["episode_id"]: e for e in data["episodes"]}
    if traj not in episodes:
        raise ValueError(f"no trajectory {traj} in {path}; valid: 0..{len(episodes) - 1}" if episodes
                         else f"{path} holds no trajectory")
    ep = episodes[traj]
    kwargs = {k: v for k, v in data["env_info"]["env_kwargs"].items() if k != "render_backend"}
    kwargs.update(obs_mode="none", render_mode="rgb_array")
    env = gym.make(data["env_info"]["env_id"], **kwargs)
    try:
        env.reset(**ep["reset_kwargs"])
        u = env.unwrapped
        if camera not in u._human_render_cameras:
            raise ValueError(f"unknown camera {camera!r}; valid: {', '.join(u._human_render_cameras)}")
        with h5py.File(path, "r") as f:
            states = dict_to_list_of_dicts(load_h5_data(f[f"traj_{traj}"]["env_states"]))
        frames = []
        for state in states:
            u.set_state_dict({k: _to_torch(v) for k, v in state.items()})
            image = env.render()
            image = image.cpu().numpy() if hasattr(image, "cpu") else np.asarray(image)
            frames.append(image.reshape(image.shape[-3:]))
    finally:
        env.close()
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.stem}.tmp{out.suffix}")
    fps = data["env_info"].get("env_kwargs", {}).get("control_freq") or 20
    # GIFs (pillow) take a frame duration in ms, videos (ffmpeg) a frame rate.
    timing = {"duration": 1000 / fps} if out.suffix.lower() == ".gif" else {"fps": fps}
    imageio.mimsave(tmp, frames, **timing)
    tmp.replace(out)
    return out


def _to_torch(value):
    import torch

    if isinstance(value, dict):
        return {k: _to_torch(v) for k, v in value.items()}
    return torch.as_tensor(np.asarray(value))[None]
