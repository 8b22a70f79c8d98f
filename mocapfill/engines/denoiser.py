"""A learned denoiser for one marker layout, after Holden (2018), "Robust solving of optical motion capture data by
denoising": the model, its file, its body frame, its corruption, and inference, in pure NumPy.

Holden trains a network on a database of clean captures of one marker layout, fed with the same captures corrupted
the way real ones are (markers occluded, displaced, swapped; noise), to output the clean result; it then solves new
captures of that layout frame by frame, robust to outliers without a separate detector.  Here the network's inputs
and outputs are both marker positions (this product repairs markers; Holden's skeleton output is out of scope):

- **body frame** (:func:`body_frames`): each frame is expressed in a frame fitted (weighted Kabsch, Besl & McKay) to
  the torso markers the layout's training data elect (:func:`mocapfill.engines.body_frame.frame_markers`: pelvis and
  torso), onto their mean shape; a marker whose fit residual is far beyond the rest is dropped and the fit redone,
  so one displaced torso marker does not turn the frame.  Frames with fewer than three torso markers use every
  observed marker against the layout's mean pose.
- **input**: the local positions normalised per coordinate (training mean and standard deviation), occluded markers
  set to zero (Holden's convention), plus one 0/1 visibility flag per marker.  **Output**: every marker's normalised
  local position.  The network: a linear layer, ``blocks`` residual blocks (ReLU), a linear layer; LeCun-normal
  initialisation; trained with an L1 loss and AMSGrad (:mod:`.denoiser_training`, JAX).
- **corruption** (:func:`corrupt`), Holden's Corrupt with swaps and noise added: per frame an occlusion probability
  ``min(|N(0, sigma_o)|, 2 sigma_o)`` and a shift probability ``min(|N(0, sigma_s)|, 2 sigma_s)``; occluded markers
  are removed, shifted markers move by U(-beta, beta) per axis (beta = 50 cm); with a small probability a marker
  trades places with one of its nearest neighbours (a label swap); every observed marker gets Gaussian noise.
- **inference** (:func:`predict_frames`): one pass per frame, then back to the laboratory frame.  The fill
  (:mod:`mocapfill.methods.learned`) smooths the per-frame outputs over time (Holden's Savitzky-Golay filter) and
  shifts them to meet the observations at each gap's ends; the guard (:mod:`mocapfill.guards.denoise`) judges an
  observed sample displaced when it is far from the network's output.

The model file (``.model``) is a NumPy ``.npz``: the layers' arrays plus a JSON record of the layout (labels), the
units, the body frame, the normalisation and the training settings.  Loading needs only NumPy.
"""

from __future__ import annotations

import json
import os
import warnings
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from ..errors import MocapfillError
from .body_frame import nearest_rotation

#: What the model file says it is; a file of another format is refused with a one-line error.
MODEL_FORMAT = "mocapfill-denoiser/1"
#: Holden's corruption: occlusion and shift probability scales and the shift range (mm); swaps and noise are ours.
SIGMA_OCCLUSION = 0.1
SIGMA_SHIFT = 0.1
SHIFT_MM = 500.0
SWAP_PROBABILITY = 0.005
NOISE_MM = 1.0
#: Smallest normalisation scale of a coordinate, in mm (a marker that barely moves in the body frame).
MIN_SCALE_MM = 10.0
#: Body frame: a torso marker whose fit residual exceeds this (mm) and 3x the median is dropped and the fit redone.
FRAME_OUTLIER_MM = 80.0


class ModelError(MocapfillError):
    """A model file cannot be read, or does not fit the capture (another layout, too few shared markers)."""


