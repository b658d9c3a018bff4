"""The object catalog: sources, limits, split, regeneration, physics, bad input."""
from __future__ import annotations

import hashlib
import json
import math
import shutil

import numpy as np
import pytest

from fetchbench_ms.objects import build, catalog, decompose, geometry as g, procedural
from fetchbench_ms.objects.asset import SOURCES, SPLITS
from fetchbench_ms.utils.packed import unxz_bytes, xz_bytes


@pytest.fixture(scope="module")
def index():
    return catalog.load_index()


def _one_per_category(records):
    """The first object of every (source, category) pair, in id order."""
    seen = {}
    for r in records:
        seen.setdefault((r.source, r.category), r.object_id)
    return sorted(seen.values())


# ----------------------------------------------------------------------- contents


def test_catalog_size_sources_and_categories():
    records = catalog.list_objects()
    assert len(records) >= 5544
    by_source = {s: len(catalog.list_objects(source=s)) for s in SOURCES}
    assert by_source["ycb"] >= 40 and by_source["blob"] >= 900 and by_source["procedural"] >= 4000
    assert len(procedural.CATEGORIES) >= 20
    assert set(procedural.CATEGORIES) <= set(catalog.categories(source="procedural"))
    ids = [r.object_id for r in records]
    assert ids == sorted(ids) and len(set(ids)) == len(ids)
    # Blob 168 has NaN vertices: it must have been dropped, with the reason recorded.
    assert "blob/168" not in set(ids)
    assert any("non-finite" in reason for reason in catalog.load_index()["dropped"]["blob/168"])


def test_every_indexed_object_meets_the_limits(index):
    for oid, e in index["objects"].items():
        assert max(e["extents"]) <= g.MAX_EXTENT, oid
        assert e["volume"] * g.MAX_DENSITY <= g.MAX_MASS, oid
        assert e["grasp_width"] <= g.MAX_GRASP_WIDTH, oid
        assert 1 <= e["n_parts"] <= g.MAX_PARTS, oid
        assert len(e["stable_poses"]) == len(e["stable_probs"]) >= 1, oid
        assert math.isclose(sum(e["stable_probs"]), 1.0, abs_tol=1e-4), oid


def test_sampled_objects_have_valid_convex_parts_and_mass_properties():
    records = {r.object_id: r for r in catalog.list_objects()}
    for oid in _one_per_category(records.values()):
        asset = catalog.get_object(oid)
        assert asset.record == records[oid]
        for part in asset.convex_parts:
            report = g.check_part(part)
            assert report.watertight and report.convex, oid
            assert report.min_width >= g.MIN_PART_WIDTH and report.aspect < g.MAX_PART_ASPECT, oid
        points = np.concatenate([p.vertices for p in asset.convex_parts])
        # Object frame: origin at the bounding-box centre; extents as recorded.
        np.testing.assert_allclose((points.max(0) + points.min(0)) / 2, 0.0, atol=1e-9)
        np.testing.assert_allclose(points.max(0) - points.min(0), asset.extents, atol=2e-6)
        assert asset.mass(g.MAX_DENSITY) <= g.MAX_MASS
        assert np.all(np.abs(asset.center_of_mass) <= asset.extents / 2 + 1e-9)
        assert asset.stable_poses.shape[1:] == (4, 4) and asset.stable_probs[0] == asset.stable_probs.max()
        assert len(asset.visual_mesh.faces) > 0


def test_surface_mesh_is_watertight_union_of_parts():
    for oid in ("ycb/025_mug", catalog.list_objects(category="mug", source="procedural")[0].object_id):
        asset = catalog.get_object(oid)
        surface = asset.surface_mesh()
        assert surface.is_watertight and surface.is_volume
        # The union is never larger than the parts together, and close to them.
        assert 0.9 * asset.volume <= surface.volume <= asset.volume * (1 + 1e-6)


def test_limits_reject_what_the_robot_cannot_fetch():
    big_box = [g.box((0.3, 0.05, 0.05))]
    assert any("larger than" in p for p in procedural.object_problems(big_box))
    fat_ball = [g.ellipsoid((0.05, 0.05, 0.05))]
    assert any("narrower" in p for p in procedural.object_problems(fat_ball))
    heavy = [g.box((0.07, 0.2, 0.2))]  # 2.8 L -> 1.1 kg at 400 kg/m^3
    assert any("heavier" in p for p in procedural.object_problems(heavy))
    sliver = [g.box((0.1, 0.05, 0.001))]
    assert any("thinner" in p for p in procedural.object_problems(sliver))
    needle = [g.box((0.2, 0.0025, 0.0025))]
    assert any("oblong" in p for p in procedural.object_problems(needle))
    assert procedural.object_problems([g.box((0.05, 0.05, 0.05))]) == []


