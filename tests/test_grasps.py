"""Grasp labels: candidate geometry, physics labels, storage and the shipped library."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import trimesh

from fetchbench_ms.cli import main as cli_main
from fetchbench_ms.grasp_labels import hand, store
from fetchbench_ms.grasp_labels.build import LabelSettings, build
from fetchbench_ms.grasp_labels.physics import GraspLabeller
from fetchbench_ms.grasp_labels.sampler import SamplerConfig, object_collision_manager, sample_candidates
from fetchbench_ms.objects.asset import ObjectAsset, ObjectRecord
from fetchbench_ms.utils.packed import xz_bytes
from grasp_dirs import write_npz_form

SHIPPED = Path(__file__).resolve().parents[1] / "assets" / "grasps"

# Small primitive objects, so these tests need no catalog: id -> (kind, dimensions).
PRIMITIVES = {
    "test/box_a": ("box", (0.05, 0.07, 0.12)),
    "test/cylinder_20": ("cylinder", (0.03, 0.10)),  # same shard as test/box_a: exercises merging
}


def primitive_asset(object_id: str) -> ObjectAsset:
    """A box or cylinder standing on z = 0, as an ObjectAsset (module-level: spawn can pickle it)."""
    kind, dims = PRIMITIVES[object_id]
    if kind == "box":
        mesh = trimesh.creation.box(extents=dims)
    else:
        mesh = trimesh.creation.cylinder(radius=dims[0], height=dims[1], sections=48)
    mesh.apply_translation([0, 0, -mesh.bounds[0, 2]])
    record = ObjectRecord(object_id, kind, "procedural", "train", tuple(float(e) for e in mesh.extents))
    return ObjectAsset(record, mesh, (mesh,), mesh.center_mass, float(mesh.volume), np.eye(4)[None], np.ones(1))


@pytest.fixture(scope="module")
def labeller():
    return GraspLabeller(slots=16)


def test_candidates_are_antipodal_open_and_collision_free():
    asset = primitive_asset("test/box_a")
    config = SamplerConfig()
    candidates = sample_candidates(asset, 24, np.random.default_rng(3), config)
    assert len(candidates) == 24
    # Widths within the hand's opening, and equal to the contact distance.
    assert np.all(candidates.width >= config.min_width) and np.all(candidates.width <= hand.MAX_OPENING - 0.005)
    p, q = candidates.contacts[:, 0], candidates.contacts[:, 1]
    np.testing.assert_allclose(np.linalg.norm(q - p, axis=1), candidates.width, atol=1e-6)
    # The closing axis (hand y) runs p -> q and lies inside the friction cone of both contacts.
    closing = candidates.T_object_hand[:, :3, 1]
    np.testing.assert_allclose(closing, (q - p) / candidates.width[:, None], atol=1e-6)
    mesh = asset.visual_mesh
    _, _, face_p = trimesh.proximity.closest_point(mesh, p)
    _, _, face_q = trimesh.proximity.closest_point(mesh, q)
    cos_cone = np.cos(config.cone_half_angle) - 1e-6
    assert np.all(np.einsum("ij,ij->i", -mesh.face_normals[face_p], closing) >= cos_cone)
    assert np.all(np.einsum("ij,ij->i", mesh.face_normals[face_q], closing) >= cos_cone)
    # The TCP lies on the approach axis within the depth range of the contact midpoint.
    tcp = candidates.T_object_hand[:, :3, 3] + hand.TCP_OFFSET * candidates.T_object_hand[:, :3, 2]
    offset = np.einsum("ij,ij->i", tcp - (p + q) / 2, candidates.T_object_hand[:, :3, 2])
    assert np.all((offset >= config.depth_range[0] - 1e-9) & (offset <= config.depth_range[1] + 1e-9))
    # The open hand is clear of the object (checked by distance, not the sampler's yes/no query).
    manager = object_collision_manager(asset)
    open_hand = hand.open_hand_mesh()
    for T in candidates.T_object_hand:
        assert manager.min_distance_single(open_hand, transform=T) > 0.0
    # Rotations are proper.
    R = candidates.T_object_hand[:, :3, :3]
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-9)
    # Same seed, same candidates.
    again = sample_candidates(asset, 24, np.random.default_rng(3), config)
    assert np.array_equal(again.T_object_hand, candidates.T_object_hand)


def test_sampler_rejects_objects_too_wide_for_the_hand():
    mesh = trimesh.creation.box(extents=(0.12, 0.12, 0.12))
    record = ObjectRecord("test/wide", "box", "procedural", "train", (0.12, 0.12, 0.12))
    asset = ObjectAsset(record, mesh, (mesh,), np.zeros(3), float(mesh.volume), np.eye(4)[None], np.ones(1))
    assert len(sample_candidates(asset, 8, np.random.default_rng(0))) == 0


def test_physics_holds_good_grasps_and_drops_bad_ones(labeller):
    asset = primitive_asset("test/cylinder_20")
    candidates = sample_candidates(asset, 8, np.random.default_rng(1))
    good = candidates.T_object_hand
    # The same hands moved 7 cm out along their approach axis close on air: all must fail.
    T_back = np.eye(4)
    T_back[2, 3] = -0.07
    missed = good @ T_back
    result = labeller.label(asset, np.concatenate([good, missed]))
    assert result.success[:8].mean() >= 0.85
    assert not result.success[8:].any()
    # Finger gap after closing on a 6 cm cylinder, across its diameter.
    held = result.success[:8]
    np.testing.assert_allclose(result.width[:8][held], candidates.width[held], atol=0.006)
    assert np.all(result.width[8:] < 0.002)  # empty hands close fully


def test_physics_fails_an_object_too_heavy_to_hold(labeller):
    asset = primitive_asset("test/box_a")
    candidates = sample_candidates(asset, 8, np.random.default_rng(2))
    labeller.set_object(asset, density=60000.0)  # ~25 kg: beyond the 100 N gripper and friction
    heavy = labeller.run_batch(candidates.T_object_hand)
    labeller.set_object(asset)
    light = labeller.run_batch(candidates.T_object_hand)
    assert heavy.success.mean() <= 0.25 and light.success.mean() >= 0.85


def test_build_store_round_trip_resume_and_errors(tmp_path, capsys):
    settings = LabelSettings(candidates_per_round=16, max_rounds=1, target_successes=8)
    ids = sorted(PRIMITIVES)
    # Incremental: label one object, then both; the result equals labelling both at once.
    build(tmp_path / "one_by_one", ids[:1], loader=primitive_asset, settings=settings, workers=0, log=lambda m: None)
    build(tmp_path / "one_by_one", ids, loader=primitive_asset, settings=settings, workers=0, log=lambda m: None)
    manifest = build(tmp_path, ids, loader=primitive_asset, settings=settings, workers=0, log=lambda m: None)
    for f in tmp_path.glob("shard_*.arrays.xz"):
        assert (tmp_path / "one_by_one" / f.name).read_bytes() == f.read_bytes()
    assert sorted(i for e in manifest["shards"].values() for i in e["successes_per_object"]) == ids
    files = sorted(tmp_path.glob("shard_*.arrays.xz"))
    assert files and store.read_manifest(tmp_path) == manifest
    before = {f.name: f.read_bytes() for f in files}

    grasps = store.load_grasps("test/box_a", tmp_path)
    assert grasps.T_object_hand.shape == (16, 4, 4) and grasps.success.dtype == bool
    np.testing.assert_allclose(grasps.T_object_hand[:, :3, :3] @ np.swapaxes(grasps.T_object_hand[:, :3, :3], 1, 2),
                               np.tile(np.eye(3), (16, 1, 1)), atol=1e-6)
    # Stored poses are the sampled ones up to float16 rotation / float32 position rounding.
    sampled = sample_candidates(primitive_asset("test/box_a"), 16, np.random.default_rng(
        [0, int(store.sha256_bytes(b"test/box_a")[:15], 16)]), settings.sampler)
    np.testing.assert_allclose(grasps.T_object_hand, sampled.T_object_hand, atol=2e-3)
    assert grasps.success.sum() >= 8
    assert store.objects_with_grasps(tmp_path) == [i for i in ids if manifest_count(manifest, i) >= store.MIN_SUCCESSES]

    # A second run resumes: nothing relabelled, files byte-identical.
    messages = []
    build(tmp_path, ids, loader=primitive_asset, settings=settings, workers=0, log=messages.append)
    assert "0 to label" in messages[0]
    assert {f.name: f.read_bytes() for f in files} == before

    # Unknown id: a clear KeyError naming how to list valid ids.
    with pytest.raises(KeyError, match="no grasps for object 'test/nope'"):
        store.GraspStore(tmp_path).load("test/nope")
    # Tampered file: the hash check refuses it, and `verify` reports it.
    tampered = files[0]
    data = bytearray(tampered.read_bytes())
    data[len(data) // 2] ^= 0xFF
    tampered.write_bytes(bytes(data))
    fresh = store.GraspStore(tmp_path)
    victim = next(i for i in ids if store.shard_name(store.shard_of(i)) == tampered.name)
    with pytest.raises(ValueError, match="corrupt or was changed"):
        fresh.load(victim)
    assert cli_main(["grasps", "verify", "--dir", str(tmp_path)]) == 1
    assert "sha256 does not match" in capsys.readouterr().out
    # The builder notices the broken shard and relabels it to the same bytes.
    build(tmp_path, ids, loader=primitive_asset, settings=settings, workers=0, log=lambda m: None)
    assert {f.name: f.read_bytes() for f in files} == before
    assert cli_main(["grasps", "verify", "--dir", str(tmp_path)]) == 0
    # A manifest from another code version is refused as stale.
    stale = store.read_manifest(tmp_path)
    stale["version"] = store.GRASPS_VERSION + 1
    (tmp_path / store.MANIFEST).write_bytes(xz_bytes(json.dumps(stale).encode()))
    with pytest.raises(ValueError, match="stale grasp labels"):
        store.GraspStore(tmp_path)


def test_a_grasp_directory_of_the_npz_form_is_read_and_rebuilt_packed(tmp_path):
    """``manifest.json`` + ``shard_NN.npz`` (the earlier form) reads as it is; the builder
    rewrites it into the packed form with the same labels, relabelling nothing."""
    settings = LabelSettings(candidates_per_round=16, max_rounds=1, target_successes=8)
    ids = sorted(PRIMITIVES)
    packed_dir, legacy_dir = tmp_path / "packed", tmp_path / "legacy"
    build(packed_dir, ids, loader=primitive_asset, settings=settings, workers=0, log=lambda m: None)
    write_npz_form(packed_dir, legacy_dir)
    for object_id in ids:
        old, new = store.GraspStore(legacy_dir).load(object_id), store.GraspStore(packed_dir).load(object_id)
        assert np.array_equal(old.T_object_hand, new.T_object_hand) and np.array_equal(old.success, new.success)
    messages = []
    build(legacy_dir, ids, loader=primitive_asset, settings=settings, workers=0, log=messages.append)
    rewritten = [m for m in messages if m.startswith("shard ")]
    assert rewritten and all(" 0 trials " in m for m in rewritten)  # rewritten, not relabelled
    assert sorted(p.name for p in legacy_dir.iterdir()) == sorted(p.name for p in packed_dir.iterdir())
    assert all((legacy_dir / p.name).read_bytes() == p.read_bytes() for p in packed_dir.iterdir())


def manifest_count(manifest: dict, object_id: str) -> int:
    return next(e["successes_per_object"][object_id] for e in manifest["shards"].values()
                if object_id in e["successes_per_object"])


def test_shipped_labels_hold_when_rerun_in_physics(labeller):
    """A seeded sample of shipped labels, re-run in physics: stored successes hold again
    (>= 90%), stored failures mostly fail again. Also checks every file's hash."""
    from fetchbench_ms.grasp_labels.build import object_from_source

    shipped = store.GraspStore(SHIPPED)
    assert shipped.verify() == []
    rng = np.random.default_rng(2024)
    ids = rng.choice(shipped.object_ids(), size=8, replace=False)
    held = failed_again = n_success = n_failure = 0
    for object_id in sorted(ids):
        grasps = shipped.load(str(object_id))
        assert len(grasps) >= 16 and grasps.T_object_hand.shape == (len(grasps), 4, 4)
        good, bad = np.flatnonzero(grasps.success), np.flatnonzero(~grasps.success)
        pick_good = rng.choice(good, size=min(3, len(good)), replace=False)
        pick_bad = rng.choice(bad, size=min(1, len(bad)), replace=False)
        result = labeller.label(object_from_source(str(object_id)), grasps.T_object_hand[np.concatenate([pick_good, pick_bad])])
        held += int(result.success[: len(pick_good)].sum())
        failed_again += int((~result.success[len(pick_good) :]).sum())
        n_success += len(pick_good)
        n_failure += len(pick_bad)
    assert n_success >= 20 and held / n_success >= 0.9
    assert n_failure >= 4 and failed_again / n_failure >= 0.5


