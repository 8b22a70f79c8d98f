"""Joint angles from markers: OpenSim inverse kinematics (IK) and the errors a fill makes in them.

The real component is optional: ``pip install 'mocapfill[opensim]'`` (the ``opensim`` wheels on PyPI, CPython
3.11-3.13).  ``opensim`` is imported only when a function that needs it is called; without it they raise a
one-line :class:`~mocapfill.errors.MocapfillError` naming the extra.

Public API
----------
- :mod:`.opensim_ik`: :func:`~.opensim_ik.load_setup` (an IK setup XML and its model) -> :class:`~.opensim_ik.IKSetup`;
  :func:`~.opensim_ik.run_ik` (setup, capture) -> :class:`~.opensim_ik.IKAngles` (the InverseKinematicsTool on a TRC
  that mocapfill writes); :func:`~.opensim_ik.track` (model, positions) -> :class:`~.opensim_ik.Tracked` (the IK
  solver frame by frame, with the fitted model's marker and body positions: what the kinematic fill reads).
- :mod:`.angles` (pure NumPy): :func:`~.angles.coordinate_errors` and :func:`~.angles.summarise_errors`: RMSE over
  frames per coordinate, then the median and worst coordinate, rotational (degrees) and translational apart.
"""

from __future__ import annotations

from .angles import coordinate_errors, summarise_errors

__all__ = ["coordinate_errors", "summarise_errors"]
