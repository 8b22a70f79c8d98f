"""Small OpenSim models built through the ``opensim`` API for the tests (no model file is committed).

- :func:`leg_model`: ground -> thigh -> shank -> foot, three pin joints (hip, knee, ankle about z), three markers per
  body; :func:`simulate_leg` poses it along known angles and reads its markers (mm).
- :func:`rigid_model`: one body on a free joint carrying given marker positions (the conformance test's rigid cloud).
- :func:`ik_setup_xml`: an InverseKinematicsTool setup naming a model, every marker weight 1.

Every function imports ``opensim`` itself; callers skip with ``pytest.importorskip("opensim")`` first.
"""

from __future__ import annotations

import numpy as np

#: Marker positions (m) in each body's frame; the joint to the next body is 0.4 m down the body's y axis.
LEG_MARKERS = {
    "thigh": {"THI1": (0.06, -0.10, 0.03), "THI2": (-0.05, -0.22, -0.04), "THI3": (0.07, -0.33, -0.02)},
    "shank": {"SHK1": (0.05, -0.08, 0.04), "SHK2": (-0.06, -0.20, 0.02), "SHK3": (0.04, -0.32, -0.05)},
    "foot": {"FT1": (0.03, -0.02, 0.05), "FT2": (0.12, -0.05, -0.03), "FT3": (0.20, -0.04, 0.02)},
}
LEG_COORDINATES = ("hip_flexion", "knee_angle", "ankle_angle")


def leg_model(path: str) -> list[str]:
    """Write the three-pin leg model to ``path`` (.osim); returns its marker names in order."""
    import opensim as osim

    model = osim.Model()
    model.setName("leg")
    parent = model.getGround()
    parent_offset = osim.Vec3(0, 1.0, 0)
    names = []
    for body_name, coord in zip(("thigh", "shank", "foot"), LEG_COORDINATES):
        body = osim.Body(body_name, 2.0, osim.Vec3(0, -0.2, 0), osim.Inertia(0.02, 0.005, 0.02))
        joint = osim.PinJoint(f"{coord}_joint", parent, parent_offset, osim.Vec3(0), body, osim.Vec3(0),
                              osim.Vec3(0))
        joint.upd_coordinates(0).setName(coord)
        joint.upd_coordinates(0).setRangeMin(-3.0)
        joint.upd_coordinates(0).setRangeMax(3.0)
        model.addBody(body)
        model.addJoint(joint)
        for name, loc in LEG_MARKERS[body_name].items():
            model.addMarker(osim.Marker(name, body, osim.Vec3(*loc)))
            names.append(name)
        parent, parent_offset = body, osim.Vec3(0, -0.4, 0)
    model.finalizeConnections()
    model.printToXML(path)
    return names


def leg_angles(n_frames: int, rate: float) -> np.ndarray:
    """Known joint angles (n_frames, 3), radians: hip, knee, ankle swinging at different frequencies."""
    t = np.arange(n_frames) / rate
    return np.stack([0.5 * np.sin(2 * np.pi * 0.8 * t), -0.6 + 0.5 * np.sin(2 * np.pi * 1.1 * t + 0.4),
                     0.25 * np.sin(2 * np.pi * 1.7 * t + 1.0)], axis=1)


def simulate_leg(path: str, angles: np.ndarray) -> np.ndarray:
    """Marker positions (n_frames, 9, 3) in mm of the model at ``path`` posed at ``angles`` (n_frames, 3) radians."""
    import opensim as osim

    model = osim.Model(path)
    state = model.initSystem()
    coords = [model.getCoordinateSet().get(name) for name in LEG_COORDINATES]
    markers = model.getMarkerSet()
    out = np.zeros((len(angles), markers.getSize(), 3))
    for t, q in enumerate(angles):
        for c, value in zip(coords, q):
            c.setValue(state, float(value), False)
        model.realizePosition(state)
        for m in range(markers.getSize()):
            p = markers.get(m).getLocationInGround(state)
            out[t, m] = [p.get(0), p.get(1), p.get(2)]
    return out * 1000.0


def rigid_model(path: str, labels: list[str], local_m: np.ndarray) -> None:
    """One body on a free joint with markers ``labels`` at ``local_m`` (n, 3) metres in its frame, written to
    ``path``."""
    import opensim as osim

    model = osim.Model()
    model.setName("rigid")
    body = osim.Body("cloud", 1.0, osim.Vec3(0), osim.Inertia(0.1, 0.1, 0.1))
    joint = osim.FreeJoint("free", model.getGround(), osim.Vec3(0), osim.Vec3(0), body, osim.Vec3(0), osim.Vec3(0))
    for i in range(6):
        joint.upd_coordinates(i).setRangeMin(-100.0)
        joint.upd_coordinates(i).setRangeMax(100.0)
    model.addBody(body)
    model.addJoint(joint)
    for name, loc in zip(labels, np.asarray(local_m, dtype=float)):
        model.addMarker(osim.Marker(name, body, osim.Vec3(*map(float, loc))))
    model.finalizeConnections()
    model.printToXML(path)


def ik_setup_xml(path: str, model_path: str, markers: list[str]) -> None:
    """An InverseKinematicsTool setup at ``path``: the model, every marker task applied with weight 1."""
    import opensim as osim

    tool = osim.InverseKinematicsTool()
    tool.setName("test")
    tool.set_model_file(model_path)
    tasks = tool.getIKTaskSet()
    for name in markers:
        task = osim.IKMarkerTask()
        task.setName(name)
        task.setWeight(1.0)
        task.setApply(True)
        tasks.cloneAndAppend(task)
    tool.set_accuracy(1e-6)
    tool.printToXML(path)