# ----------------------------------------------------------------------- split


def test_split_is_deterministic_disjoint_and_about_seven_to_one():
    train = {r.object_id for r in catalog.list_objects(split="train")}
    test = {r.object_id for r in catalog.list_objects(split="test")}
    assert train and test and not (train & test)
    assert len(train) + len(test) == len(catalog.list_objects())
    # The index was written by other processes: the hash split gives the same answer now.
    for oid in sorted(test)[:100] + sorted(train)[:100]:
        assert catalog.split_of(oid) == ("test" if oid in test else "train")
    ratio = len(train) / len(test)
    assert 6.0 <= ratio <= 8.2, ratio
    for source in SOURCES:
        records = catalog.list_objects(source=source)
        n = len(records)
        share = sum(r.split == "test" for r in records) / n
        # Within 3.5 standard deviations of 1/8 for a hash split of n objects.
        assert abs(share - 1 / 8) <= 3.5 * math.sqrt((1 / 8) * (7 / 8) / n), (source, share)
    for category in procedural.CATEGORIES:
        splits = {r.split for r in catalog.list_objects(source="procedural", category=category)}
        assert splits == set(SPLITS), category


# ----------------------------------------------------------------------- regeneration


def _mesh_bytes(parts) -> bytes:
    return b"".join(np.asarray(p.vertices).tobytes() + np.asarray(p.faces).tobytes() for p in parts)


def test_procedural_regeneration_is_byte_identical_and_ids_differ(index):
    seen = set()
    for category in sorted(procedural.CATEGORIES):
        first = procedural.generate(category, 7)
        again = procedural.generate(category, 7)
        assert _mesh_bytes(first.parts) == _mesh_bytes(again.parts)
        assert first.params == again.params
        other = procedural.generate(category, 8)
        assert _mesh_bytes(other.parts) != _mesh_bytes(first.parts)
        seen.add(_mesh_bytes(first.parts))
        # The index was built in other processes: the geometry matches it exactly.
        oid = procedural.procedural_id(category, 7)
        if oid in index["objects"]:
            asset, _ = catalog.build_object(oid, with_stable_poses=False)
            assert asset.metadata["fingerprint"] == index["objects"][oid]["fingerprint"]
    assert len(seen) == len(procedural.CATEGORIES)


def test_parameters_are_plausible_and_declared():
    for category in procedural.CATEGORIES.values():
        for spec in category.params:
            assert spec.doc and spec.unit in ("m", "rad", "count", "1"), (category.name, spec.name)
            if spec.unit == "m":
                assert 0.0 <= spec.low <= spec.high <= g.MAX_EXTENT, (category.name, spec.name)


def test_decomposition_pack_roundtrip():
    rng = np.random.default_rng(0)
    parts = {"a": [rng.uniform(-0.1, 0.1, (20, 3)), rng.uniform(0.0, 0.05, (9, 3))], "b": [rng.uniform(-0.02, 0.2, (12, 3))]}
    out = decompose.unpack(decompose.pack(parts))
    assert sorted(out) == ["a", "b"]
    for name in parts:
        assert len(out[name]) == len(parts[name])
        for original, restored in zip(parts[name], out[name]):
            np.testing.assert_allclose(restored, original, atol=5e-6)  # int16 steps of < 4 um


# ----------------------------------------------------------------------- physics


def test_samples_rest_stably_in_sapien():
    sapien = pytest.importorskip("sapien")
    from fetchbench_ms.objects.sapien_build import drop_on_plane

    ids = _one_per_category(catalog.list_objects())
    assert {oid.split("/")[0] for oid in ids} == set(SOURCES)
    failures = []
    for oid in ids:
        asset = catalog.get_object(oid)
        # Dropped from 5 mm in the most likely pose, 1.5 s simulated.
        actor, tilt, dz = drop_on_plane(asset)
        body = actor.find_component_by_type(sapien.physx.PhysxRigidDynamicComponent)
        assert len(body.collision_shapes) == len(asset.convex_parts)  # every part cooked
        if tilt > 15.0 or abs(dz) > 0.01:
            failures.append((oid, round(tilt, 1), round(dz, 4)))
    assert not failures, failures


# ----------------------------------------------------------------------- bad input


