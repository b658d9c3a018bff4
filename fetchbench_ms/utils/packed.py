"""Lossless packing of the shipped binary assets: xz with fixed settings, over byte planes.

A checkout is copied whole to every machine that runs the benchmark, so the large shipped
files are kept small. Two forms, both byte-reproducible (fixed xz settings, no timestamps):

- ``<file>.planes.xz`` (the shipped checkpoints): the file's bytes split into two planes,
  the bytes at even offsets and then those at odd offsets, xz-compressed. A ``.pt`` file's
  fp16 weights start at even offsets (torch aligns them to 64 bytes), so the planes are
  their low bytes (mantissa bits, close to random) and their high bytes (sign, exponent:
  few distinct values), which compress far better apart than interleaved. Unpacking gives
  the original file back byte for byte, so its sha256 is the one records name.
- ``<file>.arrays.xz`` (the grasp shards): named numpy arrays, each stored as its byte
  planes, after a one-line JSON header of names, dtypes and shapes, all xz-compressed.

The xz settings are preset 9 with the extreme flag, a CRC32 check and a dictionary no
larger than the data needs (``_dictionary_size``); the same input gives the same bytes
with the same liblzma.
"""
from __future__ import annotations

import json
import lzma
import os
from pathlib import Path

import numpy as np

PLANES_SUFFIX = ".planes.xz"
ARRAYS_SUFFIX = ".arrays.xz"
#: The byte planes of a ``.planes.xz`` file: 2, the bytes of an fp16 number.
PLANE_WIDTH = 2
ARRAYS_FORMAT = "fetchbench-arrays"
ARRAYS_VERSION = 1


def _dictionary_size(n_bytes: int) -> int:
    """The smallest power of two >= the data (4 KiB to 64 MiB, preset 9's own): a larger
    dictionary compresses no better and costs the reader the memory."""
    size = 4096
    while size < n_bytes and size < 64 << 20:
        size *= 2
    return size


def xz_bytes(data: bytes) -> bytes:
    filters = [{"id": lzma.FILTER_LZMA2, "preset": 9 | lzma.PRESET_EXTREME, "dict_size": _dictionary_size(len(data))}]
    return lzma.compress(data, format=lzma.FORMAT_XZ, check=lzma.CHECK_CRC32, filters=filters)


def unxz_bytes(data: bytes, what: str | os.PathLike = "data") -> bytes:
    """The content of an xz stream; ValueError naming ``what`` for a truncated or foreign one."""
    try:
        return lzma.decompress(data, format=lzma.FORMAT_XZ)
    except lzma.LZMAError as error:
        raise ValueError(f"{what} is not a complete xz stream ({error})") from None


def split_planes(data: bytes, width: int) -> bytes:
    """The bytes at offsets 0, width, 2 width, ..., then those at 1, width + 1, ..., and so on."""
    return b"".join(data[k::width] for k in range(width))


def join_planes(data: bytes, width: int) -> bytes:
    """Inverse of ``split_planes`` (plane k holds the bytes at offsets = k mod width)."""
    out = bytearray(len(data))
    start = 0
    for k in range(width):
        count = (len(data) - k + width - 1) // width
        out[k::width] = data[start:start + count]
        start += count
    return bytes(out)


def pack_planes(data: bytes) -> bytes:
    """The ``.planes.xz`` form of a file's bytes."""
    return xz_bytes(split_planes(data, PLANE_WIDTH))


def unpack_planes(packed: bytes, what: str | os.PathLike = "data") -> bytes:
    return join_planes(unxz_bytes(packed, what), PLANE_WIDTH)


def packed_or_plain(path: str | os.PathLike) -> Path:
    """``path`` when it exists, else its packed copy ``<path>.planes.xz`` when that exists
    (the shipped checkpoints are packed: ``imit_mlp.pt`` names ``imit_mlp.pt.planes.xz``),
    else ``path`` (for the caller to report missing)."""
    path = Path(path)
    packed = path.with_name(path.name + PLANES_SUFFIX)
    return packed if not path.exists() and packed.is_file() else path


def file_bytes(path: str | os.PathLike) -> bytes:
    """A file's content: a ``.planes.xz`` file unpacked, any other file as it is."""
    path = Path(path)
    if path.name.endswith(PLANES_SUFFIX):
        return unpack_planes(path.read_bytes(), path)
    return path.read_bytes()


def content_sha256(path: str | os.PathLike) -> str:
    """sha256 of ``file_bytes(path)``: a packed checkpoint hashes as the ``.pt`` it packs."""
    import hashlib

    return hashlib.sha256(file_bytes(path)).hexdigest()


def torch_load(path: str | os.PathLike, **kwargs):
    """``torch.load`` of a checkpoint file, packed (``.planes.xz``) or not."""
    import io

    import torch

    return torch.load(io.BytesIO(file_bytes(path)), **kwargs)


def _plane_width(dtype: np.dtype) -> int:
    if dtype.kind in "biufc":
        return dtype.itemsize
    if dtype.kind == "U":
        return 4  # UCS-4 code units
    raise ValueError(f"arrays of dtype {dtype} are not packed (numbers and str only)")


def pack_arrays(arrays: dict[str, np.ndarray]) -> bytes:
    """The ``.arrays.xz`` form of named arrays (in the given order)."""
    header, planes = [], []
    for name, array in arrays.items():
        array = np.asarray(array)  # (not ascontiguousarray: it makes a 0-d array 1-d)
        header.append([name, array.dtype.str, list(array.shape)])
        planes.append(split_planes(array.tobytes(order="C"), _plane_width(array.dtype)))
    line = json.dumps({"format": ARRAYS_FORMAT, "version": ARRAYS_VERSION, "arrays": header},
                      sort_keys=True, separators=(",", ":"))
    return xz_bytes(line.encode() + b"\n" + b"".join(planes))


def header_line(line: bytes, file_format: str, version: int, what: str | os.PathLike = "data") -> dict:
    """The JSON header line of a packed file, checked to be of ``file_format`` and ``version``."""
    try:
        header = json.loads(line)
    except (json.JSONDecodeError, UnicodeDecodeError):
        header = None
    if not isinstance(header, dict) or header.get("format") != file_format:
        raise ValueError(f"{what} is not a {file_format} file")
    if header.get("version") != version:
        raise ValueError(f"{what}: {file_format} version {header.get('version')!r}, this code reads {version}")
    return header


def unpack_arrays(packed: bytes, what: str | os.PathLike = "data") -> dict[str, np.ndarray]:
    """Inverse of ``pack_arrays``: the same names, dtypes, shapes and values, in order."""
    line, _, body = unxz_bytes(packed, what).partition(b"\n")
    header = header_line(line, ARRAYS_FORMAT, ARRAYS_VERSION, what)
    arrays, start = {}, 0
    for name, dtype_str, shape in header["arrays"]:
        dtype = np.dtype(dtype_str)
        size = dtype.itemsize * int(np.prod(shape, dtype=np.int64))
        if start + size > len(body):
            raise ValueError(f"{what} ends inside its array {name!r}")
        chunk = join_planes(body[start:start + size], _plane_width(dtype))
        arrays[name] = np.frombuffer(chunk, dtype=dtype).reshape(shape).copy()
        start += size
    if start != len(body):
        raise ValueError(f"{what}: {len(body) - start} bytes beyond its arrays")
    return arrays
