"""The shipped assets' packed forms (fetchbench_ms/utils/packed.py, scripts/maint/pack_assets.py)
are lossless: each unpacks to exactly what it replaced, and packing is byte-reproducible."""
from __future__ import annotations

import gzip
import hashlib
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from fetchbench_ms.grasp_labels import store as grasp_store
from fetchbench_ms.tasks import suite_packed
from fetchbench_ms.tasks.suite import load_suite, shipped_suite_file, suite_file_sha256, suite_text
from fetchbench_ms.utils import packed
from fetchbench_ms.utils.io import sha256_bytes
from grasp_dirs import write_npz_form
from script_modules import load_script

ROOT = Path(__file__).resolve().parents[1]
CHECKPOINTS = ROOT / "assets" / "checkpoints"
#: sha256 of the .pt files the shipped checkpoints were packed from (the checkpoints' JSON and
#: the evaluation records name the same ones, where they name one).
PT_SHA256 = {
    "cgn_ours": "89c00322b225179accf5373f86408789ba24ab985e2fe283d248ce7346a37c3d",
    "collision_net": "36f2d97a3fd59881f98267b8352bb566b0760dca71d274a0e414b7c11b861ed5",
    "imit_act": "1ea55247db12a728bb5be2328227136d80555b2cb1061e1aa3659783bf842f7a",
    "imit_diffusion": "9c3a6598835ea9701446ba3a6f740b0cca1d883d658d19011687979c4a6be823",
    "imit_mlp": "f09e9488070a94ee35cdbcaa0b404633e20a684a5baa5917720c867f9cf69952",
    "imit_transformer": "c9f433c681f8e2f449a39415392bd30132eea1e53f6edfd365d280c13ba6ee2d",
}
#: Per shipped suite: the sha256 inside it (of its canonical JSON) and that of the .json.gz file
#: it was packed from, which run records name it by (``source_sha256``).
SUITES = {
    "smoke": ("fed8de59cef40f8fa72379a8c0eed03c3a948e730b2a983f16557b48e43b843b",
              "e69c4b7863ee2e71e444244eb6f4b8019153eb967747fa983f49ab7943009fad"),
    "test": ("ca5f64c2d9feadc3183f7ac8d3db11359f3e2b3c4fa99816da3917b3097b98c6",
             "deba668f3a22ab82cdd38c218179c63c86232a190fac6941f8b29ca55eb921c6"),
    "train": ("6cc8d140fc2691cf157721977cbdc9e32c4d07310d7b57d241dcf7196459e858",
              "6256fae7bd5b04914b96307b86ca7dfe0daec49c8d4acf552c6d3f3b3fac1c7c"),
    "val": ("df58b8091fd7e308a1ebe526052e965957d0fe5de4f0123c047bd346c8972d92",
            "f54fb7aab5418716a371abb2e16e315f9cedb006745aad17e964d0343d98993e"),
}
#: sha256 over every shard's arrays (shard, name, dtype, shape, bytes) as the .npz shards held them.
GRASP_ARRAYS_SHA256 = "40979e5f57528fae9a9c7224ec42aaa2bb5e400c093ec048e0f3bcbc19e8f362"


def _grasp_arrays_sha256(directory: Path) -> str:
    digest = hashlib.sha256()
    manifest = grasp_store.read_manifest(directory)
    for shard in sorted(manifest["shards"], key=int):
        for name, array in grasp_store.read_shard_arrays(directory / manifest["shards"][shard]["file"]).items():
            digest.update(f"{shard}|{name}|{array.dtype.str}|{array.shape}|".encode())
            digest.update(array.tobytes())
    return digest.hexdigest()


@pytest.mark.parametrize("size", [0, 1, 2, 3, 64, 1001])
def test_byte_planes_round_trip_any_length(size):
    data = np.random.default_rng(size).integers(0, 256, size, dtype=np.uint8).tobytes()
    for width in (1, 2, 3, 4, 8):
        assert packed.join_planes(packed.split_planes(data, width), width) == data
    assert packed.unpack_planes(packed.pack_planes(data)) == data


def test_the_shipped_checkpoints_unpack_to_their_pt_bytes():
    shipped = sorted(p.name for p in CHECKPOINTS.glob("*.pt*"))
    assert shipped == sorted(f"{name}.pt.planes.xz" for name in PT_SHA256)
    for name, sha in PT_SHA256.items():
        path = CHECKPOINTS / f"{name}.pt.planes.xz"
        assert packed.content_sha256(path) == sha, name
        record = json.loads((CHECKPOINTS / f"{name}.json").read_text())
        assert record.get("checkpoint_sha256", sha) == sha, name