def test_unknown_ids_categories_splits_and_sources_are_clear_errors():
    with pytest.raises(ValueError, match="valid forms"):
        catalog.get_object("chair/0001")
    with pytest.raises(ValueError, match="valid: .*bottle"):
        catalog.get_object("procedural/teapot/0001")
    with pytest.raises(ValueError, match="indices run"):
        catalog.get_object(f"procedural/mug/{catalog.PROCEDURAL_PER_CATEGORY:04d}")
    with pytest.raises(ValueError, match="not in the catalog"):
        catalog.get_object("blob/168")
    with pytest.raises(ValueError, match="valid: .*mug"):
        catalog.list_objects(category="teapot")
    with pytest.raises(ValueError, match="valid: test, train"):
        catalog.list_objects(split="validation")
    with pytest.raises(ValueError, match="valid: blob, procedural, ycb"):
        catalog.list_objects(source="shapenet")


@pytest.fixture
def asset_copy(tmp_path, monkeypatch):
    """A copy of the shipped object files that the catalog reads instead of the originals."""
    copy = tmp_path / "objects"
    shutil.copytree(catalog.asset_dir(), copy)
    monkeypatch.setenv("FETCHBENCH_OBJECT_ASSETS", str(copy))
    catalog.clear_caches()
    yield copy
    monkeypatch.delenv("FETCHBENCH_OBJECT_ASSETS")
    catalog.clear_caches()


@pytest.mark.parametrize("name", [catalog.INDEX_NAME, catalog.YCB_CONVEX_NAME])
def test_tampered_files_are_refused(asset_copy, name):
    ycb_id = catalog.list_objects(source="ycb")[0].object_id
    catalog.clear_caches()
    data = bytearray((asset_copy / name).read_bytes())
    data[len(data) // 2] ^= 0xFF
    (asset_copy / name).write_bytes(bytes(data))
    with pytest.raises(ValueError, match="corrupt or stale"):
        if name == catalog.INDEX_NAME:
            catalog.list_objects()
        else:
            catalog.get_object(ycb_id)
    with pytest.raises(ValueError, match="does not match"):
        build.verify(asset_copy)


def test_stale_index_is_refused(asset_copy):
    """An index whose fingerprint no longer matches the regenerated geometry fails."""
    index = json.loads(unxz_bytes((asset_copy / catalog.INDEX_NAME).read_bytes()))
    oid = sorted(i for i in index["objects"] if i.startswith("procedural/"))[0]
    index["objects"][oid]["fingerprint"] = "0" * 16
    data = xz_bytes(json.dumps(index).encode())
    (asset_copy / catalog.INDEX_NAME).write_bytes(data)
    manifest = json.loads((asset_copy / catalog.MANIFEST_NAME).read_text())
    manifest["files"][catalog.INDEX_NAME]["sha256"] = hashlib.sha256(data).hexdigest()
    (asset_copy / catalog.MANIFEST_NAME).write_text(json.dumps(manifest))
    with pytest.raises(ValueError, match="stale"):
        catalog.get_object(oid)


# ----------------------------------------------------------------------- builder and CLI


def test_builder_is_resumable_and_byte_identical(tmp_path, monkeypatch):
    monkeypatch.setenv("FETCHBENCH_CACHE", str(tmp_path / "cache"))
    first = build.build(tmp_path / "a", workers=1, limit=1, log=lambda m: None)
    again = build.build(tmp_path / "a", workers=1, limit=1, log=lambda m: None)
    assert first["objects"] + first["dropped"] == 3 and first["built_now"] == 3
    assert again["built_now"] == 0  # resumed from the work file
    monkeypatch.setenv("FETCHBENCH_CACHE", str(tmp_path / "cache2"))
    build.build(tmp_path / "b", workers=2, limit=1, log=lambda m: None)
    for name in (catalog.INDEX_NAME, catalog.YCB_CONVEX_NAME):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()
    # Entries built here equal the shipped ones.
    built = json.loads(unxz_bytes((tmp_path / "a" / catalog.INDEX_NAME).read_bytes()))
    shipped = catalog.load_index()
    for oid, entry in built["objects"].items():
        assert entry == shipped["objects"][oid], oid


def test_cli_stats_verify_and_render(tmp_path, capsys):
    from fetchbench_ms.cli import main

    assert main(["objects", "stats", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["total"] == len(catalog.list_objects())
    assert sum(c["total"] for c in data["by_source"].values()) == data["total"]
    assert main(["objects", "verify", "--sample", "3"]) == 0
    out = tmp_path / "mugs.png"
    assert main(["objects", "render", "--category", "mug", "--count", "4", "--out", str(out)]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert main(["objects", "render", "--category", "teapot", "--out", str(out)]) == 2
    assert "valid:" in capsys.readouterr().err
