"""The registry of fill methods: the one place that names them.

Every method is a function ``fill_<name>(positions, *, seed=None, **options) -> FillResult`` taking positions of
shape (n_frames, n_markers, 3) with NaN = missing.  The CLI's ``--method`` choices and the conformance test are read
from :data:`METHODS`.  Modules are imported lazily so that ``import mocapfill`` stays cheap.

Context keywords: besides its own options a method may accept any of ``seed``, ``units`` ("mm", "cm", "m"),
``rate`` (Hz), ``labels`` (list of str), ``bones`` (:class:`mocapfill.bones.boneset.BoneSet` or None) and ``progress``
(a :data:`~mocapfill.methods.base.ProgressFn`); :func:`mocapfill.fill` passes those the function's signature names.
"""

from __future__ import annotations

import importlib
import inspect
import numbers
from typing import Any, Callable, NamedTuple

from ..errors import MethodError
from .base import FillResult, finish


class MethodSpec(NamedTuple):
    """A registered method: its CLI name, where its function lives, a one-line summary, whether it gives a std, and
    whether it may decline a gap (the suites' fills: ``woltring``, ``pattern``, ``rigid``)."""

    name: str
    target: str  # "module:function", module relative to mocapfill.methods
    summary: str
    uncertainty: bool  # whether the method returns a per-sample std
    requires: str | None = None  # an option the method cannot run without (the CLI names it when it is missing)
    #: whether the method may decline a gap (leave it missing, listed in ``info["declined"]``) rather than fill it
    may_decline: bool = False

    def load(self) -> Callable[..., FillResult]:
        module_name, func_name = self.target.split(":")
        module = importlib.import_module(f"{__name__}.{module_name}")
        return getattr(module, func_name)

    def parameters(self) -> set[str]:
        """Names of the keyword options the function accepts."""
        return set(inspect.signature(self.load()).parameters) - {"positions"}

    def option_problem(self, key: str, value: Any) -> str | None:
        """Why ``value`` does not fit the function's option ``key`` ("method 'dynammo' takes an integer for
        max_iter"), or None.  Only options annotated with int / float / bool / str / None are judged (a value typed
        on a command line is one of those); an option the method does not take, or one of another type (arrays,
        callables, paths, models), is left to the method."""
        try:
            param = inspect.signature(self.load()).parameters.get(key)
        except (ImportError, AttributeError):  # not in this build: said where the method is loaded
            return None
        if param is None or param.annotation is inspect.Parameter.empty:
            return None
        annotation = param.annotation
        text = annotation if isinstance(annotation, str) else getattr(annotation, "__name__", str(annotation))
        kinds = [kind.strip() for kind in text.split("|")]
        if not all(kind in _VALUE_KINDS for kind in kinds) or any(_fits(value, kind) for kind in kinds):
            return None
        return f"method {self.name!r} takes {' or '.join(_VALUE_KINDS[k] for k in kinds)} for {key}"


#: The annotations :meth:`MethodSpec.option_problem` judges, and how a message names them.
_VALUE_KINDS = {"int": "an integer", "float": "a number", "bool": "true or false", "str": "text", "None": "none"}


def _fits(value: Any, kind: str) -> bool:
    """Whether ``value`` is of the annotation ``kind`` (a key of ``_VALUE_KINDS``); an integer is a float, a bool is
    neither (``True`` for ``max_iter`` is a slip, not 1)."""
    if kind == "None":
        return value is None
    if kind == "bool":
        return isinstance(value, bool)
    if kind == "str":
        return isinstance(value, str)
    wanted = numbers.Integral if kind == "int" else numbers.Real
    return isinstance(value, wanted) and not isinstance(value, bool)


METHODS: dict[str, MethodSpec] = {
    spec.name: spec
    for spec in [
        MethodSpec("linear", "interp:fill_linear", "per-coordinate linear interpolation", False),
        MethodSpec("spline", "interp:fill_spline", "per-coordinate cubic spline", False),
        MethodSpec("msvd", "msvd:fill_msvd", "iterative low-rank SVD imputation", False),
        MethodSpec("dynammo", "dynammo:fill_dynammo", "linear dynamical system learned by EM (DynaMMo)", True),
        MethodSpec("bolero-hc", "bolero:fill_bolero_hc", "DynaMMo with hard bone-length constraints", True),
        MethodSpec("bolero-sc", "bolero:fill_bolero_sc", "DynaMMo with soft bone-length constraints", True),
        MethodSpec("bilinear", "bilinear:fill_bilinear", "DCT-conditioned bilinear spatiotemporal basis", False),
        MethodSpec("pca", "pca:fill_pca", "distance-weighted PCA (Gloersen & Federolf 2016)", True),
        MethodSpec("auto", "auto:fill_auto", "one model: local weighted PCA fused with a white-jerk motion model by "
                   "one smoother (default)", True),
        MethodSpec("auto-stack", "auto_stack:fill_auto_stack", "the previous default, a stack of corrections around "
                   "the local PCA (kept one release for comparison)", True),
        MethodSpec("woltring", "suite:fill_woltring", "quintic spline through the frames around each gap (Nexus)",
                   False, may_decline=True),
        MethodSpec("pattern", "suite:fill_pattern", "one donor's shape + a linear bridge of the offset (Nexus)",
                   False, may_decline=True),
        MethodSpec("rigid", "suite:fill_rigid", "3+ donors carried as a rigid body, both ends blended (Nexus)",
                   False, may_decline=True),
        MethodSpec("opensim-ik", "kinematic:fill_opensim_ik", "kinematic fill: OpenSim IK on the observed markers, "
                   "the missing ones read off the fitted model (needs --ik-model; extra mocapfill[opensim])", True,
                   "ik_model"),
        MethodSpec("learned", "learned:fill_learned", "denoiser learnt from clean takes of the layout (Holden "
                   "2018; needs --model)", False, "model"),
    ]
}

DEFAULT_METHOD = "auto"


def get_method(name: str) -> MethodSpec:
    """The spec of method ``name``; raises MethodError listing the known names otherwise."""
    try:
        return METHODS[name]
    except KeyError:
        raise MethodError(f"unknown method {name!r}; choose one of {', '.join(METHODS)}") from None


__all__ = ["METHODS", "DEFAULT_METHOD", "MethodSpec", "FillResult", "finish", "get_method"]
