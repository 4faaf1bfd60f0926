"""HDF5's Fletcher-32 checksum of a chunk, for the chunks lmjx writes and reads itself.

Every chunked dataset of a map file carries HDF5's Fletcher-32 filter (the last of its
filters): HDF5 appends a 4-byte checksum to each filtered chunk and checks it whenever it
decodes the chunk, so any HDF5 reader (h5py, MATLAB, C++) detects a damaged chunk.  Where
lmjx writes compressed chunks itself (`write_direct_chunk`) or reads them raw
(`read_direct_chunk`), HDF5 does not apply the filter: `with_checksum` appends the checksum
exactly as HDF5's filter would (`H5_checksum_fletcher32` of the filtered bytes, stored
little-endian) and `strip_checksum` checks and removes it.  Nothing here reads or writes files.
"""

from __future__ import annotations

import numpy as np

FLETCHER_BYTES = 4
BLOCK_WORDS = 1 << 20  # 16-bit words summed at a time (the weighted sums then stay below 2**64)
_WEIGHTS = np.arange(BLOCK_WORDS, 0, -1, dtype=np.uint64)  # (BLOCK_WORDS,) n, n - 1, ..., 1


class ChecksumError(ValueError):
    """A chunk whose stored Fletcher-32 checksum does not match its bytes."""


def fletcher32(data: bytes | bytearray | memoryview | np.ndarray) -> int:
    """HDF5's Fletcher-32 (`H5_checksum_fletcher32`) of `data`: sums of its big-endian 16-bit
    words (an odd last byte as the high byte of a word), each sum folded to 16 bits with an
    end-around carry, so a sum that is a nonzero multiple of 65535 comes out as 0xffff.
    Returns (sum2 << 16) | sum1."""
    raw = np.frombuffer(data, np.uint8) if not isinstance(data, np.ndarray) else data.reshape(-1).view(np.uint8)
    if len(raw) % 2:
        raw = np.concatenate([raw, np.zeros(1, np.uint8)])
    words = raw.view(">u2")
    n = len(words)
    s1 = s2 = 0  # exact sums (Python ints), reduced modulo 65535 as they go
    for a in range(0, n, BLOCK_WORDS):
        block = words[a : a + BLOCK_WORDS].astype(np.uint64)
        k = len(block)
        b1 = int(block.sum())
        # sum2 adds sum1 after every word: word i of n counts n - i times
        b2 = int(np.dot(_WEIGHTS[BLOCK_WORDS - k :], block))
        s2 = (s2 + b2 + (n - a - k) * b1) % 65535
        s1 = (s1 + b1) % 65535
    nonzero = bool(n) and bool(words.any())
    # HDF5's folding never reaches 0 from a positive sum: a multiple of 65535 stays 0xffff
    if nonzero and s1 == 0:
        s1 = 0xFFFF
    if nonzero and s2 == 0:
        s2 = 0xFFFF
    return (s2 << 16) | s1


def with_checksum(filtered: bytes) -> bytes:
    """A chunk's filtered bytes with HDF5's Fletcher-32 filter applied (checksum appended)."""
    return filtered + fletcher32(filtered).to_bytes(FLETCHER_BYTES, "little")


def strip_checksum(raw: bytes, where: str = "chunk") -> memoryview:
    """The filtered bytes of a raw chunk stored with the Fletcher-32 filter, checked as HDF5
    checks them (it also accepts the checksum with the bytes of each 16-bit half swapped,
    as libraries before HDF5 1.6.3 wrote it); ChecksumError naming `where` if it fails."""
    if len(raw) < FLETCHER_BYTES:
        raise ChecksumError(f"{where} is shorter than its checksum")
    body = memoryview(raw)[:-FLETCHER_BYTES]
    stored = int.from_bytes(raw[-FLETCHER_BYTES:], "little")
    value = fletcher32(body)
    swapped = ((value & 0x00FF00FF) << 8) | ((value >> 8) & 0x00FF00FF)
    if stored not in (value, swapped):
        raise ChecksumError(f"{where} fails its checksum")
    return body