def test_a_packed_checkpoint_loads_to_the_same_tensors_as_its_source(tmp_path):
    generator = torch.Generator().manual_seed(0)
    state = {"w": torch.randn(33, 17, generator=generator).half(), "b": torch.randn(17, generator=generator).half(),
             "steps": torch.arange(5), "scale": torch.randn(3, generator=generator)}
    source = tmp_path / "model.pt"
    torch.save({"state_dict": state, "config": {"width": 17}}, source)
    target = tmp_path / "model.pt.planes.xz"
    target.write_bytes(packed.pack_planes(source.read_bytes()))
    assert packed.pack_planes(source.read_bytes()) == target.read_bytes()  # same input, same bytes
    assert packed.file_bytes(target) == source.read_bytes()
    loaded = packed.torch_load(target, map_location="cpu", weights_only=True)
    assert loaded["config"] == {"width": 17} and loaded["state_dict"].keys() == state.keys()
    for key, tensor in state.items():
        assert loaded["state_dict"][key].dtype == tensor.dtype and torch.equal(loaded["state_dict"][key], tensor)


def test_a_pt_path_reads_its_packed_copy_only_when_it_is_absent(tmp_path):
    plain, copy = tmp_path / "a.pt", tmp_path / "a.pt.planes.xz"
    assert packed.packed_or_plain(plain) == plain  # neither: the caller reports the .pt missing
    copy.write_bytes(packed.pack_planes(b"packed"))
    assert packed.packed_or_plain(plain) == copy and packed.file_bytes(packed.packed_or_plain(plain)) == b"packed"
    plain.write_bytes(b"plain")  # a user's own export beside the shipped one wins
    assert packed.packed_or_plain(plain) == plain


def test_a_damaged_packed_file_is_an_error_naming_it(tmp_path):
    path = tmp_path / "a.pt.planes.xz"
    path.write_bytes(packed.pack_planes(b"x" * 1000)[:-8])
    with pytest.raises(ValueError, match="a.pt.planes.xz is not a complete xz stream"):
        packed.file_bytes(path)


def test_the_pack_script_is_idempotent_and_reproducible(tmp_path, capsys):
    script = load_script(ROOT / "scripts/maint/pack_assets.py", "pack_assets")
    (tmp_path / "checkpoints").mkdir()
    raw = (tmp_path / "checkpoints" / "net.pt")
    torch.save({"state_dict": {"w": torch.ones(8, 8).half()}}, raw)
    source = raw.read_bytes()
    assert script.main(["--assets", str(tmp_path), "--only", "checkpoints", "--check"]) == 1
    assert script.main(["--assets", str(tmp_path), "--only", "checkpoints"]) == 0
    assert not raw.exists() and packed.file_bytes(raw.with_name("net.pt.planes.xz")) == source
    first = raw.with_name("net.pt.planes.xz").read_bytes()
    capsys.readouterr()
    assert script.main(["--assets", str(tmp_path), "--only", "checkpoints", "--check"]) == 0
    assert "nothing to pack" in capsys.readouterr().out
    raw.write_bytes(source)
    raw.with_name("net.pt.planes.xz").unlink()
    assert script.main(["--assets", str(tmp_path), "--only", "checkpoints"]) == 0
    assert raw.with_name("net.pt.planes.xz").read_bytes() == first


def test_the_shipped_grasp_shards_hold_the_arrays_of_the_npz_shards():
    directory = ROOT / "assets" / "grasps"
    assert sorted(p.name for p in directory.iterdir()) == sorted(
        ["manifest.json.xz"] + [grasp_store.shard_name(int(s)) for s in grasp_store.read_manifest(directory)["shards"]])
    assert grasp_store.GraspStore(directory).verify() == []
    assert _grasp_arrays_sha256(directory) == GRASP_ARRAYS_SHA256


def test_quaternions_pack_to_a_w_correction_and_back_bit_for_bit():
    rng = np.random.default_rng(0)
    quat = rng.normal(size=(500, 4))
    quat[:5] = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 0, 1], [0.5, 0.5, 0.5, 0.5], [0, 0.6, 0.8, 0]]
    quat /= np.linalg.norm(quat, axis=1, keepdims=True)
    quat *= np.where(quat[:, :1] < 0, -1.0, 1.0)
    quat = quat.astype(np.float16)
    quat[5, 0] = np.float16(-0.0)  # a w the sign rule leaves negative zero
    arrays = {"meta": np.array("{}"), "quat_wxyz": quat, "position": rng.normal(size=(500, 3)).astype(np.float32)}
    back = grasp_store.decode_shard(grasp_store.encode_shard_arrays(arrays))
    assert list(back) == list(arrays) and back["quat_wxyz"].tobytes() == quat.tobytes()
    assert back["meta"].shape == () and back["position"].tobytes() == arrays["position"].tobytes()
    stored = packed.unpack_arrays(grasp_store.encode_shard_arrays(arrays))
    tampered = {**stored, "quat_w_correction": stored["quat_w_correction"] + np.uint16(1)}
    with pytest.raises(ValueError, match="decode to other values"):
        grasp_store.decode_shard(packed.pack_arrays(tampered), "shard_xx")


