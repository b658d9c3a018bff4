"""The packed form of a task suite file, ``<name>.suite.xz``: the suite's canonical JSON text,
rearranged so that xz finds more to share, and restored byte for byte on reading.

Almost all of a suite's bytes are floats (object poses, physics values, scene parameters),
interleaved with the keys around them. The packed form stores the text with every float
cut out, then each float in a column of its own key path (``arrangements/objects/density``
...), so that like values sit together. Layout, one xz stream (``utils.packed.xz_bytes``)::

    header line     JSON: format, version, ``json_gz_sha256``, and per column its key path,
                    encoding, count of values and bytes
    skeleton        the canonical JSON text with each float replaced by a NUL byte
                    (canonical JSON is ASCII with control characters escaped: no NUL of its own)
    column ids      a little-endian uint16 per float, in text order: the column it is taken from
    columns         in header order: ``text``, each value's ``repr`` and a newline, or ``f64``,
                    the little-endian float64 values as 8 byte planes (``utils.packed``); a
                    column whose values average more than 12 characters (full-precision
                    floats) is smaller as f64, one of rounded values as text

Unpacking puts each column's next value back at each NUL in turn: the result is the
canonical JSON text itself (``json.dumps`` writes a float as its ``repr``), which
``suite.load_suite`` then reads and checks against the suite's sha256 as for any suite file.

``json_gz_sha256`` is the sha256 of the suite's ``.json.gz`` file (``TaskSuite.save``): what
a run records as its suite's identity (``source_sha256``) and the test-split guard knows test
suites by, so that a suite keeps its identity in either form (``suite.suite_file_sha256``).
"""
from __future__ import annotations

import json
import lzma

import numpy as np

from ..utils.packed import header_line, join_planes, split_planes, unxz_bytes, xz_bytes

SUFFIX = ".suite.xz"
FORMAT = "fetchbench-task-suite-packed"
VERSION = 1
#: Floats whose repr averages more than this many characters go into an f64 column.
TEXT_MAX_CHARS = 12
_HOLE = '"\\u0000"'  # how json.dumps writes the placeholder string "\0" that stands for a float


def _cut_floats(node, path: str, columns: dict[str, list[float]], order: list[str]):
    """``node`` with every float replaced by "\\0"; the floats, in canonical text order (sorted
    keys), appended to their key path's column and their path to ``order``."""
    if isinstance(node, dict):
        return {key: _cut_floats(node[key], f"{path}/{key}" if path else key, columns, order) for key in sorted(node)}
    if isinstance(node, list):
        return [_cut_floats(item, path, columns, order) for item in node]
    if isinstance(node, float):
        columns.setdefault(path, []).append(node)
        order.append(path)
        return "\0"
    return node


def pack(text: bytes, json_gz_sha256: str) -> bytes:
    """The packed form of a suite's canonical JSON ``text`` (ValueError if it is not canonical)."""
    columns: dict[str, list[float]] = {}
    order: list[str] = []
    skeleton = json.dumps(_cut_floats(json.loads(text), "", columns, order), sort_keys=True,
                          separators=(",", ":"), allow_nan=False)
    if skeleton.count(_HOLE) != len(order):  # a string "\0" of its own would take a float's place
        raise ValueError("a suite's JSON holds the string \"\\u0000\": it cannot be packed")
    skeleton_bytes = skeleton.replace(_HOLE, "\0").encode("ascii")
    names = list(columns)
    if len(names) > 1 << 16:
        raise ValueError(f"a suite with floats under {len(names)} key paths cannot be packed (at most 65536)")
    index = {name: k for k, name in enumerate(names)}
    entries, parts = [], []
    for name in names:
        values = columns[name]
        reprs = "".join(f"{v!r}\n" for v in values).encode("ascii")
        if len(reprs) > (TEXT_MAX_CHARS + 1) * len(values):
            data, encoding = split_planes(np.array(values, dtype="<f8").tobytes(), 8), "f64"
        else:
            data, encoding = reprs, "text"
        entries.append([name, encoding, len(values), len(data)])
        parts.append(data)
    line = json.dumps({"format": FORMAT, "version": VERSION, "json_gz_sha256": json_gz_sha256,
                       "skeleton_bytes": len(skeleton_bytes), "columns": entries},
                      sort_keys=True, separators=(",", ":"))
    ids = np.array([index[p] for p in order], dtype="<u2").tobytes()
    packed = xz_bytes(b"".join([line.encode("ascii"), b"\n", skeleton_bytes, ids, *parts]))
    if unpack(packed)[0] != text:  # every float goes back where it was, or nothing is written
        raise ValueError("the suite's packed form does not unpack to its text")
    return packed


def header(data: bytes, what="suite") -> dict:
    """The header alone, from the start of the stream (the rest is not decompressed)."""
    decompressor = lzma.LZMADecompressor(format=lzma.FORMAT_XZ)
    try:
        start = decompressor.decompress(data, max_length=1 << 16)
        while b"\n" not in start and not decompressor.eof and not decompressor.needs_input:
            start += decompressor.decompress(b"", max_length=1 << 20)
    except lzma.LZMAError as error:
        raise ValueError(f"{what} is not a complete xz stream ({error})") from None
    return header_line(start.partition(b"\n")[0], FORMAT, VERSION, what)


def unpack(data: bytes, what="suite") -> tuple[bytes, dict]:
    """(the suite's canonical JSON text, the header) of a packed suite."""
    content = unxz_bytes(data, what)
    line, _, rest = content.partition(b"\n")
    head = header_line(line, FORMAT, VERSION, what)
    columns = head["columns"]
    n_floats = sum(count for _, _, count, _ in columns)
    skeleton = rest[: head["skeleton_bytes"]]
    ids = np.frombuffer(rest, dtype="<u2", count=n_floats, offset=head["skeleton_bytes"])
    start = head["skeleton_bytes"] + 2 * n_floats
    if n_floats and int(ids.max()) >= len(columns):
        raise ValueError(f"{what} is damaged: a float of column {int(ids.max())} of {len(columns)}")
    places = np.argsort(ids, kind="stable")  # column 0's places in text order, then column 1's, ...
    bounds = np.concatenate([[0], np.cumsum(np.bincount(ids, minlength=len(columns)))])
    values = np.empty(n_floats, dtype=object)
    for k, (name, encoding, count, size) in enumerate(columns):
        data = rest[start:start + size]
        if encoding == "f64":
            texts = [repr(v) for v in np.frombuffer(join_planes(data, 8), dtype="<f8").tolist()]
        elif encoding == "text":
            texts = data.decode("ascii").split("\n")[:-1]
        else:
            raise ValueError(f"{what}: column {name!r} has an unknown encoding {encoding!r}")
        if len(texts) != count or bounds[k + 1] - bounds[k] != count:
            raise ValueError(f"{what}: column {name!r} holds {len(texts)} values for {bounds[k + 1] - bounds[k]} places")
        values[places[bounds[k]:bounds[k + 1]]] = texts
        start += size
    pieces = skeleton.decode("ascii").split("\0")
    if len(pieces) != n_floats + 1 or start != len(rest):
        raise ValueError(f"{what} is damaged: its parts do not add up")
    out = [None] * (2 * n_floats + 1)
    out[0::2], out[1::2] = pieces, values.tolist()
    return "".join(out).encode("ascii"), head
