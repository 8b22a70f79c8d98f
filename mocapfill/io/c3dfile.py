"""Low-level C3D: header, parameter section and the layout of the data section, parsed tolerantly.

Our own parser (rather than the ``c3d`` package's reader) because a faithful rewrite needs the byte offsets of
every part of the original file, and because several valid files in the wild trip the package's strict checks
(duplicate parameter names, a SCALE parameter stored with an unusual type, header and parameters disagreeing on the
scale).  Only genuinely unreadable content raises :class:`FormatError`.

C3D in brief: 512-byte blocks.  Block 1 is the header (16-bit words: parameter block, point count, analog values per
frame, first / last frame, scale, data start block, rate).  The parameter section starts with 4 bytes (the third is
its block count, the fourth the processor type: 84 Intel, 85 DEC, 86 MIPS) followed by a chain of groups and
parameters.  The data section holds, per frame, ``4 * n_points`` words (x, y, z, residual/camera word) and then the
analog words; words are int16 when the point scale is positive, float32 when it is negative.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field

import numpy as np

from ..errors import FormatError

BLOCK = 512
#: Byte offset of the frame rate (a float in the processor's format) in the header.
HEADER_RATE_AT = 20
INTEL, DEC, MIPS = 84, 85, 86
PROCESSOR_NAMES = {INTEL: "Intel", DEC: "DEC", MIPS: "MIPS"}


# --- numbers in each processor's format ----------------------------------------------------------------------------

def int16_dtype(processor: int) -> np.dtype:
    return np.dtype(">i2" if processor == MIPS else "<i2")


def uint16_dtype(processor: int) -> np.dtype:
    return np.dtype(">u2" if processor == MIPS else "<u2")


def decode_floats(raw: np.ndarray | bytes, processor: int) -> np.ndarray:
    """float32 values (as float32 array) from bytes stored in ``processor``'s float format.

    DEC (VAX F-floating) keeps its two 16-bit halves in the opposite order to IEEE little-endian and has an exponent
    bias two higher, so swapping the halves and dividing by 4 gives the value (exact: a power-of-two scaling).
    """
    buf = np.frombuffer(bytes(raw) if not isinstance(raw, np.ndarray) else raw.tobytes(), dtype=np.uint8)
    if processor == MIPS:
        return buf.view(">f4").astype(np.float32)
    if processor == DEC:
        swapped = buf.reshape(-1, 4)[:, [2, 3, 0, 1]].copy()
        with np.errstate(over="ignore", invalid="ignore"):
            return swapped.view("<f4").ravel() / np.float32(4.0)
    return buf.view("<f4").copy()


def encode_floats(values: np.ndarray, processor: int) -> bytes:
    """Bytes of float32 ``values`` in ``processor``'s float format (inverse of :func:`decode_floats`)."""
    values = np.asarray(values, dtype=np.float32)
    if processor == MIPS:
        return values.astype(">f4").tobytes()
    if processor == DEC:
        with np.errstate(over="ignore"):
            scaled = (values * np.float32(4.0)).astype("<f4")
        return scaled.view(np.uint8).reshape(-1, 4)[:, [2, 3, 0, 1]].tobytes()
    return values.astype("<f4").tobytes()


# --- parameters ----------------------------------------------------------------------------------------------------