@dataclass
class DenoiserModel:
    """A trained denoiser for one marker layout.

    Attributes
    ----------
    labels : list of str (M,)
        The layout's marker labels, without subject prefix.
    units : str
        Units of every length below ("mm", "cm" or "m").
    frame_markers : ndarray of int (F,)
        Indices of the torso markers the body frame is fitted to.
    template : ndarray (F, 3)
        Their mean shape in the body frame.
    mean, scale : ndarray (3 M,)
        Normalisation of the local positions (flattened marker-major).
    layers : list of (W (n_in, n_out), b (n_out,))
        Input layer, residual blocks, output layer.
    residual : ndarray (M,)
        Per-marker RMS 3-D error of the output on held-out clean frames with Holden's occlusions (model units).
    settings : dict
        Training settings and facts (steps, batch, hidden, blocks, corruption, frames, clips, seconds, losses).
    """

    labels: list[str]
    units: str
    frame_markers: np.ndarray
    template: np.ndarray
    mean: np.ndarray
    scale: np.ndarray
    layers: list[tuple[np.ndarray, np.ndarray]]
    residual: np.ndarray
    settings: dict[str, Any] = field(default_factory=dict)

    @property
    def n_markers(self) -> int:
        return len(self.labels)

    @property
    def mean_pose(self) -> np.ndarray:
        """(M, 3) mean local position of each marker."""
        return self.mean.reshape(-1, 3)

    def n_parameters(self) -> int:
        return int(sum(w.size + b.size for w, b in self.layers))


def save_model(model: DenoiserModel, path: str | os.PathLike) -> None:
    """Write ``model`` to ``path`` (a NumPy ``.npz`` whatever the extension), atomically."""
    from ..io.atomic import atomic_write

    meta = {"format": MODEL_FORMAT, "labels": list(model.labels), "units": model.units,
            "n_layers": len(model.layers), "settings": model.settings}
    arrays = {"frame_markers": np.asarray(model.frame_markers, dtype=np.int64), "template": model.template,
              "mean": model.mean, "scale": model.scale, "residual": model.residual,
              "meta": np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8)}
    for k, (w, b) in enumerate(model.layers):
        arrays[f"w{k}"] = np.asarray(w, dtype=np.float32)
        arrays[f"b{k}"] = np.asarray(b, dtype=np.float32)
    with atomic_write(os.fspath(path), "wb", encoding=None) as handle:
        np.savez_compressed(handle, **arrays)


def load_model(path: str | os.PathLike) -> DenoiserModel:
    """Read a model file written by :func:`save_model` (``mocapfill train``); one-line :class:`ModelError` else."""
    name = os.fspath(path)
    try:
        with np.load(name, allow_pickle=False) as z:
            meta = json.loads(bytes(z["meta"]).decode())
            if meta.get("format") != MODEL_FORMAT:
                raise ModelError(f"{name}: not a mocapfill denoiser model (format {meta.get('format')!r})")
            layers = [(z[f"w{k}"].astype(np.float64), z[f"b{k}"].astype(np.float64))
                      for k in range(int(meta["n_layers"]))]
            model = DenoiserModel(list(meta["labels"]), str(meta["units"]), z["frame_markers"].astype(int),
                                  z["template"], z["mean"], z["scale"], layers, z["residual"],
                                  dict(meta.get("settings", {})))
        _check_shapes(model)
        return model
    except ModelError:
        raise
    except FileNotFoundError:
        raise ModelError(f"{name}: no such model file") from None
    except MemoryError:
        raise
    except Exception as exc:  # noqa: BLE001 - a damaged file fails anywhere in zipfile, zlib or NumPy's header parser
        problem = "the file is empty" if isinstance(exc, EOFError) else f"{type(exc).__name__}: {exc}"
        raise ModelError(f"{name}: not a readable mocapfill model ({' '.join(problem.split())[:120]})") from None


