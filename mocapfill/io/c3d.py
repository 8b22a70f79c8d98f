"""C3D read and write, keeping everything a fill did not touch byte for byte.

Reading: markers are the points of the data section minus the model outputs listed in POINT:ANGLES / FORCES /
MOMENTS / POWERS / SCALARS / REACTIONS.  A sample is missing when its residual word is negative, a coordinate is not
finite, or the point is exactly (0, 0, 0).  Labels come from POINT:LABELS, LABELS2, ... (stripped); duplicates are
renamed ``LABEL_2``, ``LABEL_3`` ... and listed in ``MarkerData.notes``.

Writing a C3D that was read by this module copies the original bytes (header, every parameter, analog words,
events, model outputs, the storage format and scale, the processor type) and re-encodes only the marker samples whose
position changed: changed observed samples keep their residual word, newly filled samples (and samples rejected as
outliers and filled again, :func:`mark_refilled`) get residual 0 and camera mask 0, samples that became missing get
(0, 0, 0) and residual -1.  A rate that replaced the file's (``--override-rate``) is written into the header,
POINT:RATE and (in the same ratio) ANALOG:RATE.  Data without a C3D origin (CSV, TRC) is written
as a fresh float C3D (Intel) with POINT, ANALOG (no channels), TRIAL and MANUFACTURER groups.
"""

from __future__ import annotations

import dataclasses
import struct
import warnings
from dataclasses import dataclass

import numpy as np

from ..errors import DataWarning, FormatError
from ..markers import MarkerData
from . import c3dfile
from .c3dfile import BLOCK, INTEL, C3DFile
from .labels import make_unique, normalise_units, point_kinds, rename_notes

MODEL_OUTPUT_PARAMS = ("ANGLES", "FORCES", "MOMENTS", "POWERS", "SCALARS", "REACTIONS")

__all__ = ["C3DExtra", "read_c3d", "c3d_bytes", "c3d_storage", "mark_refilled", "c3d_kinds", "MODEL_OUTPUT_PARAMS",
           "MODEL_POINT_PARAMS"]


@dataclass
class C3DExtra:
    """What a C3D rewrite needs (kept in ``MarkerData.extra``).

    file : the parsed original (its ``raw`` bytes, parameters and data layout).
    marker_points : int array (n_markers,), the C3D point index of each marker column of ``positions``.
    model_outputs : labels of the points left out as model outputs (angles, forces, ...).
    """

    file: C3DFile
    marker_points: np.ndarray
    model_outputs: list[str]
    #: (n_frames, n_markers) bool or None: samples observed in the original that the caller dropped and filled
    #: again (rejected outliers); the rewrite marks them filled (residual 0), not observed.  See :func:`mark_refilled`.
    refilled: np.ndarray | None = None

    @property
    def processor(self) -> str:
        return c3dfile.PROCESSOR_NAMES.get(self.file.processor, "?")

    @property
    def storage(self) -> str:
        return "float" if self.file.is_float else "integer"

    @property
    def n_analog_channels(self) -> int:
        used = self.file.number("ANALOG", "USED", 0)
        return int(used) & 0xFFFF if used else 0


def _all_labels(f: C3DFile) -> list[str]:
    labels: list[str] = list(f.strings("POINT", "LABELS"))
    k = 2
    while f.param("POINT", f"LABELS{k}") is not None:
        labels += f.strings("POINT", f"LABELS{k}")
        k += 1
    return labels


