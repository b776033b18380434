"""The HDF5 superblock, read before HDF5 opens a file: signature, end-of-file address, the
"open for writing" status flags, and clearing those flags (what ``h5clear -s`` does).

Why: HDF5 itself answers a truncated file with a quick error only in normal mode; a file whose
writer never closed it only opens in SWMR read mode, where HDF5 retries failed metadata reads
with growing sleeps (minutes on a damaged file).  Reading the few header bytes first gives a
one-line error at once and tells which mode to use.

Layout (HDF5 File Format Specification, section II.A): the 8-byte signature at offset 0, 512,
1024, 2048, ... (after a user block); version 0/1: sizes at bytes 13-14, addresses from byte 24
(version 1: 28), the end-of-file address third; version 2/3: sizes at bytes 9-10, status flags
at byte 11, four addresses from byte 12 (base, extension, end of file, root), then a Jenkins
lookup3 checksum of everything before it.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

from imucal_cli.formats.inputs import SIGNATURE

_WRITE_ACCESS = 0x01  # version 3 status flags: opened for writing
_SWMR_WRITE = 0x04  # ... in SWMR write mode
_M32 = 0xFFFFFFFF


class SuperblockError(ValueError):
    """The header is missing or damaged; the message says what is wrong, in a few words."""


@dataclass(frozen=True)
class Superblock:
    """What the reader needs from the header.

    Attributes
    ----------
    offset : int
        Byte offset of the signature (the size of the user block).
    version : int
        Superblock version, 0 to 3.
    eof : int
        End of the HDF5 data the header declares, bytes from the start of the file (a user
        block included).
    flags : int
        Status flags (version 2/3; 0 for older versions).
    size : int
        The file's size in bytes.
    """

    offset: int
    version: int
    eof: int
    flags: int
    size: int

    @property
    def open_for_write(self) -> bool:
        """Whether the writer has not closed the file (killed, or still writing)."""
        return self.version >= 3 and bool(self.flags & (_WRITE_ACCESS | _SWMR_WRITE))


def _rot(x: int, k: int) -> int:
    return ((x << k) | (x >> (32 - k))) & _M32


def _mix_half(a: int, b: int, c: int, k1: int, k2: int, k3: int) -> tuple[int, int, int]:
    """Half of lookup3's ``mix()``: three subtract, xor and rotate steps (by ``k1, k2, k3``)."""
    a = (a - c) & _M32 ^ _rot(c, k1)
    c = (c + b) & _M32
    b = (b - a) & _M32 ^ _rot(a, k2)
    a = (a + c) & _M32
    c = (c - b) & _M32 ^ _rot(b, k3)
    b = (b + a) & _M32
    return a, b, c


def lookup3(data: bytes, initval: int = 0) -> int:
    """Bob Jenkins' lookup3 ``hashlittle``, HDF5's metadata checksum (``H5_checksum_lookup3``)."""
    n = len(data)
    a = b = c = (0xDEADBEEF + n + initval) & _M32
    i = 0
    while n > 12:
        a = (a + int.from_bytes(data[i : i + 4], "little")) & _M32
        b = (b + int.from_bytes(data[i + 4 : i + 8], "little")) & _M32
        c = (c + int.from_bytes(data[i + 8 : i + 12], "little")) & _M32
        a, b, c = _mix_half(a, b, c, 4, 6, 8)  # lookup3's mix(): two halves
        a, b, c = _mix_half(a, b, c, 16, 19, 4)
        n -= 12
        i += 12
    if n == 0:
        return c
    tail = data[i:] + bytes(12 - n)
    a = (a + int.from_bytes(tail[0:4], "little")) & _M32
    b = (b + int.from_bytes(tail[4:8], "little")) & _M32
    c = (c + int.from_bytes(tail[8:12], "little")) & _M32
    c = (c ^ b) - _rot(b, 14) & _M32
    a = (a ^ c) - _rot(c, 11) & _M32
    b = (b ^ a) - _rot(a, 25) & _M32
    c = (c ^ b) - _rot(b, 16) & _M32
    a = (a ^ c) - _rot(c, 4) & _M32
    b = (b ^ a) - _rot(a, 14) & _M32
    c = (c ^ b) - _rot(b, 24) & _M32
    return c