def _check_shapes(model: DenoiserModel) -> None:
    """Raise ValueError unless the arrays of ``model`` fit its layout and chain into one network (a damaged file can
    unpack into arrays that would fail later, in the middle of a fill)."""
    m = model.n_markers
    if m == 0 or not model.layers:
        raise ValueError("no markers or no layers")
    expected = {"mean": (3 * m,), "scale": (3 * m,), "residual": (m,), "template": (len(model.frame_markers), 3)}
    for key, shape in expected.items():
        if np.shape(getattr(model, key)) != shape:
            raise ValueError(f"{key} has shape {np.shape(getattr(model, key))}, expected {shape}")
    if model.frame_markers.ndim != 1 or ((model.frame_markers < 0) | (model.frame_markers >= m)).any():
        raise ValueError("frame marker indices outside the layout")
    width = 4 * m  # each layer's input is the previous one's output; the last gives every marker's 3 coordinates
    for k, (w, b) in enumerate(model.layers):
        if w.ndim != 2 or w.shape[0] != width or b.shape != (w.shape[1],):
            raise ValueError(f"layer {k} has shapes {w.shape} and {b.shape}, expected ({width}, n) and (n,)")
        width = w.shape[1]
    if width != 3 * m:
        raise ValueError(f"the network gives {width} outputs, expected {3 * m}")


def untrained_model(n_markers: int, units: str = "mm", *, hidden: int = 16, blocks: int = 1, seed: int = 0,
                    labels: Sequence[str] | None = None) -> DenoiserModel:
    """A model with random weights for ``n_markers`` markers (tests and examples: the shapes of a real one)."""
    rng = np.random.default_rng(seed)
    sizes = [(4 * n_markers, hidden)] + [(hidden, hidden)] * blocks + [(hidden, 3 * n_markers)]
    layers = [(rng.normal(0.0, 0.1 / np.sqrt(a), size=(a, b)), np.zeros(b)) for a, b in sizes]
    fm = np.arange(min(4, n_markers))
    mean = rng.normal(0.0, 200.0, size=3 * n_markers)
    return DenoiserModel(list(labels) if labels is not None else [f"M{k}" for k in range(n_markers)], units, fm,
                         mean.reshape(-1, 3)[fm], mean, np.full(3 * n_markers, 100.0), layers,
                         np.full(n_markers, 20.0), {"untrained": True})


# --------------------------------------------------------------------------------------------------- body frame