@dataclass
class Parameter:
    """One C3D parameter: ``dims`` in file order (first varies fastest), ``raw`` its data bytes, ``offset`` where
    they start in the file (for a rewrite that changes a value in place; -1 when not read from a file)."""

    group: str
    name: str
    type: int  # -1 char, 1 byte, 2 int16, 4 float
    dims: tuple[int, ...]
    raw: bytes
    description: str = ""
    offset: int = -1

    def values(self, processor: int) -> np.ndarray:
        """Numeric values as a flat array (int16 / float32 / int8); empty for char data."""
        if self.type == 2:
            return np.frombuffer(self.raw, dtype=int16_dtype(processor)).astype(np.int64)
        if self.type == 4:
            return decode_floats(self.raw[: len(self.raw) // 4 * 4], processor)
        if self.type == 1:
            return np.frombuffer(self.raw, dtype=np.int8).astype(np.int64)
        return np.zeros(0)

    def strings(self) -> list[str]:
        """Char data as a list of stripped strings (one per column of a 2-D char array)."""
        text = self.raw.decode("latin-1")
        if self.type != -1:
            return []
        if len(self.dims) <= 1:
            return [text.replace("\x00", " ").strip()]
        width = self.dims[0]
        count = int(np.prod(self.dims[1:]))
        if width == 0:
            return [""] * count
        return [text[i * width:(i + 1) * width].replace("\x00", " ").strip() for i in range(count)]


@dataclass
class C3DFile:
    """Everything parsed from a C3D file, plus where each part lies in the original bytes."""

    raw: bytes
    processor: int
    params: dict[tuple[str, str], Parameter]
    groups: list[str]
    n_points: int
    n_frames: int
    first_frame: int
    rate: float
    scale: float  # POINT:SCALE; negative = float storage
    is_float: bool
    data_offset: int  # byte offset of frame 0
    analog_words: int  # analog words per frame
    notes: list[str] = field(default_factory=list)

    @property
    def word_size(self) -> int:
        return 4 if self.is_float else 2

    @property
    def frame_bytes(self) -> int:
        return (4 * self.n_points + self.analog_words) * self.word_size

    def param(self, group: str, name: str) -> Parameter | None:
        return self.params.get((group.upper(), name.upper()))

    def number(self, group: str, name: str, default=None):
        """First numeric value of a parameter, or ``default`` when absent or empty."""
        p = self.param(group, name)
        if p is None:
            return default
        vals = p.values(self.processor)
        if vals.size == 0:
            return default
        return vals[0].item()

    def strings(self, group: str, name: str) -> list[str]:
        p = self.param(group, name)
        return p.strings() if p is not None else []

    def point_block(self) -> np.ndarray:
        """Raw point words of every frame: shape (n_frames, n_points, 4), int16 or float32 (file byte order)."""
        if self.n_points == 0:
            return np.zeros((self.n_frames, 0, 4), dtype=np.float32 if self.is_float else np.int16)
        words = 4 * self.n_points + self.analog_words
        if self.is_float:
            dtype = np.dtype(">f4" if self.processor == MIPS else "<f4")
        else:
            dtype = int16_dtype(self.processor)
        if self.is_float and self.processor == DEC:
            dtype = np.dtype("<u4")  # decoded below
        table = np.frombuffer(self.raw, dtype=dtype, count=self.n_frames * words, offset=self.data_offset)
        points = table.reshape(self.n_frames, words)[:, : 4 * self.n_points]
        if self.is_float and self.processor == DEC:
            return decode_floats(points.tobytes(), DEC).reshape(self.n_frames, self.n_points, 4)
        return points.reshape(self.n_frames, self.n_points, 4)


#: Characters accepted in a group or parameter name.  The C3D specification asks for upper-case letters, digits and
#: underscores, but real writers use more (Vicon Nexus: ``%RMMAX``; others ``$``, ``-``, ``.``, spaces), so any
#: printable ASCII character is accepted; whether the chain breaks is judged on the structure (see
#: :func:`plausible_entry`), not on the spelling.
NAME_CHARS = frozenset(range(0x20, 0x7F))
#: The largest number of dimensions a parameter may have (the specification allows 7).
MAX_DIMS = 7


def plausible_entry(raw: bytes, pos: int, end: int) -> bool:
    """Does ``pos`` hold the end of the chain (a zero name length or group id) or a well-formed group / parameter?

    Well formed: a name of printable characters (:data:`NAME_CHARS`), then for a group its description length, for
    a parameter a known type (-1, 1, 2, 4), at most :data:`MAX_DIMS` dimensions and its data, all inside the
    section (``end``).
    """
    if pos + 2 > end:
        return pos >= end - 1
    n_chars = abs(struct.unpack("b", raw[pos:pos + 1])[0])
    gid = struct.unpack("b", raw[pos + 1:pos + 2])[0]
    if n_chars == 0 or gid == 0:
        return True
    name = raw[pos + 2:pos + 2 + n_chars]
    if len(name) != n_chars or not all(c in NAME_CHARS for c in name) or not name.strip():
        return False
    p = pos + 2 + n_chars + 2  # past the name and the offset
    if gid < 0:
        return p < end and p + 1 + raw[p] <= end
    if p + 2 > end:
        return False
    ptype, ndim = struct.unpack("b", raw[p:p + 1])[0], raw[p + 1]
    if ptype not in (-1, 1, 2, 4) or ndim > MAX_DIMS or p + 2 + ndim > end:
        return False
    dims = raw[p + 2:p + 2 + ndim]
    size = abs(ptype) * int(np.prod(list(dims))) if ndim else abs(ptype)
    return p + 2 + ndim + size <= end


def _parse_parameters(raw: bytes, start: int, end: int, processor: int, notes: list[str]):
    """Walk the group / parameter chain between byte ``start`` (after the 4-byte block header) and ``end``."""
    i16 = "<h" if processor != MIPS else ">h"
    group_names: dict[int, str] = {}
    pending: list[tuple[int, Parameter]] = []
    pos = start
    while pos + 2 <= end:
        n_chars = abs(struct.unpack("b", raw[pos:pos + 1])[0])
        gid = struct.unpack("b", raw[pos + 1:pos + 2])[0]
        if n_chars == 0 or gid == 0:
            break
        p = pos + 2
        if p + n_chars + 2 > end:
            notes.append("parameter section ends inside an entry; the rest ignored")
            break
        item = raw[p:p + n_chars].decode("latin-1").strip().upper()
        p += n_chars
        offset_pos = p
        offset = struct.unpack(i16, raw[p:p + 2])[0]
        p += 2
        try:
            if gid < 0:
                dlen = raw[p]
                desc = raw[p + 1:p + 1 + dlen].decode("latin-1").strip()
                group_names.setdefault(-gid, item)
                computed = p + 1 + dlen
            else:
                ptype = struct.unpack("b", raw[p:p + 1])[0]
                ndim = raw[p + 1]
                dims = tuple(raw[p + 2:p + 2 + ndim])
                p += 2 + ndim
                size = abs(ptype) * int(np.prod(dims)) if ndim else abs(ptype)
                if ptype not in (-1, 1, 2, 4) or p + size > end:
                    raise IndexError
                data, data_at = raw[p:p + size], p
                p += size
                dlen = raw[p] if p < end else 0
                desc = raw[p + 1:p + 1 + dlen].decode("latin-1").strip()
                computed = p + 1 + dlen
                pending.append((gid, Parameter("", item, ptype, dims, data, desc, data_at)))
        except (IndexError, struct.error):
            notes.append(f"parameter {item!r} is malformed; it and the rest of the parameter section were ignored")
            break
        if offset == 0:
            break
        # The offset is a signed 16-bit count from the offset field; large entries wrap, so read it unsigned when
        # negative, and fall back on the size we parsed when the stored offset points nowhere sensible.
        declared = offset_pos + (offset & 0xFFFF)
        if plausible_entry(raw, declared, end):
            pos = declared
        elif plausible_entry(raw, computed, end):
            pos = computed
        else:
            notes.append(f"the parameter chain breaks after {item!r}; later parameters (if any) were ignored")
            break
    params: dict[tuple[str, str], Parameter] = {}
    for gid, prm in pending:
        prm.group = group_names.get(gid, f"GROUP{gid}")
        key = (prm.group, prm.name)
        if key in params:
            notes.append(f"parameter {prm.group}:{prm.name} appears twice; the first one is used")
            continue
        params[key] = prm
    groups = [group_names[g] for g in sorted(group_names)]
    return params, groups


def parse(raw: bytes, name: str) -> C3DFile:
    """Parse the header and parameter section of C3D ``raw`` bytes and locate the data section.

    Raises FormatError (naming ``name``) when the content is not a C3D or is truncated.
    """
    if len(raw) < BLOCK:
        raise FormatError(f"{name}: not a C3D file (only {len(raw)} bytes; a C3D has at least a 512-byte header)")
    if raw[1] != 0x50:
        raise FormatError(f"{name}: not a C3D file (byte 2 is {raw[1]:#04x}, expected the C3D key 0x50)")
    param_block = raw[0] or 2
    pstart = (param_block - 1) * BLOCK
    if pstart + 4 > len(raw):
        raise FormatError(f"{name}: truncated C3D: the parameter section (block {param_block}) is missing")
    processor = raw[pstart + 3]
    notes: list[str] = []
    if processor not in PROCESSOR_NAMES:
        notes.append(f"unknown processor type {processor}; read as Intel")
        processor = INTEL
    u16 = ">H" if processor == MIPS else "<H"
    hdr = [struct.unpack(u16, raw[2 * k:2 * k + 2])[0] for k in range(12)]
    header_points, header_analog, header_first, header_last = hdr[1], hdr[2], hdr[3], hdr[4]
    header_scale = float(decode_floats(raw[12:16], processor)[0])
    header_data_block = hdr[8]
    header_analog_per_frame = hdr[9]
    header_rate = float(decode_floats(raw[HEADER_RATE_AT:HEADER_RATE_AT + 4], processor)[0])

    # The parameter section may claim fewer blocks than it uses; read up to the data section (or the file's end).
    n_pblocks = raw[pstart + 2]
    pend = min(len(raw), max(pstart + n_pblocks * BLOCK, (header_data_block - 1) * BLOCK if header_data_block
                             > param_block else 0))
    if pend <= pstart + 4:
        pend = len(raw)
    params, groups = _parse_parameters(raw, pstart + 4, pend, processor, notes)
    f = C3DFile(raw, processor, params, groups, 0, 0, 1, 0.0, 0.0, False, 0, 0, notes)

    n_points = f.number("POINT", "USED", None)
    n_points = header_points if n_points is None else int(n_points) & 0xFFFF
    if n_points != header_points:
        notes.append(f"header says {header_points} points, POINT:USED {n_points}; POINT:USED is used")

    scale = f.number("POINT", "SCALE", None)
    if scale is None or not np.isfinite(scale) or scale == 0:
        scale = header_scale
    elif not np.isclose(scale, header_scale, rtol=1e-4):
        notes.append(f"header scale {header_scale:g} differs from POINT:SCALE {scale:g}; POINT:SCALE is used")
    if not np.isfinite(scale) or scale == 0:
        scale = -1.0
    rate = f.number("POINT", "RATE", None)
    if rate is None or not np.isfinite(rate) or rate <= 0:
        rate = header_rate
    if not np.isfinite(rate) or rate <= 0:
        raise FormatError(f"{name}: corrupt C3D: no valid frame rate (header {header_rate:g})")

    data_block = f.number("POINT", "DATA_START", None)
    data_block = header_data_block if not data_block else int(data_block) & 0xFFFF
    if data_block <= param_block:
        data_block = header_data_block
    data_offset = (data_block - 1) * BLOCK
    if data_block < 1 or data_offset > len(raw):
        raise FormatError(f"{name}: truncated C3D: the data section (block {data_block}) is beyond the file's end")

    first = header_first
    n_frames = header_last - header_first + 1 if header_last >= header_first else 0
    start_field = f.param("TRIAL", "ACTUAL_START_FIELD")
    end_field = f.param("TRIAL", "ACTUAL_END_FIELD")
    if start_field is not None and end_field is not None and start_field.type == 2 and end_field.type == 2:
        s = np.frombuffer(start_field.raw, dtype=uint16_dtype(processor)).astype(np.int64)
        e = np.frombuffer(end_field.raw, dtype=uint16_dtype(processor)).astype(np.int64)
        if s.size >= 2 and e.size >= 2:
            s0, e0 = int(s[0] + (s[1] << 16)), int(e[0] + (e[1] << 16))
            if e0 >= s0 and e0 - s0 + 1 > n_frames:
                first, n_frames = s0, e0 - s0 + 1  # the header's 16-bit frame numbers overflowed
    if n_frames == 0:
        frames = f.number("POINT", "FRAMES", 0)
        n_frames = int(frames) & 0xFFFF if frames else 0

    # Analog words per frame: the header's count, else ANALOG:USED x samples per frame.  Use the first candidate
    # whose frames fit the data section (files are padded to whole blocks).
    candidates = [header_analog]
    analog_used = f.number("ANALOG", "USED", None)
    analog_rate = f.number("ANALOG", "RATE", None)
    if analog_used is not None:
        used = int(analog_used) & 0xFFFF
        per = header_analog_per_frame
        if analog_rate and analog_rate > 0:
            per = int(round(analog_rate / rate))
        candidates += [used * per, used * header_analog_per_frame]
    available = len(raw) - data_offset
    storages = [scale < 0, scale >= 0]
    chosen = None
    for is_float in storages:
        word = 4 if is_float else 2
        for analog_words in candidates:
            need = n_frames * (4 * n_points + analog_words) * word
            if need <= available and available - need < max(BLOCK, (4 * n_points + analog_words) * word) + BLOCK:
                chosen = (is_float, analog_words)
                break
        if chosen:
            break
    if chosen is None:
        word = 4 if scale < 0 else 2
        need = n_frames * (4 * n_points + header_analog) * word
        if need > available:
            frame_bytes = (4 * n_points + header_analog) * word
            held = available // frame_bytes if frame_bytes else 0
            raise FormatError(f"{name}: truncated C3D: the data section holds {held} of {n_frames} frames")
        chosen = (scale < 0, header_analog)
        frame_bytes = (4 * n_points + header_analog) * (4 if scale < 0 else 2)
        if frame_bytes and (n_frames == 0 or header_last == 0xFFFF):
            # The 16-bit header frame count was capped (long captures) and nothing else gave the real count.
            # The section is padded with zeros to a whole block; a frame of real data rarely ends in a whole
            # frame of zero bytes, so the data ends at the frame holding the last non-zero byte.
            tail = raw[data_offset:]
            used = len(tail.rstrip(b"\x00"))
            n_frames = -(-used // frame_bytes)
            notes.append(f"frame count taken from the size of the data section ({n_frames} frames)")
        else:
            notes.append(f"the data section is longer than {n_frames} frames need; the extra bytes are kept as "
                         "they are")
    if chosen[0] != (scale < 0):
        notes.append("the storage (integer / float) disagrees with the sign of the scale; the data size decided")
    if chosen[1] != header_analog:
        notes.append(f"header says {header_analog} analog values per frame, the data section holds {chosen[1]}")
    f.n_points, f.n_frames, f.first_frame, f.rate = n_points, n_frames, first, float(rate)
    f.scale, f.is_float, f.data_offset, f.analog_words = float(scale), chosen[0], data_offset, chosen[1]
    return f
