"""Training the learned denoiser (:mod:`.denoiser`) with JAX and optax: the ``mocapfill[learn]`` extra.

:func:`train` takes clean captures of one marker layout, puts every frame in the body frame, and fits the network by
AMSGrad on an L1 loss (Holden 2018) over mini-batches corrupted on the fly (:func:`.denoiser.corrupt`).  The body
frame of a training input is fitted to the *corrupted* markers, as it will be at run time, and the target is the
clean frame in that same body frame.  The last ``validation`` fraction of every take is held out: its loss is
reported, and the per-marker error on it (with Holden's occlusions, no shifts) becomes ``model.residual``, the
scale the denoise guard judges displacements by.

Only this module imports JAX; without the extra, :func:`require_jax` raises a one-line error naming it.
"""

from __future__ import annotations

import time
from typing import Any, Callable, Sequence

import numpy as np

from ..errors import MocapfillError
from ..units import length_factor
from .denoiser import (MIN_SCALE_MM, NOISE_MM, SHIFT_MM, SIGMA_OCCLUSION, SIGMA_SHIFT, SWAP_PROBABILITY,
                       DenoiserModel, body_frames, corrupt, forward, kabsch, nearest_markers, network_input,
                       to_local)

#: Default network and schedule: small enough to train on 2 shared CPU cores in minutes (Holden: 2048 units, 6
#: blocks, on a GPU).
HIDDEN = 256
BLOCKS = 2
STEPS = 3000
BATCH = 256
LEARNING_RATE = 1e-3
#: Fraction of each take (its end) held out for validation.
VALIDATION = 0.1


class LearnExtraMissing(MocapfillError):
    """``mocapfill train`` needs JAX and optax (the ``learn`` extra)."""


def require_jax():
    """Import and return (jax, jax.numpy, optax), or raise :class:`LearnExtraMissing` in one line."""
    try:
        import jax
        import jax.numpy as jnp
        import optax
    except ImportError as exc:
        raise LearnExtraMissing(f"training a denoiser needs the learn extra (JAX, optax): pip install "
                                f"'mocapfill[learn]' ({exc.name or exc} is not installed)") from None
    return jax, jnp, optax


def _init_layers(rng: np.random.Generator, n_in: int, hidden: int, blocks: int, n_out: int) -> list:
    """LeCun-normal weights, zero biases: input layer, ``blocks`` residual layers, output layer."""
    sizes = [(n_in, hidden)] + [(hidden, hidden)] * blocks + [(hidden, n_out)]
    return [(rng.normal(0.0, 1.0 / np.sqrt(a), size=(a, b)), np.zeros(b)) for a, b in sizes]