def kabsch(points: np.ndarray, template: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per frame the rotation R (n, 3, 3) and centre c (n, 3) with ``local = (x - c) @ R`` closest to ``template``.

    points (n, F, 3) (NaN = missing), template (F, 3), weights (n, F) (0 where missing).  Frames with fewer than
    three weighted points get the identity and their weighted centroid (or 0).
    """
    w = np.where(np.isnan(points).any(axis=2), 0.0, weights)
    x = np.nan_to_num(points)
    wsum = w.sum(axis=1, keepdims=True)
    safe = np.maximum(wsum, 1e-12)
    cx = (w[..., None] * x).sum(axis=1) / safe  # (n, 3)
    ct = (w @ template) / safe  # (n, 3)
    xc = x - cx[:, None, :]
    tc = template[None] - ct[:, None, :]
    R = nearest_rotation(np.einsum("tf,tfi,tfj->tij", w, xc, tc))  # (n, 3, 3)
    few = (w > 0).sum(axis=1) < 3
    R[few] = np.eye(3)
    # local = (x - c) @ R must put the centroid cx on ct: c = cx - ct @ R^T
    c = cx - np.einsum("tj,tij->ti", ct, R)
    return R, c


def body_frames(positions: np.ndarray, model: DenoiserModel) -> tuple[np.ndarray, np.ndarray]:
    """The body frame of every frame: R (n, 3, 3), c (n, 3), ``local = (x - c) @ R`` (positions (n, M, 3), NaN =
    missing, in the model's marker order and units)."""
    fm = model.frame_markers
    pts = positions[:, fm]
    w = np.ones(pts.shape[:2])
    R, c = kabsch(pts, model.template, w)
    # drop a torso marker far from the fit (a displaced or swapped one) and fit again
    local = np.einsum("tfi,tij->tfj", pts - c[:, None, :], R)
    resid = np.linalg.norm(local - model.template[None], axis=2)  # (n, F), NaN where missing
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a frame without torso markers: its median is NaN, as meant
        med = np.nanmedian(np.where(np.isnan(resid), np.nan, resid), axis=1, keepdims=True) if resid.size else resid
        bad = np.nan_to_num(resid, nan=0.0) > np.maximum(FRAME_OUTLIER_MM * _mm(model), 3 * np.nan_to_num(med))
    if bad.any():
        w = np.where(bad, 0.0, 1.0)
        R, c = kabsch(pts, model.template, w)
    # frames with fewer than three torso markers: every observed marker against the mean pose
    few = ((~np.isnan(pts).any(axis=2)) & (w > 0)).sum(axis=1) < 3
    if few.any():
        R2, c2 = kabsch(positions[few], model.mean_pose, np.ones(positions[few].shape[:2]))
        R[few], c[few] = R2, c2
    return R, c


def _mm(model: DenoiserModel) -> float:
    from ..units import length_factor

    return length_factor("mm", model.units)


def to_local(positions: np.ndarray, R: np.ndarray, c: np.ndarray) -> np.ndarray:
    """positions (n, M, 3) -> body-frame coordinates (n, M, 3)."""
    return np.einsum("tmi,tij->tmj", positions - c[:, None, :], R)


def to_world(local: np.ndarray, R: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Body-frame coordinates (n, M, 3) -> laboratory positions (n, M, 3)."""
    return np.einsum("tmj,tij->tmi", local, R) + c[:, None, :]


# ----------------------------------------------------------------------------------------------------- network

def network_input(local: np.ndarray, model: DenoiserModel) -> np.ndarray:
    """(n, M, 3) local positions, NaN = occluded -> (n, 4 M) network input: normalised coordinates (0 where
    occluded) and the visibility flags."""
    n, m, _ = local.shape
    seen = ~np.isnan(local).any(axis=2)
    z = (local.reshape(n, 3 * m) - model.mean) / model.scale
    z = np.where(np.repeat(seen, 3, axis=1), z, 0.0)
    return np.concatenate([z, seen.astype(np.float64)], axis=1)


def forward(layers: Sequence[tuple[np.ndarray, np.ndarray]], x: np.ndarray) -> np.ndarray:
    """The network in NumPy: x (n, 4 M) -> (n, 3 M).  Input layer + ReLU, residual ReLU blocks, output layer.  (A
    skip from the input's coordinates to the output was tried: it keeps clean markers but passes displaced ones
    through, and its validation loss was worse, 0.83 against 0.50 after 1,000 steps.)"""
    w, b = layers[0]
    h = np.maximum(x @ w + b, 0.0)
    for w, b in layers[1:-1]:
        h = h + np.maximum(h @ w + b, 0.0)
    w, b = layers[-1]
    return h @ w + b


def predict_frames(positions: np.ndarray, model: DenoiserModel, *, chunk: int = 4096) -> np.ndarray:
    """The network's clean estimate of every marker in every frame: positions (n, M, 3) in the model's marker order
    and units (NaN = missing) -> (n, M, 3) (NaN in frames without any observed marker)."""
    n = positions.shape[0]
    out = np.full(positions.shape, np.nan)
    for start in range(0, n, chunk):
        x = positions[start:start + chunk]
        R, c = body_frames(x, model)
        z = forward(model.layers, network_input(to_local(x, R, c), model))
        local = (z * model.scale + model.mean).reshape(x.shape)
        est = to_world(local, R, c)
        est[np.isnan(x).any(axis=2).all(axis=1)] = np.nan
        out[start:start + chunk] = est
    return out


# ---------------------------------------------------------------------------------------------------- corruption

def corrupt(local: np.ndarray, rng: np.random.Generator, *, sigma_o: float = SIGMA_OCCLUSION,
            sigma_s: float = SIGMA_SHIFT, shift: float = SHIFT_MM, swap: float = SWAP_PROBABILITY,
            noise: float = NOISE_MM, neighbours: np.ndarray | None = None) -> np.ndarray:
    """Holden's corruption of clean frames (n, M, 3) (lengths in the data's units: ``shift`` and ``noise`` too).

    Returns (n, M, 3) with occluded markers NaN.  ``neighbours`` (M, k): each marker's nearest markers, the partners
    of a swap (none without it).
    """
    n, m, _ = local.shape
    out = local + rng.normal(0.0, noise, size=local.shape) if noise > 0 else local.copy()
    p_o = np.minimum(np.abs(rng.normal(0.0, sigma_o, size=(n, 1))), 2 * sigma_o)
    p_s = np.minimum(np.abs(rng.normal(0.0, sigma_s, size=(n, 1))), 2 * sigma_s)
    shifted = rng.random((n, m)) < p_s
    out = out + shifted[..., None] * rng.uniform(-shift, shift, size=(n, m, 3))
    if swap > 0 and neighbours is not None and neighbours.size:
        rows, cols = np.nonzero(rng.random((n, m)) < swap)
        partner = neighbours[cols, rng.integers(0, neighbours.shape[1], size=len(cols))]
        a, b = out[rows, cols].copy(), out[rows, partner].copy()
        out[rows, cols], out[rows, partner] = b, a
    occluded = rng.random((n, m)) < p_o
    out[occluded] = np.nan
    return out


def nearest_markers(mean_pose: np.ndarray, k: int = 3) -> np.ndarray:
    """(M, k) indices of each marker's k nearest markers in the mean pose (M, 3)."""
    d = np.linalg.norm(mean_pose[:, None] - mean_pose[None], axis=2)
    np.fill_diagonal(d, np.inf)
    return np.argsort(d, axis=1)[:, :k]


def layout_index(model: DenoiserModel, labels: Sequence[str] | None, n_markers: int) -> np.ndarray:
    """For each capture marker the layout marker it is (index into ``model.labels``) or -1: by label, a
    ``Subject:`` prefix aside; without labels, by position when the counts agree.  Raises :class:`ModelError`
    when fewer than half the layout's markers are found."""
    from ..references import bare_label

    if labels is None:
        if n_markers != model.n_markers:
            raise ModelError(f"the model's layout has {model.n_markers} markers, the capture {n_markers}; give "
                             "labels to match them by name")
        return np.arange(n_markers)
    where = {bare_label(x): k for k, x in enumerate(model.labels)}
    idx = np.array([where.get(bare_label(x), -1) for x in labels])
    found = len(set(idx[idx >= 0].tolist()))
    if found < max(3, model.n_markers // 2):
        missing = [x for x in model.labels if bare_label(x) not in {bare_label(y) for y in labels}]
        raise ModelError(f"the capture has {found} of the model's {model.n_markers} markers (lacks "
                         f"{', '.join(missing[:10])}{' ...' if len(missing) > 10 else ''}); it was trained on "
                         "another layout")
    return idx


def to_layout(positions: np.ndarray, idx: np.ndarray, model: DenoiserModel, units: str) -> np.ndarray:
    """Capture positions (n, n_markers, 3) in ``units`` -> (n, M, 3) in the model's order and units (NaN where the
    capture lacks a layout marker)."""
    from ..units import length_factor

    out = np.full((positions.shape[0], model.n_markers, 3), np.nan)
    mine = idx >= 0
    out[:, idx[mine]] = positions[:, mine] * length_factor(units, model.units)
    return out


def from_layout(estimate: np.ndarray, idx: np.ndarray, n_markers: int, model: DenoiserModel, units: str
                ) -> np.ndarray:
    """(n, M, 3) in the model's order and units -> (n, n_markers, 3) in the capture's (NaN for markers outside the
    layout)."""
    from ..units import length_factor

    out = np.full((estimate.shape[0], n_markers, 3), np.nan)
    mine = idx >= 0
    out[:, mine] = estimate[:, idx[mine]] * length_factor(model.units, units)
    return out
