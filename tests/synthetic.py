"""The tests' synthetic moving body: one generator for every test that needs a capture whose truth it knows.

A body is a set of marker positions in its own frame (random, or given), optionally with a second segment on a hinge;
per frame it is turned and carried along a path through the laboratory, then noise may be added. Each test states its
motion with :func:`rot_x` / :func:`rot_z` and a path as functions of time, so the data say what the test is about
(a tumbling cloud that a laboratory-frame linear model cannot follow, a hinge whose pair is not a bone, ...).
"""

from __future__ import annotations

from typing import Callable

import numpy as np

#: A function of the frame times t (n_frames,) in seconds.
OfTime = Callable[[np.ndarray], np.ndarray]


def plane_rotations(angle: np.ndarray, i: int, j: int) -> np.ndarray:
    """Rotations by ``angle`` (n_frames,) radians from axis ``i`` towards axis ``j``: (n_frames, 3, 3)."""
    c, s = np.cos(angle), np.sin(angle)
    out = np.repeat(np.eye(3)[None], len(angle), axis=0)
    out[:, i, i] = out[:, j, j] = c
    out[:, i, j], out[:, j, i] = -s, s
    return out


def rot_z(angle: np.ndarray) -> np.ndarray:
    """Rotations about the vertical axis z: (n_frames, 3, 3)."""
    return plane_rotations(angle, 0, 1)


def rot_x(angle: np.ndarray) -> np.ndarray:
    """Rotations about the x axis: (n_frames, 3, 3)."""
    return plane_rotations(angle, 1, 2)


def walk(t: np.ndarray) -> np.ndarray:
    """The default path: 300 mm/s along x at 1 m height, (n_frames, 3)."""
    return np.stack([300.0 * t, 0.0 * t, 1000.0 + 0.0 * t], axis=1)


def moving_body(n_frames: int = 300, n_markers: int = 9, *, seed: int = 0, rng: np.random.Generator | None = None,
                spread: float = 150.0, body: np.ndarray | None = None, rate: float = 100.0,
                rotation: OfTime | None = None, path: OfTime = walk,
                hinge: tuple[slice, OfTime, np.ndarray | list] | None = None, noise: float = 0.0) -> np.ndarray:
    """A complete capture of a moving body, in mm: (n_frames, n_markers, 3), no NaN.

    Parameters
    ----------
    n_frames, n_markers : int
        Frames, and markers of a random body (ignored when ``body`` is given).
    seed, rng : int, Generator
        The random numbers (``rng`` wins): first the body, N(0, ``spread``^2) per coordinate, then the noise.
    body : (n_markers, 3) array, optional
        The markers in the body's own frame instead of random ones.
    rate : float
        Frames per second: the functions below get the times t = frame / rate.
    rotation : t -> (n_frames, 3, 3), optional
        The body's orientation per frame (none: it only translates).
    path : t -> (n_frames, 3)
        Where the body's origin is per frame (default :func:`walk`).
    hinge : (markers, t -> (n_frames, 3, 3), offset), optional
        A second segment: those markers are first turned by their own rotation about the body's origin and moved by
        ``offset``, then turned and carried with the rest.
    noise : float
        Standard deviation (mm) of Gaussian noise added to every coordinate.
    """
    rng = rng if rng is not None else np.random.default_rng(seed)
    if body is None:
        body = rng.normal(scale=spread, size=(n_markers, 3))
    t = np.arange(n_frames) / rate
    pos = np.repeat(np.asarray(body, dtype=float)[None], n_frames, axis=0)
    if hinge is not None:
        markers, turn, offset = hinge
        pos[:, markers] = np.einsum("fij,fmj->fmi", turn(t), pos[:, markers]) + np.asarray(offset, dtype=float)
    if rotation is not None:
        pos = np.einsum("fij,fmj->fmi", rotation(t), pos)
    pos = pos + path(t)[:, None, :]
    if noise:
        pos = pos + rng.normal(0.0, noise, pos.shape)
    return pos


def tumbling_body(n_frames: int = 300, n_markers: int = 9, seed: int = 2) -> np.ndarray:
    """A rigid marker cloud (mm) tumbling through full turns about two axes while it travels: a linear map in the
    laboratory frame cannot follow it, one in the body's frame can.  (n_frames, n_markers, 3)."""
    return moving_body(n_frames, n_markers, seed=seed, spread=120.0, rate=100.0,
                       rotation=lambda t: rot_x(2 * np.pi * 0.25 * t) @ rot_z(2 * np.pi * 0.4 * t))
