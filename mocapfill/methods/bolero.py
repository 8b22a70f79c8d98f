"""BoLeRO: DynaMMo with bone-length constraints (Li, McCann, Pollard & Faloutsos 2010).

Both variants run the DynaMMo EM engine (:func:`mocapfill.methods.dynammo.run_dynammo`) and, after each E-step from
iteration ``project_start`` on, replace the imputation of every frame with a missing marker by the solution of a
per-frame problem around the model's estimate e_t = G E[z_t] (:mod:`mocapfill.bones.constraints`), and once more
after EM on the estimate with DynaMMo's gap-end residual bridge added (that solve is the output).  The engine runs
with ``fill_dynammo``'s settings (its defaults) and hands the hook only the frames with a missing marker
(:class:`mocapfill.methods.dynammo.ProjectStep`):

- **BoLeRO-HC** (hard): the missing coordinates nearest e_t (the observation noise is isotropic, so its metric is
  the Euclidean one) with |x_u - x_v| = L for every bone touching a missing marker; where the bones cannot all hold,
  the least-squares point of the bone residuals.
- **BoLeRO-SC** (soft): the paper's per-frame objective |x - e_t|^2 / sigma^2 + sum_b lambda_b (|x_u - x_v|^2 -
  L_b^2)^2 with a per-bone weight ``lambda_b = w_b / (4 sigma^2 L_b^2)``.  Then the objective is
  ``(1/sigma^2) [ |x - e_t|^2 + sum_b w_b r_b^2 ]`` with r_b = (|d|^2 - L^2) / (2L) ~ |d| - L: a bone's length error
  costs w_b times as much as the same displacement of a marker from the model.  ``w_b = w (s_ref / s_b)^2``
  (:func:`bone_weights`): s_b is the bone's spread (robust std of its length in the observed frames) and s_ref the
  median spread of the set, i.e. the Gaussian bone-length model, so nearly-rigid pairs weigh less than rigid ones.
  The weights are dimensionless, hence independent of the units (sigma, L and s scale together), of sigma^2 (which
  cancels from the minimiser) and of the number of markers (the penalty is per bone and frame, the likelihood per
  marker and frame).  The paper's fixed lambda = 10^6 (in metres) instead depends on the units, on the noise level
  EM happens to reach and on each bone's length.  Default w = :data:`DEFAULT_PENALTY` (measured).

Bones come from ``bones`` (a :class:`mocapfill.bones.boneset.BoneSet`) or, when None, from
:func:`mocapfill.bones.boneset.estimate_bones` on the observed samples of the same input.
"""

from __future__ import annotations

from typing import Any, Callable

import numpy as np

from ..bones.boneset import resolve_bones
from ..errors import MethodError
from .base import FillResult, ProgressFn, check_positions
from ..bones.constraints import SolveStats, bone_errors, frame_groups, solve_hard, solve_soft
from .dynammo import DEFAULT_HIDDEN, DEFAULT_MAX_ITER, DEFAULT_TOL, ProjectStep, run_dynammo

#: Default dimensionless penalty weight w of BoLeRO-SC.  Measured with ``benchmarks/bench_bolero.py --sweep-penalty``
#: (10 trials x 2 protocols x 2 files, spread weighting): w = 1 / 3 / 10 / 100 gave the median RMSE ratio to DynaMMo
#: 0.55 / 0.48 / 0.455 / 0.52, RMSE <= DynaMMo's in 95 / 95 / 95 / 90 % of trials and a mean bone error 6.9 / 11.4
#: / 16 / (not measured) x lower.  Larger w pulls harder on bones that are only nearly rigid (a shoulder marker to
#: the spine), which is where BoLeRO loses to DynaMMo.
DEFAULT_PENALTY = 10.0

#: Newton steps per EM iteration once BoLeRO-SC's per-frame solve is warm-started from the previous solution.
#: 1 and 2 gave the same RMSE to 3 digits on the 5 trials checked; 1 costs half.
WARM_NEWTON_STEPS = 1

#: How BoLeRO-SC weighs bones against each other (see :func:`bone_weights`).
BONE_WEIGHTINGS = ("spread", "none")
DEFAULT_BONE_WEIGHTING = "spread"