def test_the_pack_script_packs_an_npz_grasp_directory(tmp_path):
    script = load_script(ROOT / "scripts/maint/pack_assets.py", "pack_assets")
    shipped, legacy = ROOT / "assets" / "grasps", tmp_path / "grasps"
    first = sorted(int(k) for k in grasp_store.read_manifest(shipped)["shards"])[:2]
    write_npz_form(shipped, legacy, shards=first)
    before = _grasp_arrays_sha256(legacy)
    assert script.main(["--assets", str(tmp_path), "--only", "grasps"]) == 0
    assert sorted(p.name for p in legacy.iterdir()) == sorted(["manifest.json.xz"] + [grasp_store.shard_name(k) for k in first])
    assert _grasp_arrays_sha256(legacy) == before and grasp_store.GraspStore(legacy).verify() == []
    for k in first:  # the same bytes as the shipped shards
        assert (legacy / grasp_store.shard_name(k)).read_bytes() == (shipped / grasp_store.shard_name(k)).read_bytes()
    assert script.main(["--assets", str(tmp_path), "--only", "grasps", "--check"]) == 0


@pytest.mark.parametrize("name", sorted(SUITES))
def test_the_shipped_suites_load_to_the_content_they_hash_to(name):
    content_sha, gz_sha = SUITES[name]
    path = shipped_suite_file(name)
    assert path.name == f"{name}.suite.xz"
    suite = load_suite(name)  # checks the canonical JSON against the sha256 inside
    assert json.loads(suite_text(path.read_bytes(), path))["sha256"] == content_sha and len(suite) > 0
    assert suite_file_sha256(path) == gz_sha


def test_every_shipped_record_names_a_shipped_suite():
    """The suite identity each shipped run recorded (``source_sha256``, the checkpoints'
    ``suite_sha256``) is a shipped suite's: a new run of the same tasks compares with them."""
    known = {suite_file_sha256(shipped_suite_file(name)) for name in SUITES}
    recorded = {json.loads(p.read_text()).get("source_sha256") for p in (ROOT / "results").rglob("run.json")}
    recorded |= {json.loads(p.read_text()).get("selection", {}).get("suite_sha256") for p in CHECKPOINTS.glob("*.json")}
    assert recorded - {None} and recorded - {None} <= known


