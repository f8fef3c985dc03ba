"""Test data of a creature without standard marker names (shared by the lacore and Blender calibration tests)."""

import numpy as np
from conftest import shared_mesh

from lacore.markers.binding import MarkerBinding, surface_points

#: The creature: the finger of shared/data as a 46 cm tentacle (object scale 0.1), turned 30 degrees about Z.
CREATURE_SCALE, CREATURE_TURN, CREATURE_AT = 0.1, np.radians(30.0), np.array([0.3, -0.2, 0.1])
CREATURE_FRAMES, CREATURE_PINS = 8, (0, 5, 11)


def creature_inputs():
    """A finger (no standard marker names: m01..m12) with 6 training poses as shape keys and a take of 8 other
    poses of the same shape space: 12 markers 1 cm off its surface, 0.5 mm noise, in metres in the world."""
    from lacore.io.meshes import load_mesh
    from lacore.markers.io import MarkerTake
    from lacore.models.shape_model import ShapeModel
    shapes = [load_mesh(shared_mesh(f"finger/{n}.ply")) for n in ("finger0", "finger1", "finger_var")]
    faces = shapes[0][1]
    space = ShapeModel.fit(np.array([X for X, _ in shapes]), faces)
    sd = space.standard_deviations
    grid = np.array([[a, b] for a in (-1.0, 0.0, 1.0) for b in (-1.0, 1.0)]) * sd[:2]
    training = np.array([space.synthesize(c) for c in grid])
    path = np.column_stack([np.linspace(-0.8, 0.8, CREATURE_FRAMES), 0.5 * np.sin(np.linspace(0, 3, CREATURE_FRAMES))])
    poses = np.array([space.synthesize(c) for c in path * sd[:2]])
    rng = np.random.default_rng(5)
    marker_faces = rng.choice(len(faces), 12, replace=False)
    bary = rng.random((12, 3)) + 0.2
    binding = MarkerBinding.from_surface(marker_faces, bary / bary.sum(1, keepdims=True), np.full(12, 0.1))
    c, s = np.cos(CREATURE_TURN), np.sin(CREATURE_TURN)
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    world = CREATURE_SCALE * poses @ R.T + CREATURE_AT  # (T, V, 3) metres
    x = np.array([surface_points(X, faces, binding) for X in poses])
    x = CREATURE_SCALE * x @ R.T + CREATURE_AT + rng.normal(0.0, 0.0005, x.shape)
    labels = [f"m{i + 1:02d}" for i in range(12)]
    take = MarkerTake(labels=labels, positions=x, rate=30.0, units="m")
    # pins: markers 1, 6 and 12 to the vertex of their triangle nearest to them
    pins = {labels[i]: int(faces[marker_faces[i], np.argmax(bary[i])]) for i in CREATURE_PINS}
    return {"faces": faces, "basis": shapes[0][0], "training": training, "world": world, "take": take,
            "pin_labels": np.array(list(pins)), "pin_vertices": np.array(list(pins.values())),
            "rotation": R, "location": CREATURE_AT, "scale": CREATURE_SCALE}