#: First EM iteration whose imputation is constrained.  Measured (``--sweep-start 1,2,5,15``): 1 and 2 give the same
#: RMSE to 3 digits on all 40 trials; 5 and 15 are no more accurate and sometimes let DynaMMo's objective-change test
#: stop EM a few iterations after the constraints start (the objective jumps when they do), so: from the start.
PROJECT_START_SC = 1
PROJECT_START_HC = 1

HC_WARM_NEWTON_STEPS = 2


def _run(positions, solver: Callable[..., tuple[np.ndarray, SolveStats]], *, variant: str, bones, units, labels,
         hidden, max_iter, tol, seed, progress, project_start, extra_info, uncertainty=True) -> FillResult:
    positions = check_positions(positions)
    if int(project_start) < 1:
        raise MethodError(f"project_start must be >= 1, got {project_start}")
    boneset = resolve_bones(positions, bones, units=units, labels=labels)
    source = "given" if bones is not None else "estimated from the observed samples"
    pairs, lengths, spread = boneset.pairs, boneset.lengths, boneset.spread
    missing = np.isnan(positions).any(axis=2)
    # A marker missing in every frame stays NaN (the engine does not model it): its bones hold nothing.
    dead = missing.all(axis=0) if missing.size else np.zeros(positions.shape[1], dtype=bool)
    alive = ~dead[pairs].any(axis=1) if pairs.size else np.zeros(0, dtype=bool)
    pairs, lengths, spread = pairs[alive], lengths[alive], spread[alive]
    missing = missing & ~dead
    record: dict[str, Any] = {"calls": 0, "iterations": 0, "last": None, "frames": None}

    def project(step: ProjectStep) -> np.ndarray:
        # The engine passes only the frames with a missing marker; the data's observed samples there are the
        # bones' fixed partners, so they are taken from ``positions``, not from the model's estimate.
        if record["frames"] is None:
            record["frames"] = step.frames
            record["data"] = positions[step.frames]
            record["missing"] = step.missing & ~dead
        out, stats = solver(step.estimate, record["data"], record["missing"], pairs, lengths, spread,
                            final=step.final)
        record["calls"] += 1
        record["iterations"] += stats.iterations
        record["last"] = stats
        return out

    use = project if pairs.shape[0] and missing.any() else None
    # The engine's own settings, as fill_dynammo runs it (gap-end bridge included: the bridged estimate goes
    # through the solver once more, so the output still meets its bones).
    result = run_dynammo(positions, hidden=hidden, max_iter=max_iter, tol=tol, seed=seed, progress=progress,
                         project=use, project_start=int(project_start), uncertainty=uncertainty)
    info = dict(result.info)
    info.update(extra_info)
    info["variant"] = variant
    info["bones"] = int(pairs.shape[0])
    info["bones_source"] = source
    info["project_start"] = int(project_start)
    info["constraint_solves"] = record["calls"]
    info["solver_iterations"] = record["iterations"]
    last = record["last"]
    if last is not None:
        info["last_solve"] = last.as_dict()
    info.update(_violations(result.positions, missing, pairs, lengths))
    if last is not None and variant == "hard":
        # Exactness where the bones can all hold: the frames the last solve did not report as infeasible.
        feasible = missing.copy()
        feasible[record["frames"][np.asarray(last.infeasible, dtype=np.intp)]] = False  # solver rows -> frames
        info["infeasible_frames"] = int(last.n_infeasible)
        info["bone_error_max_rel_feasible"] = _violations(result.positions, feasible, pairs, lengths)[
            "bone_error_max_rel"]
    result.info = info
    return result


def bone_weights(penalty: float, lengths: np.ndarray, spread: np.ndarray, mode: str) -> np.ndarray:
    """Per-bone weights w_b of BoLeRO-SC, shape (B,), from the penalty w and the bones' spreads (B,).

    ``"none"``: w for every bone.  ``"spread"``: ``w * (s_ref / s_b)^2`` with s_b a bone's spread (robust standard
    deviation of its length in the observed frames) and s_ref the median spread of the set, the ratio clipped to
    [1/100, 100]: the Gaussian bone-length model, in which a bone whose length varies more weighs less.  Bones of
    unknown spread (hand-written) get s_ref.  Dimensionless, so independent of units and of the marker count.
    """
    weight = np.full(lengths.shape, float(penalty))
    if mode == "none" or not lengths.size:
        return weight
    spread = np.asarray(spread, dtype=np.float64)
    known = np.isfinite(spread) & (spread > 0)
    if not known.any():
        return weight
    ref = float(np.median(spread[known]))
    ratio = np.ones(lengths.shape)
    ratio[known] = np.clip((ref / spread[known]) ** 2, 1e-2, 1e2)
    return weight * ratio