def test_a_suite_saved_packed_reads_back_and_keeps_its_gzip_identity(tmp_path):
    smoke = load_suite("smoke")
    smoke.save(tmp_path / "a.suite.xz")
    smoke.save(tmp_path / "b.suite.xz")
    smoke.save(tmp_path / "a.json.gz")
    assert (tmp_path / "a.suite.xz").read_bytes() == (tmp_path / "b.suite.xz").read_bytes()
    again = load_suite(tmp_path / "a.suite.xz")
    assert again.ids() == smoke.ids() and again.tasks == smoke.tasks and again.info == smoke.info
    assert suite_text((tmp_path / "a.suite.xz").read_bytes(), "a") == gzip.decompress((tmp_path / "a.json.gz").read_bytes())
    assert suite_file_sha256(tmp_path / "a.suite.xz") == sha256_bytes((tmp_path / "a.json.gz").read_bytes())
    data = bytearray((tmp_path / "a.suite.xz").read_bytes())
    data[len(data) // 2] ^= 0xFF
    (tmp_path / "c.suite.xz").write_bytes(bytes(data))
    with pytest.raises(ValueError, match="c.suite.xz is corrupt"):
        load_suite(tmp_path / "c.suite.xz")


def test_packing_puts_every_float_back_and_refuses_a_nul_string():
    body = {"a": [0.1, -0.0, 1e-07, 2.5, 3], "b": {"x": 1.2345678901234567, "y": "0.5"}, "c": [{"x": 0.25}, {"x": True}]}
    text = json.dumps(body, sort_keys=True, separators=(",", ":")).encode()
    assert suite_packed.unpack(suite_packed.pack(text, "0" * 64))[0] == text
    with pytest.raises(ValueError, match="cannot be packed"):
        suite_packed.pack(json.dumps({"a": "\0", "b": 0.5}, sort_keys=True, separators=(",", ":")).encode(), "0" * 64)


def test_the_pack_script_packs_a_gzip_suite(tmp_path):
    script = load_script(ROOT / "scripts/maint/pack_assets.py", "pack_assets")
    (tmp_path / "suites").mkdir()
    load_suite("smoke").save(tmp_path / "suites" / "smoke.json.gz")
    gz = (tmp_path / "suites" / "smoke.json.gz").read_bytes()
    assert script.main(["--assets", str(tmp_path), "--only", "suites", "--check"]) == 1
    assert script.main(["--assets", str(tmp_path), "--only", "suites"]) == 0
    assert [p.name for p in (tmp_path / "suites").iterdir()] == ["smoke.suite.xz"]
    assert suite_file_sha256(tmp_path / "suites" / "smoke.suite.xz") == sha256_bytes(gz)
    assert load_suite(tmp_path / "suites" / "smoke.suite.xz").tasks == load_suite("smoke").tasks


def test_the_shipped_runs_are_packed_and_the_pack_script_packs_a_gzip_run(tmp_path):
    folders = [p.parent for p in (ROOT / "results").rglob("run.json")]
    assert folders and all((f / "results.jsonl.xz").is_file() and not (f / "results.jsonl.gz").exists() for f in folders)
    script = load_script(ROOT / "scripts/maint/pack_assets.py", "pack_assets")
    shipped = ROOT / "results" / "runs" / "ga-mesh-rrt-paper-val100"
    run = tmp_path / "results" / "runs" / "r"
    run.mkdir(parents=True)
    (run / "run.json").write_bytes((shipped / "run.json").read_bytes())
    (run / "results.jsonl.gz").write_bytes(gzip.compress(packed.unxz_bytes((shipped / "results.jsonl.xz").read_bytes())))
    args = ["--results", str(tmp_path / "results"), "--only", "results"]
    assert script.main([*args, "--check"]) == 1
    assert script.main(args) == 0
    assert sorted(p.name for p in run.iterdir()) == ["results.jsonl.xz", "run.json"]
    assert (run / "results.jsonl.xz").read_bytes() == (shipped / "results.jsonl.xz").read_bytes()
    assert script.main([*args, "--check"]) == 0


#: sha256 of the object index's canonical JSON (the text catalog.json.gz held).
CATALOG_JSON_SHA256 = "0d8f697098f25d7873c32d183bc88937f681dd798eba66be72ef0d48e2e6c670"


def test_the_catalog_index_reads_in_either_form_and_packs_to_the_shipped_bytes(tmp_path, monkeypatch):
    from fetchbench_ms.objects import catalog

    shipped = ROOT / "assets" / "objects"
    text = packed.unxz_bytes((shipped / catalog.INDEX_NAME).read_bytes())
    assert sha256_bytes(text) == CATALOG_JSON_SHA256
    assert not (shipped / catalog.LEGACY_INDEX_NAME).exists()
    legacy = tmp_path / "objects"
    shutil.copytree(shipped, legacy)
    gz = gzip.compress(text, compresslevel=9, mtime=0)
    (legacy / catalog.INDEX_NAME).unlink()
    (legacy / catalog.LEGACY_INDEX_NAME).write_bytes(gz)
    manifest = json.loads((legacy / catalog.MANIFEST_NAME).read_text())
    del manifest["files"][catalog.INDEX_NAME]
    manifest["files"][catalog.LEGACY_INDEX_NAME] = {"bytes": len(gz), "sha256": sha256_bytes(gz)}
    (legacy / catalog.MANIFEST_NAME).write_text(json.dumps(manifest, indent=1, sort_keys=True) + "\n")
    monkeypatch.setenv("FETCHBENCH_OBJECT_ASSETS", str(legacy))
    catalog.clear_caches()
    try:
        assert catalog.load_index() == json.loads(text)
        script = load_script(ROOT / "scripts/maint/pack_assets.py", "pack_assets")
        assert script.main(["--assets", str(tmp_path), "--only", "catalog"]) == 0
        catalog.clear_caches()
        assert catalog.load_index() == json.loads(text) and catalog.verify_files(legacy)
        for name in (catalog.INDEX_NAME, catalog.MANIFEST_NAME):
            assert (legacy / name).read_bytes() == (shipped / name).read_bytes()
    finally:
        monkeypatch.delenv("FETCHBENCH_OBJECT_ASSETS")
        catalog.clear_caches()


def test_nothing_shipped_is_left_unpacked(capsys):
    """A plain .pt, .npz shard, .json.gz suite or index, or .gz run added to the tree fails here:
    `python scripts/maint/pack_assets.py` packs it."""
    script = load_script(ROOT / "scripts/maint/pack_assets.py", "pack_assets")
    assert script.main(["--check"]) == 0, capsys.readouterr().out