def _find_signature(fd: int, size: int) -> int:
    offset = 0
    while offset + len(SIGNATURE) <= size:
        if os.pread(fd, len(SIGNATURE), offset) == SIGNATURE:
            return offset
        offset = 512 if offset == 0 else offset * 2
    raise SuperblockError("not an HDF5 file")


def _layout(version: int, head: bytes) -> tuple[int, int, int]:
    """(size of addresses, byte of the first address, bytes up to the checksum or end)."""
    if version in (0, 1):
        sizeof_addr = head[13]
        first = 24 if version == 0 else 28
        return sizeof_addr, first, first + 4 * sizeof_addr
    sizeof_addr = head[9]
    return sizeof_addr, 12, 12 + 4 * sizeof_addr


def read_superblock(fd: int) -> tuple[Superblock, bytes]:
    """Parse the superblock of an open file; return it and its raw bytes.

    Raises
    ------
    SuperblockError
        No signature, an unknown version, a header cut short, a checksum that does not match,
        or a file shorter than the end-of-file address its header declares (truncated).
    """
    size = os.fstat(fd).st_size
    offset = _find_signature(fd, size)
    head = os.pread(fd, 64, offset)
    if len(head) < 16:
        raise SuperblockError(f"truncated: {size} bytes, the HDF5 header is cut short")
    version = head[8]
    if version > 3:
        raise SuperblockError(f"unknown HDF5 superblock version {version}")
    sizeof_addr, first, end = _layout(version, head)
    if sizeof_addr not in (2, 4, 8):
        raise SuperblockError(f"damaged HDF5 header (address size {sizeof_addr})")
    need = end + (4 if version >= 2 else 0)
    if len(head) < need or offset + need > size:
        raise SuperblockError(f"truncated: {size} bytes, the HDF5 header is cut short")
    raw = head[:need]
    if version >= 2:
        stored = int.from_bytes(raw[end : end + 4], "little")
        if lookup3(raw[:end]) != stored:
            raise SuperblockError("damaged HDF5 header (superblock checksum does not match)")

    def address(k: int) -> int:
        return int.from_bytes(
            raw[first + k * sizeof_addr : first + (k + 1) * sizeof_addr], "little"
        )

    # The end-of-file address counts from the start of the file, user block included: HDF5
    # itself (H5F__super_read) refuses a file as truncated when its size is below the stored
    # address, whatever the base address (the user block's size) is.  Adding the base to it
    # refused every valid file with a user block (issue 26).
    eof = address(2)
    if eof > size:
        raise SuperblockError(
            f"truncated: the file has {size} bytes, its HDF5 header says {eof} "
            "(copied or downloaded only in part?)"
        )
    flags = raw[11] if version >= 2 else 0
    return Superblock(offset, version, eof, flags, size), raw


def clear_status_flags(path: str | os.PathLike) -> bool:
    """Clear the "open for writing" flags of a version 3 superblock in place (``h5clear -s``).

    Only for a file whose writer is known to be gone.  Returns whether anything was changed.

    Raises
    ------
    OSError
        The file cannot be opened for writing.
    SuperblockError
        The header is damaged.
    """
    fd = os.open(path, os.O_RDWR | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0))
    try:
        block, raw = read_superblock(fd)
        if not block.open_for_write:
            return False
        end = len(raw) - 4
        patched = bytearray(raw)
        patched[11] = 0
        patched[end:] = lookup3(bytes(patched[:end])).to_bytes(4, "little")
        os.pwrite(fd, bytes(patched), block.offset)
        os.fsync(fd)
        return True
    finally:
        os.close(fd)