def _cached_groups(data, missing, pairs, lengths, cache: dict) -> list:
    """The per-pattern systems, built once per fill: the missing mask is the same at every EM iteration."""
    key = missing.tobytes()
    if cache.get("key") != key:
        cache["key"] = key
        cache["groups"] = frame_groups(data, missing, pairs, lengths)
    return cache["groups"]


def _violations(filled: np.ndarray, missing: np.ndarray, pairs: np.ndarray, lengths: np.ndarray) -> dict:
    """Bone-length errors of the output on (bone, frame) pairs with a missing endpoint: mean and max, data units."""
    if not pairs.size:
        return {"bone_error_mean": 0.0, "bone_error_max": 0.0, "bone_error_max_rel": 0.0}
    active = missing[:, pairs[:, 0]] | missing[:, pairs[:, 1]]
    all_err = np.abs(bone_errors(filled, pairs, lengths))
    err = all_err[active]
    err = err[np.isfinite(err)]
    if not err.size:
        return {"bone_error_mean": 0.0, "bone_error_max": 0.0, "bone_error_max_rel": 0.0}
    rel = (all_err / lengths)[active]
    return {"bone_error_mean": float(err.mean()), "bone_error_max": float(err.max()),
            "bone_error_max_rel": float(np.nanmax(rel))}


def fill_bolero_hc(
    positions: np.ndarray,
    *,
    bones: Any = None,
    units: str = "mm",
    labels: list[str] | None = None,
    hidden: int = DEFAULT_HIDDEN,
    max_iter: int = DEFAULT_MAX_ITER,
    tol: float = DEFAULT_TOL,
    seed: int | None = None,
    progress: ProgressFn | None = None,
    project_start: int = PROJECT_START_HC,
    solver_iter: int = 50,
) -> FillResult:
    """Fill gaps with DynaMMo under hard bone-length constraints (BoLeRO-HC).

    Parameters
    ----------
    positions : ndarray, shape (n_frames, n_markers, 3)
        NaN = missing.
    bones : BoneSet or None
        Bones to hold; None estimates them from the observed samples of ``positions``.
    units, labels
        Passed to bone estimation.
    hidden, max_iter, tol, seed, progress
        DynaMMo's options.
    project_start : int
        First EM iteration (1-based) whose imputation is constrained.
    uncertainty : True, "model" or False
        As :func:`~mocapfill.methods.dynammo.run_dynammo`: long gaps' std from a second opinion (True), the
        model's own posterior with its drift ("model"), or no std (False).
    solver_iter : int
        Iteration cap of each phase of the per-frame solver.

    Returns
    -------
    FillResult
        ``positions`` (n_frames, n_markers, 3); ``info`` holds ``bones`` (count), ``bone_error_mean`` /
        ``bone_error_max`` / ``bone_error_max_rel`` of the output on constrained (bone, frame) pairs,
        ``infeasible_frames`` (frames whose bones cannot all hold: least-squares there),
        ``bone_error_max_rel_feasible`` (the largest relative bone error on the other frames), ``last_solve``
        (the last per-frame solve: violations before/after, iterations, infeasible frames) and
        ``solver_iterations`` (summed over EM iterations).
    """

    cache: dict = {}
    previous: list[np.ndarray] = []

    def solver(estimate, data, missing, pairs, lengths, spread, final=False):
        # Cold starts (penalty continuation from the estimate) except in frames with no observed partner: there a
        # warm start from the previous EM iteration's solution was measured to keep frames with an observed
        # partner on a branch of the constraint set that is no longer the nearest to the estimate (RMSE up to
        # 1.65x worse on 7 of 40 benchmark trials, median ratio to DynaMMo 0.475 -> 0.52), while in whole-body
        # blackouts it is as accurate and the cold start is what makes HC slow (the final solve is always cold).
        out, stats = solve_hard(estimate, data, missing, pairs, lengths, max_iter=solver_iter,
                                start=previous[0] if previous and not final else None, start_unanchored_only=True,
                                warm_newton_iter=HC_WARM_NEWTON_STEPS,
                                groups=_cached_groups(data, missing, pairs, lengths, cache))
        previous[:] = [out]
        return out, stats

    return _run(positions, solver, variant="hard", bones=bones, units=units, labels=labels, hidden=hidden,
                max_iter=max_iter, tol=tol, seed=seed, progress=progress, project_start=project_start,
                extra_info={})


