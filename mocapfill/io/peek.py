"""What a capture file holds, cheaply: :func:`peek` reads a file's header and a bounded sample of its data.

``batch`` orders its files by expected cost with it (the fill's time grows with the missing samples far more than
with the file's size).  Only a hint: it never raises, and what it cannot tell it leaves None.

- C3D: frames and points from the header and parameters; the missing fraction from the point words of at most
  :data:`SCAN_FRAMES` evenly spaced frames, decoded as :mod:`mocapfill.io.c3d` reads them (negative residual,
  non-finite or all-zero coordinates).  Only those frames' words are read, one by one: a memory map's fault-around
  would bring in most of a big file.
- TRC: frames and markers from the header line under ``NumFrames`` / ``NumMarkers``.
- Text (TRC, CSV, TSV, Motive CSV): the share of fields that are empty or a NaN token (or zero, in a QTM TSV, which
  writes a missing sample as zeros) in :data:`TEXT_CHUNKS` chunks spread over the file (at most :data:`SCAN_BYTES`),
  and, where the header does not say, samples = the file's size / :data:`TEXT_BYTES_PER_SAMPLE`.
"""

from __future__ import annotations

import dataclasses
import mmap
import os
import re
from typing import NamedTuple

import numpy as np

#: The scan reads at most this many frames of a C3D (evenly spaced) and this many bytes of a text file (in
#: :data:`TEXT_CHUNKS` spread chunks): a few milliseconds per file, whatever its size.
SCAN_FRAMES = 1000
SCAN_BYTES = 1 << 18
#: Many small chunks follow the gaps along a capture (they come in stretches) better than a few big ones.
TEXT_CHUNKS = 64
#: Bytes per sample (one marker in one frame) of a text capture whose header does not give its size.
TEXT_BYTES_PER_SAMPLE = 25

#: A text field that counts as a missing coordinate (what the text readers read as NaN).
_MISSING_FIELD = re.compile(rb"(?<=[\t,])[ ]*(?:nan|-nan|null|na|n/a)?[ ]*(?=[\t,\r\n])", re.IGNORECASE)
_MISSING_OR_ZERO_FIELD = re.compile(rb"(?<=[\t,])[ ]*(?:nan|-nan|null|na|n/a|-?0(?:\.0*)?)?[ ]*(?=[\t,\r\n])",
                                    re.IGNORECASE)
_FIELD_SEPARATORS = re.compile(rb"[\t,]")


class Peek(NamedTuple):
    """What :func:`peek` found: ``samples`` = frames x points (None when unknown), ``missing`` the estimated
    fraction of missing samples (None when unknown)."""

    samples: int | None
    missing: float | None


def peek(path: str | os.PathLike, *, scan: bool = True) -> Peek:
    """Frames x points and the missing fraction of the capture at ``path`` from its header and a bounded scan
    (``scan=False``: the header alone).  Never raises; a FIFO or device is not opened (its reader would block)."""
    path = os.fspath(path)
    try:
        if not os.path.isfile(path):
            return Peek(None, None)
        with open(path, "rb") as handle:
            head = handle.read(2 * 512)
            size = os.fstat(handle.fileno()).st_size
            if size == 0:
                return Peek(None, None)
            if len(head) >= 2 and head[1] == 0x50:
                found = _peek_c3d(handle, head, path, scan)
                return found if found.samples else Peek(size // TEXT_BYTES_PER_SAMPLE or None, found.missing)
            samples = _trc_samples(head) or size // TEXT_BYTES_PER_SAMPLE or None
            if not scan:
                return Peek(samples, None)
            return Peek(samples, _text_missing_fraction(handle, size, path.lower().endswith(".tsv")))
    except Exception:  # noqa: BLE001 - only a hint: whatever went wrong, the file's reader reports it
        return Peek(None, None)


def _c3d_header_samples(head: bytes) -> int | None:
    """Points x frames from a C3D header block's 16-bit words (processor type from the parameter block)."""
    if len(head) < 1024:
        return None
    pstart = ((head[0] or 2) - 1) * 512
    order = "big" if pstart + 3 < len(head) and head[pstart + 3] == 86 else "little"  # 86: MIPS, big-endian
    points, first, last = (int.from_bytes(head[2 * k:2 * k + 2], order) for k in (1, 3, 4))
    return points * (last - first + 1) if last >= first and points > 0 else None


def _peek_c3d(handle, head: bytes, path: str, scan: bool) -> Peek:
    from .c3d import decode_points
    from .c3dfile import parse

    if not scan:
        return Peek(_c3d_header_samples(head), None)
    # parse reads the header and the parameters through the map (and the data section only when nothing else gives
    # the frame count); the sampled frames' point words are then read one by one.
    with mmap.mmap(handle.fileno(), 0, access=mmap.ACCESS_READ) as raw:
        if hasattr(raw, "madvise"):
            raw.madvise(mmap.MADV_RANDOM)
        f = parse(raw, path)
    if f.n_frames == 0 or f.n_points == 0:
        return Peek(None, None)
    row = 4 * f.n_points * f.word_size
    words = bytearray()
    for frame in range(0, f.n_frames, -(-f.n_frames // SCAN_FRAMES)):
        handle.seek(f.data_offset + frame * f.frame_bytes)
        words += handle.read(row)
    sampled = dataclasses.replace(f, raw=bytes(words), n_frames=len(words) // row, data_offset=0, analog_words=0)
    positions, _ = decode_points(sampled, sampled.point_block())
    return Peek(f.n_frames * f.n_points, float(np.isnan(positions[:, :, 0]).mean()))


def _trc_samples(head: bytes) -> int | None:
    """NumFrames x NumMarkers of a TRC header, None for another format or a header without them."""
    if head[:12].lower() != b"pathfiletype":
        return None
    lines = head.decode("latin-1").splitlines()
    if len(lines) < 3:
        return None
    sep = "\t" if "\t" in lines[1] else ","
    meta = dict(zip((k.strip() for k in lines[1].split(sep)), (v.strip() for v in lines[2].split(sep))))
    try:
        samples = int(meta["NumFrames"]) * int(meta["NumMarkers"])
    except (KeyError, ValueError):
        return None
    return samples if samples > 0 else None


def _text_missing_fraction(handle, size: int, zeros_missing: bool) -> float | None:
    chunk = SCAN_BYTES // TEXT_CHUNKS
    starts = [0] if size <= SCAN_BYTES else [k * (size - chunk) // (TEXT_CHUNKS - 1) for k in range(TEXT_CHUNKS)]
    pattern = _MISSING_OR_ZERO_FIELD if zeros_missing else _MISSING_FIELD
    missing = fields = 0
    for start in starts:
        handle.seek(start)
        text = handle.read(size if len(starts) == 1 else chunk)
        missing += len(pattern.findall(text))
        fields += len(_FIELD_SEPARATORS.findall(text))
    return missing / fields if fields else None