def decode_points(f: C3DFile, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Positions (n_frames, k, 3) float64 with NaN where missing, and the residual words (n_frames, k) float64.

    ``points`` is the raw point block of the selected points, shape (n_frames, k, 4).
    """
    words = points.astype(np.float64)
    xyz = words[:, :, :3]
    if not f.is_float:
        xyz = xyz * abs(f.scale)
    residual = words[:, :, 3]
    with np.errstate(invalid="ignore"):
        missing = (residual < 0) | ~np.isfinite(xyz).all(axis=2) | (xyz == 0).all(axis=2)
    xyz = np.where(missing[:, :, None], np.nan, xyz)
    return xyz, residual


def read_c3d(raw: bytes, name: str) -> MarkerData:
    """Parse C3D bytes into MarkerData (positions (n_frames, n_markers, 3), NaN = missing)."""
    f = c3dfile.parse(raw, name)
    notes = list(f.notes)
    labels = _all_labels(f)
    if len(labels) < f.n_points:
        notes.append(f"POINT:LABELS names {len(labels)} of {f.n_points} points; the rest are called P###")
    labels = labels[: f.n_points] + [""] * (f.n_points - len(labels))
    labels = [lab if lab else f"P{i + 1:03d}" for i, lab in enumerate(labels)]

    model_set: set[str] = set()
    for pname in MODEL_OUTPUT_PARAMS:
        model_set.update(s for s in f.strings("POINT", pname) if s)
    marker_points = np.array([i for i, lab in enumerate(labels) if lab not in model_set], dtype=np.int64)
    model_outputs = [labels[i] for i in range(f.n_points) if labels[i] in model_set]
    if model_outputs:
        notes.append(f"{len(model_outputs)} model outputs (angles, forces, ...) kept in the file but not filled")

    marker_labels, renamed = make_unique([labels[i] for i in marker_points])
    notes.extend(rename_notes(renamed))
    if renamed:
        warnings.warn(f"{name}: {len(renamed)} duplicate marker label(s) renamed (e.g. {renamed[0][1]!r})",
                      DataWarning, stacklevel=3)

    block = f.point_block()
    positions, residual = decode_points(f, block[:, marker_points, :])
    kinds, kind_notes = c3d_kinds(f, marker_labels, [labels[i] for i in marker_points], positions, residual)
    notes.extend(kind_notes)
    units_raw = " ".join(f.strings("POINT", "UNITS"))
    units, unit_note = normalise_units(units_raw, positions)
    if unit_note:
        notes.append(unit_note)
    for note in f.notes:
        warnings.warn(f"{name}: {note}", DataWarning, stacklevel=3)
    extra = C3DExtra(f, marker_points, model_outputs)
    return MarkerData(positions, marker_labels, f.rate, units, f.first_frame, "c3d", extra, name, notes, kinds)


#: Groups of ``POINT:TYPE_GROUPS`` (and parameters of the POINT group) that list points the modelling software
#: computed but that are positions, kept among the points as model points (Nexus: ``MODELED_MARKERS``).
MODEL_POINT_PARAMS = ("MODELED_MARKERS", "MODELLED_MARKERS", "VIRTUAL_MARKERS", "VIRTUAL_POINTS")
#: A C3D records which cameras saw each sample (the residual word: camera bits and residual, > 0 when seen).  When
#: at least this fraction of its points were seen by cameras, a point whose every sample has residual word exactly 0
#: was seen by none: the capture software computed it (CMU's virtual skeleton points).
CAMERA_RECORDED_FRACTION = 0.05


def c3d_kinds(f: C3DFile, labels: list[str], raw_labels: list[str], positions: np.ndarray, residual: np.ndarray
              ) -> tuple[list[str], list[str]]:
    """The kind of each point column, as the C3D says, and a note per rule that found model points.

    ``labels`` are the unique labels, ``raw_labels`` the file's; ``positions`` (n_frames, k, 3) NaN = missing,
    ``residual`` (n_frames, k) the residual words.  In order: a name in a model-point parameter
    (:data:`MODEL_POINT_PARAMS`, or a ``POINT:TYPE_GROUPS`` group other than angles, forces, moments, powers);
    the names (:func:`mocapfill.io.labels.point_kinds`); a point seen by no camera in a file that records them
    (:data:`CAMERA_RECORDED_FRACTION`).
    """
    notes: list[str] = []
    kinds = point_kinds(labels)
    groups = set(MODEL_POINT_PARAMS)
    type_groups = f.strings("POINT", "TYPE_GROUPS")
    groups.update(g.upper() for g in type_groups[0::2] if g and g.upper() not in MODEL_OUTPUT_PARAMS)
    listed: set[str] = set()
    for group in sorted(groups):
        listed.update(s for s in f.strings("POINT", group) if s)
    by_param = [k for k, lab in enumerate(raw_labels) if lab in listed and kinds[k] != "model"]
    for k in by_param:
        kinds[k] = "model"
    observed = ~np.isnan(positions).any(axis=2)
    if positions.shape[0] and positions.shape[1]:
        with np.errstate(invalid="ignore"):
            seen = (residual > 0) & observed
        any_seen = seen.any(axis=0)
        if any_seen.mean() >= CAMERA_RECORDED_FRACTION:
            unseen = [k for k in range(len(kinds)) if kinds[k] == "marker" and observed[:, k].any()
                      and not any_seen[k] and np.all(residual[observed[:, k], k] == 0)]
            for k in unseen:
                kinds[k] = "model"
            if unseen:
                notes.append(f"{len(unseen)} point(s) seen by no camera (residual 0 in every frame, while the "
                             f"file's markers carry camera residuals) are model points, e.g. {labels[unseen[0]]!r}")
    return kinds, notes


# --- writing -------------------------------------------------------------------------------------------------------

def mark_refilled(data: MarkerData, refilled: np.ndarray) -> MarkerData:
    """``data`` whose C3D rewrite marks the samples of ``refilled`` (n_frames, n_markers) bool as filled.

    For samples the file had but that were dropped (rejected outliers) and filled again: their new position is
    written with residual 0 / camera mask 0 like any filled sample, not with the original's residual.  Data that
    did not come from a C3D is returned as it is.
    """
    if not isinstance(data.extra, C3DExtra):
        return data
    return dataclasses.replace(data, extra=dataclasses.replace(data.extra, refilled=np.asarray(refilled, dtype=bool)))


def c3d_bytes(data: MarkerData, name: str = "<c3d>") -> bytes:
    """The bytes of a C3D holding ``data`` (a faithful rewrite when ``data.extra`` comes from a C3D read)."""
    extra = data.extra
    if isinstance(extra, C3DExtra):
        if (data.n_frames == extra.file.n_frames and data.n_markers == len(extra.marker_points)):
            return _rewrite(data, extra, name)
        warnings.warn(f"{name}: the markers or frames differ from the original C3D; writing a new C3D without the "
                      "original's analog data and parameters", DataWarning, stacklevel=3)
    return _fresh(data, name)


def c3d_storage(data: MarkerData, samples: np.ndarray) -> str | None:
    """None when the C3D :func:`c3d_bytes` writes holds the ``samples`` ((n_frames, n_markers) bool) of ``data``
    exactly: a rewrite keeps the words of every sample equal to the original's, a float C3D holds float32 values;
    else how it stores them."""
    extra = data.extra
    if isinstance(extra, C3DExtra) and (data.n_frames == extra.file.n_frames
                                        and data.n_markers == len(extra.marker_points)):
        if data.n_frames and data.n_markers:
            original, _ = decode_points(extra.file, extra.file.point_block()[:, extra.marker_points, :])
            samples = samples & ~(data.positions == original).all(axis=2)  # written back word for word
        if not extra.file.is_float:
            return (f"stored as integers of {abs(extra.file.scale):g} {data.units} by the C3D" if samples.any()
                    else None)
    values = data.positions[samples]
    return None if np.array_equal(values.astype(np.float32).astype(np.float64), values) else \
        "stored as float32 by C3D"


def _word_bytes(values: np.ndarray, f: C3DFile) -> np.ndarray:
    """Encode ``values`` (m, k) float64 as C3D words in ``f``'s storage; returns uint8 (m, k * word_size)."""
    m, k = values.shape
    if f.is_float:
        raw = c3dfile.encode_floats(values.ravel(), f.processor)
    else:
        raw = values.astype(c3dfile.int16_dtype(f.processor)).tobytes()
    return np.frombuffer(raw, dtype=np.uint8).reshape(m, k * f.word_size)


def _set_number(buf: bytearray, f: C3DFile, group: str, param: str, value: float) -> bool:
    """Write ``value`` over the first value of a numeric parameter of ``f`` in ``buf`` (nothing when absent); False
    when it is stored as an integer that cannot hold ``value``."""
    prm = f.param(group, param)
    if prm is None or prm.offset < 0 or prm.type not in (2, 4) or len(prm.raw) < abs(prm.type):
        return True
    if prm.type == 4:
        payload = c3dfile.encode_floats(np.array([value]), f.processor)
    elif float(value).is_integer() and -32768 <= value <= 32767:
        payload = np.array([int(value)], dtype=c3dfile.int16_dtype(f.processor)).tobytes()
    else:
        return False
    buf[prm.offset:prm.offset + len(payload)] = payload
    return True


def _set_rate(buf: bytearray, f: C3DFile, rate: float, name: str) -> None:
    """Write the point rate ``rate`` (a caller's override) into the header and POINT:RATE of ``buf``.

    The data section interleaves a fixed number of analog samples with each point frame (the header's samples per
    frame), so ANALOG:RATE, which is in Hz, is scaled with the point rate to keep that ratio.
    """
    if not abs(rate) <= 3.4e38:
        raise FormatError(f"{name}: frame rate {rate:g} Hz cannot be stored in a C3D (a 32-bit float)")
    at = c3dfile.HEADER_RATE_AT
    buf[at:at + 4] = c3dfile.encode_floats(np.array([rate]), f.processor)
    if not _set_number(buf, f, "POINT", "RATE", rate):
        warnings.warn(f"{name}: POINT:RATE is stored as an integer and cannot hold {rate:g} Hz; only the header "
                      "says it", DataWarning, stacklevel=4)
    analog = f.number("ANALOG", "RATE", None)
    if analog and np.isfinite(analog) and analog > 0 and not _set_number(buf, f, "ANALOG", "RATE",
                                                                          analog * rate / f.rate):
        warnings.warn(f"{name}: ANALOG:RATE is stored as an integer and cannot hold {analog * rate / f.rate:g} Hz; "
                      "left as it was", DataWarning, stacklevel=4)


def _rewrite(data: MarkerData, extra: C3DExtra, name: str) -> bytes:
    f = extra.file
    buf = bytearray(f.raw)
    with np.errstate(over="ignore"):
        replaced = np.float32(data.rate) != np.float32(f.rate)  # the caller's rate for the file's (--override-rate)
    if replaced:
        _set_rate(buf, f, data.rate, name)
    if f.n_frames == 0 or len(extra.marker_points) == 0:
        return bytes(buf)
    block = f.point_block()[:, extra.marker_points, :]
    original, _ = decode_points(f, block)
    new = data.positions
    both_nan = np.isnan(new) & np.isnan(original)
    same = ((new == original) | both_nan).all(axis=2)
    was_missing = np.isnan(original).any(axis=2)
    now_missing = np.isnan(new).any(axis=2)
    changed = ~same
    refilled = np.zeros_like(changed) if extra.refilled is None else np.asarray(extra.refilled, dtype=bool)
    if not changed.any():
        return bytes(buf)

    ws = f.word_size
    table = np.frombuffer(buf, dtype=np.uint8, count=f.n_frames * f.frame_bytes, offset=f.data_offset)
    table = table.reshape(f.n_frames, f.frame_bytes)

    def put(mask: np.ndarray, word0: int, values: np.ndarray) -> None:
        rows, cols = np.nonzero(mask)
        if rows.size == 0:
            return
        encoded = _word_bytes(values, f)
        start = extra.marker_points[cols] * 4 * ws + word0 * ws
        byte_cols = start[:, None] + np.arange(encoded.shape[1])
        table[rows[:, None], byte_cols] = encoded

    # Coordinates of samples that are (still or newly) present but moved.
    moved = changed & ~now_missing
    xyz = new[moved]
    if not f.is_float:
        counts = np.rint(xyz / abs(f.scale))
        bad = ~((counts >= -32768) & (counts <= 32767)).all(axis=1)
        if bad.any():
            # Integer storage cannot hold these values; the file keeps its storage, so these samples keep what the
            # original had (missing stays missing) and the user is told where, rather than losing the whole write.
            rows, cols = np.argwhere(moved)[bad].T
            markers = sorted({data.labels[k] for k in cols})
            warnings.warn(f"{name}: {int(bad.sum())} sample(s) of {', '.join(markers)} (first at frame "
                          f"{int(rows.min()) + data.first_frame}) lie outside the integer storage range of the "
                          f"original C3D (+-32767 x {abs(f.scale):g} {data.units}) and were not written; write CSV "
                          "or TRC to keep them", DataWarning, stacklevel=3)
            moved[rows, cols] = False
            counts = counts[~bad]
        xyz = counts
    put(moved, 0, xyz)
    # Newly filled (or dropped as an outlier and filled again): residual 0, camera mask 0 (valid, so other software
    # shows them).
    filled = moved & (was_missing | refilled)
    put(filled, 3, np.zeros((int(filled.sum()), 1)))
    # Observed before, missing now (e.g. rejected outliers): (0, 0, 0) and residual -1.
    dropped = changed & now_missing & ~was_missing
    put(dropped, 0, np.tile([0.0, 0.0, 0.0, -1.0], (int(dropped.sum()), 1)))
    return bytes(buf)


def _param_entry(name: str, gid: int, ptype: int, dims: tuple[int, ...], payload: bytes, last: bool) -> bytes:
    name_b = name.encode("ascii")
    body = struct.pack("bB", ptype, len(dims)) + bytes(dims) + payload + b"\x00"
    offset = 0 if last else 2 + len(body)
    return struct.pack("bb", len(name_b), gid) + name_b + struct.pack("<h", offset) + body


def _group_entry(name: str, gid: int) -> bytes:
    name_b = name.encode("ascii")
    return struct.pack("bb", len(name_b), -gid) + name_b + struct.pack("<h", 3) + b"\x00"


def _char_param(strings: list[str]) -> tuple[tuple[int, ...], bytes]:
    width = max([len(s) for s in strings] + [1])
    payload = b"".join(s.encode("latin-1", "replace").ljust(width) for s in strings)
    return (width, len(strings)), payload


def _fresh(data: MarkerData, name: str) -> bytes:
    """A new Intel float C3D with the markers of ``data`` and no analog channels."""
    n_frames, n_markers = data.n_frames, data.n_markers
    first = max(int(data.first_frame), 1)
    last = first + n_frames - 1
    if abs(data.rate) > 3.4e38:  # also inf; 0 and NaN pack (and read back as "no rate")
        raise FormatError(f"{name}: frame rate {data.rate:g} Hz cannot be stored in a C3D (a 32-bit float)")
    if n_markers > 65535:
        raise FormatError(f"{name}: {n_markers} markers are more than the 65535 a C3D can hold")
    stored = [label.encode("latin-1", "replace").decode("latin-1") for label in data.labels]  # one byte a character
    for label, kept in zip(data.labels, stored):
        if len(kept) > 255:
            raise FormatError(f"{name}: label {label[:20]!r}... is longer than the 255 characters C3D allows")
    changed = [(a, b) for a, b in zip(data.labels, stored) if a != b]
    if changed:  # C3D holds one byte per character (Latin-1): say so now, not when it is read back
        clash = len(set(stored)) < len(set(data.labels))
        warnings.warn(f"{name}: {len(changed)} label(s) hold characters C3D cannot store, written with '?' (e.g. "
                      f"{changed[0][0]!r} as {changed[0][1]!r})" + ("; some now read the same" if clash else ""),
                      DataWarning, stacklevel=3)
    from .. import __version__

    def params(data_block: int) -> bytes:
        entries: list[tuple] = []
        i16 = lambda *v: struct.pack(f"<{len(v)}h", *[((x + 32768) % 65536) - 32768 for x in v])  # noqa: E731
        f32 = lambda *v: struct.pack(f"<{len(v)}f", *v)  # noqa: E731
        entries.append(("USED", 1, 2, (), i16(n_markers)))
        entries.append(("SCALE", 1, 4, (), f32(-1.0)))
        entries.append(("RATE", 1, 4, (), f32(data.rate)))
        entries.append(("DATA_START", 1, 2, (), i16(data_block)))
        entries.append(("FRAMES", 1, 2, (), i16(min(n_frames, 65535))))
        for k in range(0, max(n_markers, 1), 255):
            chunk = data.labels[k:k + 255]
            suffix = "" if k == 0 else str(k // 255 + 1)
            dims, payload = _char_param(chunk)
            entries.append((f"LABELS{suffix}", 1, -1, dims, payload))
            entries.append((f"DESCRIPTIONS{suffix}", 1, -1, (1, len(chunk)), b" " * len(chunk)))
        dims, payload = _char_param([data.units])
        entries.append(("UNITS", 1, -1, (dims[0],), payload))
        entries.append(("USED", 2, 2, (), i16(0)))
        entries.append(("RATE", 2, 4, (), f32(data.rate)))
        entries.append(("GEN_SCALE", 2, 4, (), f32(1.0)))
        entries.append(("ACTUAL_START_FIELD", 3, 2, (2,), i16(first & 0xFFFF, first >> 16)))
        entries.append(("ACTUAL_END_FIELD", 3, 2, (2,), i16(last & 0xFFFF, last >> 16)))
        dims, payload = _char_param([f"mocapfill {__version__}"])
        entries.append(("SOFTWARE", 4, -1, (dims[0],), payload))
        out = b"".join(_group_entry(g, i) for i, g in enumerate(["POINT", "ANALOG", "TRIAL", "MANUFACTURER"], 1))
        out += b"".join(_param_entry(n, g, t, d, p, k == len(entries) - 1) for k, (n, g, t, d, p) in
                        enumerate(entries))
        return out

    body = params(2)
    n_blocks = (4 + len(body) + BLOCK - 1) // BLOCK
    data_block = 2 + n_blocks
    body = params(data_block)
    section = (bytes([1, 0x50, n_blocks, INTEL]) + body).ljust(n_blocks * BLOCK, b"\x00")

    header = bytearray(BLOCK)
    header[0], header[1] = 2, 0x50
    struct.pack_into("<HHHH", header, 2, n_markers, 0, min(first, 65535), min(last, 65535))
    struct.pack_into("<Hf", header, 10, 0, -1.0)
    # One analog sample per frame: ANALOG:RATE equals POINT:RATE (readers check the ratio even with no channel).
    struct.pack_into("<HHf", header, 16, data_block, 1, data.rate)

    words = np.zeros((n_frames, n_markers, 4), dtype="<f4")
    missing = data.missing
    words[:, :, :3] = np.where(missing[:, :, None], 0.0, data.positions)
    words[:, :, 3] = np.where(missing, -1.0, 0.0)
    payload = words.tobytes()
    payload += b"\x00" * (-len(payload) % BLOCK)
    return bytes(header) + section + payload

