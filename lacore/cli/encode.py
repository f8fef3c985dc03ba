"""``lacore encode MESH [-o OUT.npz] [--json]``: a mesh as edge lengths and dihedral angles.

Writes (with ``-o``) an ``.npz`` with keys ``vertices, faces, edges, lengths,
angles, z, integrability_violation`` (``.npz`` is appended to a name without
it; the name reported is the file written; written atomically); ``--json``
prints one JSON object with counts, ranges, timings and the integrability of
the lengths and angles (:func:`lacore.integrability.check_integrability`, all of
Theorem 3.2): ``integrable``, ``max_integrability_violation`` split into
``local`` (largest ``|tr I_v - 3|`` at a vertex), ``holonomy`` (largest angle,
radians, by which the frames fail to close around a hole or handle) and
``translation`` (largest gap around a hole or handle, relative to the loop's
length), their ``integrability_tolerances``, ``genus`` and ``boundary_loops``
per component, and ``loops``: every loop of the homology basis (its label,
kind, boundary loop, edge count, holonomy, translation and whether it closes).
Numerically degenerate triangles
(:func:`lacore.geometry.lengths_angles.check_nondegenerate`) and coordinates
that float64 cannot hold faithfully (subnormal, or edge lengths beyond its range:
:func:`lacore.geometry.lengths_angles.check_float_range`) exit with code 2.  Lengths,
angles and the integrability checks are computed scale-free (any other magnitude of
coordinates works: :func:`lacore.geometry.lengths_angles.safe_scaled`).
"""

import time

import numpy as np

from ..io.atomic import check_writable, npz_path, save_npz_atomic
from ..errors import InputError, MeshError, format_indices
from ..integrability import check_integrability, homology_basis
from ..geometry.lengths_angles import check_nondegenerate, lengths_and_angles
from ..io.meshes import load_mesh
from ..geometry.topology import MeshTopology
from .common import EXIT_OK, json_float, print_json

__all__ = ["HELP", "configure", "run", "encode_mesh"]

HELP = "encode a mesh as edge lengths and dihedral angles"


def configure(parser):
    """Declare the arguments of ``lacore encode``."""
    parser.add_argument("mesh", metavar="MESH", help="triangle mesh (.ply, .obj, .off, .stl)")
    parser.add_argument("-o", "--output", metavar="OUT.npz",
                        help="write faces, edges, vertices, lengths, angles (and z) to this .npz file")
    parser.add_argument("--json", action="store_true", help="print one JSON object with counts and timings")


def encode_mesh(vertices, faces):
    """Encode one mesh: returns ``(topology, z, violation, timings, check)``.

    ``violation`` is ``|tr I_v - 3|`` per vertex, ``check`` the
    :class:`~lacore.integrability.checks.IntegrabilityCheck` of ``z``.
    """
    t0 = time.perf_counter()
    topology = MeshTopology.from_faces(faces, n_vertices=len(vertices))
    vertices = check_nondegenerate(vertices, topology)  # shape, NaN/inf, zero-area triangles
    t1 = time.perf_counter()
    z = np.asarray(lengths_and_angles(vertices, topology), dtype=np.float64)
    t2 = time.perf_counter()
    homology_basis(topology)
    t3 = time.perf_counter()
    check = check_integrability(z, topology)
    violation = np.asarray(check.local, dtype=np.float64)
    t4 = time.perf_counter()
    bad = np.flatnonzero(~np.isfinite(z))
    if bad.size:  # cannot happen after check_nondegenerate; never write or report NaN with exit 0
        raise MeshError(f"lengths or angles are not finite at edges {format_indices(bad % topology.n_edges)}")
    bad = np.flatnonzero(~np.isfinite(violation))
    if bad.size:
        raise MeshError(f"the integrability violation is not finite at {format_indices(bad)}: "
                        "numerically degenerate triangles")
    timings = {"topology": t1 - t0, "lengths_angles": t2 - t1, "homology": t3 - t2, "integrability": t4 - t3}
    return topology, z, violation, timings, check


def run(args):
    """Run ``lacore encode``; returns the exit code (errors are raised for :func:`lacore.cli.main`)."""
    start = time.perf_counter()
    if args.output is not None and not args.output.strip():
        raise InputError("-o/--output is empty: give a file name (or leave -o out to write nothing)")
    if args.output:
        check_writable(npz_path(args.output))
    vertices, faces = load_mesh(args.mesh)
    t_load = time.perf_counter() - start
    try:
        topology, z, violation, timings, check = encode_mesh(vertices, faces)
    except MeshError as exc:
        raise MeshError(f"{args.mesh}: {exc}") from None
    E = topology.n_edges
    lengths, angles = z[:E], z[E:]
    t_save, written = 0.0, None
    if args.output:
        t = time.perf_counter()
        written = save_npz_atomic(args.output, vertices=vertices, faces=topology.faces, edges=topology.edges,
                                  lengths=lengths, angles=angles, z=z, integrability_violation=violation)
        t_save = time.perf_counter() - t
    seconds = time.perf_counter() - start
    integrability = check.summary()
    summary = {
        "command": "encode",
        "mesh": args.mesh,
        "output": written,
        "vertices": int(topology.n_vertices),
        "edges": int(E),
        "faces": int(topology.n_faces),
        "boundary_edges": int(np.count_nonzero(topology.is_boundary_edge)),
        "boundary_vertices": len(topology.boundary_vertices),
        "min_length": json_float(lengths.min()),
        "max_length": json_float(lengths.max()),
        "max_abs_angle": json_float(np.abs(angles).max()),
        "integrable": integrability["integrable"],
        "max_integrability_violation": integrability["max_integrability_violation"],
        "integrability_tolerances": integrability["tolerances"],
        "genus": integrability["genus"],
        "boundary_loops": integrability["boundary_loops"],
        "loops": integrability["loops"],
        "seconds": seconds,
        "timings": {"load": t_load, **timings, "save": t_save},
    }
    if args.json:
        print_json(summary)
    else:
        print(f"{args.mesh}: {summary['vertices']} vertices, {E} edges ({summary['boundary_edges']} on the "
              f"boundary), {summary['faces']} faces")
        print(f"  lengths in [{lengths.min():.6g}, {lengths.max():.6g}], max |angle| {np.abs(angles).max():.6g} rad")
        print(f"  {check.describe()}")
        if args.output:
            print(f"  wrote {written}")
        print(f"  {seconds:.3f} s")
    return EXIT_OK