def test_kept_objects_have_enough_successes():
    shipped = store.GraspStore(SHIPPED)
    kept = store.objects_with_grasps(SHIPPED)
    counts = shipped.successes_per_object()
    assert len(kept) > 0.9 * len(counts)
    assert all(counts[i] >= store.MIN_SUCCESSES for i in kept)
    assert all(counts[i] < store.MIN_SUCCESSES for i in set(counts) - set(kept))
    grasps = store.load_grasps(kept[0], SHIPPED).successful
    assert len(grasps) >= store.MIN_SUCCESSES and grasps.success.all()
    assert np.all((grasps.width > 0.0) & (grasps.width <= hand.MAX_OPENING + 1e-3))


def test_show_draws_successful_grasps_and_cli_errors(tmp_path, capsys):
    from PIL import Image

    out = tmp_path / "mug.png"
    assert cli_main(["grasps", "show", "procedural/mug/0000", "--out", str(out), "--max", "12", "--dir", str(SHIPPED)]) == 0
    assert "12 grasps of procedural/mug/0000" in capsys.readouterr().out
    rgb = np.asarray(Image.open(out).convert("RGB")).astype(int)
    greenish = (rgb[..., 1] > 120) & (rgb[..., 1] > rgb[..., 0] + 50) & (rgb[..., 1] > rgb[..., 2] + 50)
    assert greenish.sum() > 200  # the hand outlines are drawn in green
    # Bad input: one clear line, exit 2.
    assert cli_main(["grasps", "show", "procedural/mug/9999", "--out", str(out), "--dir", str(SHIPPED)]) == 2
    assert "no grasps for object 'procedural/mug/9999'" in capsys.readouterr().err
    assert cli_main(["grasps", "build", "--shards", "70", "--dir", str(tmp_path)]) == 2
    assert "valid shard indices are 0..63" in capsys.readouterr().err


