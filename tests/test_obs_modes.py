"""The obs-mode layer (``envs/obs_modes.py``) on its own: which ManiSkill mode each of
FetchBench's runs on, the name the env reports, the checks and the copies an observation gets.
(The modes' observations themselves: test_envs_modes.py, test_policy_obs.py, test_composed_obs.py.)"""
import pytest
import torch

from fetchbench_ms.envs import pointcloud
from fetchbench_ms.envs.obs_modes import (MANISKILL_OBS_MODES, POLICY_TEXTURES, ObsModes, camera_size,
                                          check_obs_mode, own_arrays)


@pytest.mark.parametrize("asked, underneath", [
    (pointcloud.COMPACT_OBS_MODE, "pointcloud"), (pointcloud.POLICY_OBS_MODE, POLICY_TEXTURES),
    (pointcloud.COMPOSED_OBS_MODE, "state_dict"), *[(m, m) for m in MANISKILL_OBS_MODES], (None, None)])
def test_each_mode_runs_on_one_of_maniskills_and_keeps_its_name(asked, underneath):
    modes = ObsModes(asked)
    assert modes.maniskill_obs_mode == underneath
    assert modes.name(underneath or "state") == (asked or "state")
    assert modes.composed is None  # made with a scene (composed_pointcloud) or when asked


def test_episodes_start_marks_the_composed_points_stale_only_where_there_are_some():
    modes = ObsModes(pointcloud.COMPOSED_OBS_MODE)
    modes.episodes_start(torch.tensor([0]))  # no scene yet: nothing to mark

    class Store:
        device = "cpu"
        stale = torch.zeros(3, dtype=torch.bool)

    modes.composed = Store()
    modes.episodes_start(torch.tensor([0, 2]))
    assert modes.composed.stale.tolist() == [True, False, True]


def test_checks_name_the_valid_choices():
    with pytest.raises(ValueError, match="valid: state, state_dict"):
        check_obs_mode("pointclouds")
    with pytest.raises(ValueError, match="need a renderer"):
        check_obs_mode("rgb", render_backend="none")
    check_obs_mode("rgb+depth+state")
    assert camera_size(pointcloud.POLICY_OBS_MODE, None, None) == pointcloud.POLICY_CAMERA_SIZE
    assert camera_size("pointcloud", None, None) == (320, 240)
    with pytest.raises(ValueError, match="leave camera_width"):
        camera_size(pointcloud.POLICY_OBS_MODE, 640, 480)
    with pytest.raises(ValueError, match="valid: 320x240, 640x480"):
        camera_size("rgb", 100, 100)


def test_own_arrays_copies_small_tensors_and_keeps_rendered_data():
    pose, rendered = torch.zeros(3), {"left_camera": torch.zeros(2)}
    out = own_arrays({"extra": {"base_pose": pose}, "sensor_data": rendered})
    assert out["sensor_data"] is rendered and out["extra"]["base_pose"] is not pose
    assert torch.equal(out["extra"]["base_pose"], pose)
