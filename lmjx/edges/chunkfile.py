"""The chunk files of a streamed build's partial folder (`<out>.partial/edges-<a>-<b>.chunk`):
one packed chunk of sampled edges [a, b) each, kept until the map is finished so that a
killed build resumes from them, read back by the map-writing process (`mapwriter`), and
read again at the end to sort the spatial index and to hash the map's states for its
content digest (`mapappend`: the bytes the map holds, without decompressing it).

A file is a header and the chunk's arrays, raw, each starting at a multiple of 64 bytes:

    b"LMJXCHK2" | header length (8 bytes, little-endian) | header (JSON) | arrays

The header holds the chunk's counts and, per array, its dtype, shape, offset in the file and
CRC-32, which catches a damaged array on reading.  Raw, not compressed: on 2 H200s
(benchmarks/RESULTS.md) deflating the arrays on saving and inflating them again
in the writing process took about 55 CPU-seconds of a 5M-edge build, for a partial folder
0.6 of the size.  Writing hands numpy's buffers straight to the file (the interpreter lock
is released while the kernel copies them), reading fills one buffer the arrays are views
of.

Files are written atomically (a killed build leaves a chunk whole or absent) but not synced
to disk one by one: `saved_chunks` drops a file shorter than its header says, and `read`
removes one whose checksum fails; either is only left by a crash of the machine, and the
chunk is then computed again.
"""

from __future__ import annotations

import json
import os
import re
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from lmjx.errors import LmjxError

if TYPE_CHECKING:  # (the map-writing process reads chunk files without JAX: `mapappend`)
    from lmjx.edges.chunk import EdgeChunk

try:
    from isal.isal_zlib import crc32  # 3x zlib's
except ImportError:  # pragma: no cover - isal is a dependency
    from zlib import crc32

MAGIC = b"LMJXCHK2"
ALIGN = 64
NAME = re.compile(r"^edges-(\d+)-(\d+)\.chunk$")


class ChunkFileError(LmjxError):
    """A chunk file that cannot be read back: damaged (then removed, so that a rerun
    computes it again), or not readable from the file system now (then kept)."""


def chunk_path(folder: Path, a: int, b: int) -> Path:
    return folder / f"edges-{a}-{b}.chunk"


def _up(n: int) -> int:
    return -(-n // ALIGN) * ALIGN


def save(folder: Path, chunk: EdgeChunk) -> Path:
    """A packed chunk into `folder`, atomically; its path back."""
    path = chunk_path(folder, chunk.start, chunk.stop)
    tmp = folder / f".{path.name}.{os.getpid()}.tmp"
    arrays = {k: np.ascontiguousarray(getattr(chunk, k)) for k in chunk.ARRAYS}
    # offsets relative to the end of the (padded) header
    table, at = {}, 0
    for k, a in arrays.items():
        table[k] = [a.dtype.str, list(a.shape), at, crc32(a)]
        at = _up(at + a.nbytes)
    head = json.dumps({"rolled_out": chunk.rolled_out, "states_evaluated": chunk.states_evaluated,
                       "seconds": chunk.seconds, "size": at, "arrays": table}).encode()  # fmt: skip
    start = MAGIC + len(head).to_bytes(8, "little") + head
    with open(tmp, "wb") as fh:
        fh.write(start + bytes(_up(len(start)) - len(start)))
        for a in arrays.values():
            fh.write(a.reshape(-1).view(np.uint8))  # no copy
            fh.write(bytes(_up(a.nbytes) - a.nbytes))
    os.replace(tmp, path)
    return path


def _header(fh) -> tuple[dict, int]:
    """(header, where the arrays start) of an open chunk file."""
    start = fh.read(16)
    if len(start) < 16 or start[:8] != MAGIC:
        raise ValueError("not a chunk file")
    n = int.from_bytes(start[8:], "little")
    head = json.loads(fh.read(n))
    return head, _up(16 + n)


def read(folder: Path, a: int, b: int, names: tuple[str, ...] | None = None) -> tuple[dict, dict]:
    """The arrays `names` (None: all, `EdgeChunk.ARRAYS`) of a saved chunk (checked against
    their CRC-32), and its header.  A damaged file is removed and reported (ChunkFileError): the same command again
    computes that chunk anew.  One the file system fails to read is reported, and kept."""
    path = chunk_path(folder, a, b)
    if names is None:
        from lmjx.edges.chunk import EdgeChunk

        names = EdgeChunk.ARRAYS
    try:
        with open(path, "rb") as fh:
            head, base = _header(fh)
            table = head["arrays"]
            wanted = sorted((table[k][2], k) for k in names)
            lo = wanted[0][0]
            hi = max(off + _nbytes(table[k]) for off, k in wanted)
            raw = np.empty(hi - lo + ALIGN, np.uint8)  # one buffer, the arrays aligned views of it
            shift = -raw.ctypes.data % ALIGN
            buf = raw[shift : shift + hi - lo]
            fh.seek(base + lo)
            if fh.readinto(buf) != len(buf):
                raise ValueError("truncated")
        out = {}
        for off, k in wanted:
            dtype, shape, _, crc = table[k]
            arr = np.frombuffer(buf, np.dtype(dtype), int(np.prod(shape)), off - lo).reshape(shape)
            if crc32(arr) != crc:
                raise ValueError(f"{k}: checksum")
            out[k] = arr
        return out, head
    except (ValueError, KeyError) as e:  # its bytes are wrong: it goes
        path.unlink(missing_ok=True)
        raise ChunkFileError(
            f"{path.name} in {folder} was damaged ({e}) and is removed: rerun the same command to compute it again"
        ) from e
    except OSError as e:  # the file system's trouble, perhaps passing: the file stays
        raise ChunkFileError(f"{path.name} in {folder} could not be read ({e}); rerun the same command") from e


def _nbytes(entry: list) -> int:
    dtype, shape, _, _ = entry
    return int(np.prod(shape)) * np.dtype(dtype).itemsize


def load(folder: Path, a: int, b: int) -> EdgeChunk:
    from lmjx.edges.chunk import EdgeChunk

    arrays, head = read(folder, a, b)
    return EdgeChunk(start=a, stop=b, rolled_out=head["rolled_out"], states_evaluated=head["states_evaluated"],
                     seconds=head["seconds"], **arrays)  # fmt: skip


def saved_chunks(folder: Path) -> list[tuple[int, int]]:
    """The chunk ranges saved in a partial folder, in order; temporary files are removed,
    and files shorter than their header says (a crash of the machine), whose chunks are
    then computed again."""
    ranges = []
    for f in folder.iterdir():
        m = NAME.match(f.name)
        if m:
            try:
                with open(f, "rb") as fh:
                    head, base = _header(fh)
                if f.stat().st_size != base + head["size"]:
                    raise ValueError("truncated")
            except (OSError, ValueError, KeyError):
                f.unlink(missing_ok=True)
                continue
            ranges.append((int(m.group(1)), int(m.group(2))))
        elif f.name.startswith(".") and f.name.endswith(".tmp"):
            f.unlink(missing_ok=True)  # a save a kill interrupted
    return sorted(ranges)