def test_objects_stats_report_grasps():
    from fetchbench_ms.objects import catalog

    stats = catalog.stats()  # importing fetchbench_ms.grasp_labels registered the extension
    grasps = stats["grasps"]
    assert grasps["kept"] + grasps["dropped"] == grasps["labelled"] <= stats["total"]
    assert 0.5 < grasps["success_rate"] < 1.0 and grasps["mean_successes_per_kept"] >= store.MIN_SUCCESSES
    assert set(grasps["by_source"]) == set(stats["by_source"])
    assert set(stats["grasps_by_category"]) == set(stats["by_category"])


def test_candidates_do_not_depend_on_how_the_hull_is_listed():
    """The same shape with its triangles listed, rotated and split differently gives the
    same candidates: labels are a function of the shape and the seed only."""
    a = primitive_asset("test/cylinder_20")
    mesh = a.convex_parts[0]
    rng = np.random.default_rng(0)
    faces = np.roll(mesh.faces[rng.permutation(len(mesh.faces))], 1, axis=1)
    perm = rng.permutation(len(mesh.vertices))
    inverse = np.argsort(perm)
    shuffled = trimesh.Trimesh(mesh.vertices[perm], inverse[faces], process=False)
    # Re-triangulate the caps from their centre-less rims (another valid triangulation).
    other = trimesh.convex.convex_hull(mesh.vertices[perm])
    for variant in (shuffled, other):
        b = ObjectAsset(a.record, variant, (variant,), a.center_of_mass, a.volume, a.stable_poses, a.stable_probs)
        np.testing.assert_array_equal(
            sample_candidates(b, 16, np.random.default_rng(4)).T_object_hand,
            sample_candidates(a, 16, np.random.default_rng(4)).T_object_hand,
        )


def test_the_old_package_names_import_the_same_modules():
    """``grasps`` -> ``grasp_labels``, ``grasping`` -> ``grasp_prediction``: code, loader strings
    and pickles written with the old names get the very same modules (fetchbench_ms/_moved.py)."""
    import importlib
    import pickle

    import fetchbench_ms.grasp_labels.store as labels_store
    import fetchbench_ms.grasp_prediction as prediction
    from fetchbench_ms.grasp_labels.build import object_from_source, resolve_loader

    assert importlib.import_module("fetchbench_ms.grasps.store") is labels_store
    assert importlib.import_module("fetchbench_ms.grasping") is prediction
    assert labels_store.__spec__.name == "fetchbench_ms.grasp_labels.store"  # its own spec, not the alias's
    assert resolve_loader("fetchbench_ms.grasps.build:object_from_source") is object_from_source
    old_pickle = pickle.dumps(labels_store.GraspStore, protocol=0).replace(b"fetchbench_ms.grasp_labels.store",
                                                                           b"fetchbench_ms.grasps.store")
    assert pickle.loads(old_pickle) is labels_store.GraspStore
    with pytest.raises(ModuleNotFoundError):
        importlib.import_module("fetchbench_ms.grasps.no_such_module")