def fill_bolero_sc(
    positions: np.ndarray,
    *,
    bones: Any = None,
    units: str = "mm",
    labels: list[str] | None = None,
    hidden: int = DEFAULT_HIDDEN,
    max_iter: int = DEFAULT_MAX_ITER,
    tol: float = DEFAULT_TOL,
    seed: int | None = None,
    progress: ProgressFn | None = None,
    penalty: float = DEFAULT_PENALTY,
    bone_weighting: str = DEFAULT_BONE_WEIGHTING,
    project_start: int = PROJECT_START_SC,
    solver_iter: int = 30,
    uncertainty: bool | str = True,
) -> FillResult:
    """Fill gaps with DynaMMo under soft bone-length constraints (BoLeRO-SC).

    Parameters
    ----------
    positions : ndarray, shape (n_frames, n_markers, 3)
        NaN = missing.
    bones : BoneSet or None
        Bones to favour; None estimates them from the observed samples of ``positions``.
    penalty : float
        Dimensionless weight w >= 0: lambda_b = w_b / (4 sigma^2 L_b^2) in the paper's objective, i.e. a bone's
        length error costs w_b times a marker's displacement from the model (w_b = w, scaled by the bone's spread
        under ``bone_weighting="spread"``).  0 gives plain DynaMMo.
    bone_weighting : {"spread", "none"}
        Per-bone weights from the bones' spreads (see :func:`bone_weights`), or w for every bone.
    project_start : int
        First EM iteration (1-based) whose imputation is penalised.
    solver_iter : int
        Newton iterations per frame group and EM iteration.
    (other parameters as :func:`fill_bolero_hc`)

    Returns
    -------
    FillResult
        As :func:`fill_bolero_hc`, with ``info["penalty"]``.
    """
    penalty = float(penalty)
    if not np.isfinite(penalty) or penalty < 0:
        raise MethodError(f"penalty must be a finite number >= 0, got {penalty}")

    if bone_weighting not in BONE_WEIGHTINGS:
        raise MethodError(f"bone_weighting must be one of {', '.join(BONE_WEIGHTINGS)}, got {bone_weighting!r}")
    previous: list[np.ndarray] = []
    cache: dict = {}

    def solver(estimate, data, missing, pairs, lengths, spread, final=False):
        weight = bone_weights(penalty, lengths, spread, bone_weighting)
        # Warm start from the previous EM iteration's solution: the estimate moves little between iterations, and
        # EM is itself the outer loop, so WARM_NEWTON_STEPS Newton steps per iteration track the moving minimiser
        # (Newton converges quadratically from there) at a fraction of a full solve (~10 steps from the estimate).
        # The first and the final (after the bridge) solves run to convergence.
        out, stats = solve_soft(estimate, data, missing, pairs, lengths, weight=weight,
                                max_iter=min(solver_iter, WARM_NEWTON_STEPS) if previous and not final else
                                solver_iter,
                                start=previous[0] if previous else None,
                                groups=_cached_groups(data, missing, pairs, lengths, cache))
        previous[:] = [out]
        return out, stats

    return _run(positions, solver, variant="soft", bones=bones, units=units, labels=labels, hidden=hidden,
                max_iter=max_iter, tol=tol, seed=seed, progress=progress, project_start=project_start,
                extra_info={"penalty": penalty, "bone_weighting": bone_weighting}, uncertainty=uncertainty)


__all__ = ["fill_bolero_hc", "fill_bolero_sc", "DEFAULT_PENALTY", "PROJECT_START_SC", "PROJECT_START_HC"]