def _frame_template(local_pts: np.ndarray) -> np.ndarray:
    """Mean shape (F, 3) of the frame markers over complete frames (n, F, 3), after one Procrustes pass."""
    ref = local_pts[len(local_pts) // 2] - local_pts[len(local_pts) // 2].mean(axis=0)
    R, c = kabsch(local_pts, ref, np.ones(local_pts.shape[:2]))
    return np.einsum("tfi,tij->tfj", local_pts - c[:, None, :], R).mean(axis=0)


def train(takes: Sequence[np.ndarray], labels: Sequence[str], units: str, *, hidden: int = HIDDEN,
          blocks: int = BLOCKS, steps: int = STEPS, batch: int = BATCH, learning_rate: float = LEARNING_RATE,
          seed: int = 0, sigma_o: float = SIGMA_OCCLUSION, sigma_s: float = SIGMA_SHIFT,
          shift_mm: float = SHIFT_MM, swap: float = SWAP_PROBABILITY, noise_mm: float = NOISE_MM,
          validation: float = VALIDATION, names: Sequence[str] | None = None,
          progress: Callable[[int, int, float], None] | None = None) -> DenoiserModel:
    """Train a denoiser on clean takes of one layout.

    Parameters
    ----------
    takes : sequence of ndarray (n_frames_i, M, 3)
        Clean captures, all in ``units`` and the order of ``labels`` (NaN = missing: frames with a missing marker
        are not used).
    labels : the layout's marker labels (M,), without subject prefix.
    hidden, blocks : width and residual blocks of the network.
    steps, batch, learning_rate : AMSGrad schedule.
    sigma_o, sigma_s, shift_mm, swap, noise_mm : the corruption (:func:`.denoiser.corrupt`); lengths in mm.
    validation : fraction of each take (its end) held out.
    progress : ``progress(step, steps, loss)`` every few steps.

    Returns
    -------
    DenoiserModel
    """
    jax, jnp, optax = require_jax()
    from .body_frame import frame_markers, vertical_axis

    started = time.perf_counter()
    mm = length_factor("mm", units)
    train_parts, val_parts = [], []
    for x in takes:
        x = np.asarray(x, dtype=np.float64)
        complete = x[~np.isnan(x).any(axis=(1, 2))]
        cut = int(round(len(complete) * (1 - validation)))
        train_parts.append(complete[:cut])
        val_parts.append(complete[cut:])
    clean = np.concatenate(train_parts)
    if clean.shape[1] == 0:  # every frame of no markers is "complete": say so before the body frame reduces over none
        raise MocapfillError("training needs markers observed in every take; the takes give none")
    held = np.concatenate(val_parts) if sum(len(v) for v in val_parts) else clean[-max(1, len(clean) // 10):]
    if len(clean) < 50:
        raise MocapfillError(f"training needs at least 50 complete frames of the layout; the takes give {len(clean)}")
    n_markers = clean.shape[1]
    fm = frame_markers(clean, axis=vertical_axis(clean))
    # template of the frame markers, and a first body frame for the normalisation statistics
    template = _frame_template(clean[:, fm])
    probe = DenoiserModel(list(labels), units, fm, template, np.zeros(3 * n_markers), np.ones(3 * n_markers), [],
                          np.zeros(n_markers))
    R, c = body_frames(clean, probe)
    local = to_local(clean, R, c)
    mean = local.reshape(len(local), -1).mean(axis=0)
    scale = np.maximum(local.reshape(len(local), -1).std(axis=0), MIN_SCALE_MM * mm)
    probe.mean, probe.scale = mean, scale
    neighbours = nearest_markers(mean.reshape(-1, 3))

    rng = np.random.default_rng(seed)

    def make_batch(frames: np.ndarray, size: int, shifts: bool = True) -> tuple[np.ndarray, np.ndarray]:
        world = frames[rng.integers(0, len(frames), size=size)]
        bad = corrupt(world, rng, sigma_o=sigma_o, sigma_s=sigma_s if shifts else 0.0, shift=shift_mm * mm,
                      swap=swap if shifts else 0.0, noise=noise_mm * mm, neighbours=neighbours)
        Rb, cb = body_frames(bad, probe)  # the frame fitted to the corrupted markers, as at run time
        x = network_input(to_local(bad, Rb, cb), probe)
        y = ((to_local(world, Rb, cb).reshape(size, -1) - mean) / scale)
        return x.astype(np.float32), y.astype(np.float32)

    params = [(jnp.asarray(w, dtype=jnp.float32), jnp.asarray(b, dtype=jnp.float32))
              for w, b in _init_layers(rng, 4 * n_markers, hidden, blocks, 3 * n_markers)]

    def net(p, x):
        h = jax.nn.relu(x @ p[0][0] + p[0][1])
        for w, b in p[1:-1]:
            h = h + jax.nn.relu(h @ w + b)
        return h @ p[-1][0] + p[-1][1]

    def loss_fn(p, x, y):
        return jnp.mean(jnp.abs(net(p, x) - y))

    optimiser = optax.amsgrad(learning_rate)
    state = optimiser.init(params)

    @jax.jit
    def step_fn(p, s, x, y):
        loss, grads = jax.value_and_grad(loss_fn)(p, x, y)
        updates, s = optimiser.update(grads, s, p)
        return optax.apply_updates(p, updates), s, loss

    val_x, val_y = make_batch(held, min(2048, max(256, len(held))))
    losses = []
    running = float("nan")
    for k in range(1, steps + 1):
        x, y = make_batch(clean, batch)
        params, state, loss = step_fn(params, state, jnp.asarray(x), jnp.asarray(y))
        if k % 50 == 0 or k == steps:
            running = float(loss)
            losses.append([k, running])
            if progress is not None:
                progress(k, steps, running)
    layers = [(np.asarray(w, dtype=np.float64), np.asarray(b, dtype=np.float64)) for w, b in params]
    val_loss = float(np.mean(np.abs(forward(layers, val_x.astype(np.float64)) - val_y)))
    # per-marker error on held-out frames with occlusions only: the scale of an honest output
    occ_x, occ_y = make_batch(held, min(2048, max(256, len(held))), shifts=False)
    err = (forward(layers, occ_x.astype(np.float64)) - occ_y) * scale
    residual = np.sqrt((err.reshape(len(err), n_markers, 3) ** 2).sum(axis=2).mean(axis=0))
    seconds = time.perf_counter() - started
    settings: dict[str, Any] = {
        "hidden": hidden, "blocks": blocks, "steps": steps, "batch": batch, "learning_rate": learning_rate,
        "seed": seed, "optimiser": "amsgrad", "loss": "L1 on normalised body-frame positions",
        "corruption": {"sigma_occlusion": sigma_o, "sigma_shift": sigma_s, "shift_mm": shift_mm,
                       "swap_probability": swap, "noise_mm": noise_mm},
        "frames": int(len(clean)), "validation_frames": int(len(held)), "takes": list(names or []),
        "train_loss": running, "validation_loss": val_loss, "seconds": round(seconds, 2),
        "loss_curve": losses, "jax": jax.__version__,
    }
    return DenoiserModel(list(labels), units, fm, template, mean, scale, layers, residual, settings)
