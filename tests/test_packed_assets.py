"""The shipped assets' packed forms (fetchbench_ms/utils/packed.py, scripts/maint/pack_assets.py)
are lossless: each unpacks to exactly what it replaced, and packing is byte-reproducible."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from fetchbench_ms.utils import packed
from script_modules import load_script

ROOT = Path(__file__).resolve().parents[1]
CHECKPOINTS = ROOT / "assets" / "checkpoints"
#: sha256 of the .pt files the shipped checkpoints were packed from (the checkpoints' JSON and
#: the evaluation records name the same ones, where they name one).
PT_SHA256 = {
    "cgn_ours": "c8dda80d2a1f697586064d2fbda1c2d2ddbf08d9b646248bbbc33d9be946d0e7",
    "collision_net": "bf1c9be6e2f09e95a7c01478a735064aff67d2326cb185accb93d64e12d9f973",
    "imit_act": "1ea55247db12a728bb5be2328227136d80555b2cb1061e1aa3659783bf842f7a",
    "imit_diffusion": "9c3a6598835ea9701446ba3a6f740b0cca1d883d658d19011687979c4a6be823",
    "imit_mlp": "d1709d1994719a66b6a9ccba48560b1b0daeda3cfcb4100155f4ad48c5855cb9",
    "imit_transformer": "c9f433c681f8e2f449a39415392bd30132eea1e53f6edfd365d280c13ba6ee2d",
}


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
