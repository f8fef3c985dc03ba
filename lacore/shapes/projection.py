"""Projection of lengths and angles onto the admissible set (thesis 4.2, Definitions 4.3 and 4.4).

Working in the ambient space ``R^{2E}`` (e.g. linear interpolation or
extrapolation of lengths and angles, section 4.2) produces vectors ``z~`` that
are in general not admissible.  A projection maps them back onto ``Z``:

* energy-based projection (Def. 4.3, (4.7)), the default::

      P_Z^W[z~] = Z[ argmin_X W[z~, Z[X]] ]

  i.e. ``Z`` of the Gauss-Newton reconstruction (``method="gn"``);
* projection by reconstruction (Def. 4.4, (4.8)) for any other reconstruction
  method ``R``: ``P_Z^R[z~] = Z[R[z~]]``.

For admissible ``z`` both return ``z`` up to round-off (``P_Z[z] = z``).
"""

from ..geometry.lengths_angles import lengths_and_angles
from ..reconstruction import reconstruct

__all__ = ["project"]


def project(z, topology, reference_vertices, method="gn", **reconstruct_kw):
    """Project lengths and angles onto the admissible set, ``P_Z[z~] = Z[R[z~]]`` (4.7), (4.8).

    Parameters
    ----------
    z : (2E,) array_like
        Lengths and angles ``z~`` to project.
    topology : MeshTopology
    reference_vertices : (V, 3) array_like
        Reference mesh of the reconstruction (weights of ``W_q``, start).
    method : str
        Reconstruction method, see :func:`lacore.reconstruction.reconstruct`;
        ``"gn"`` gives the energy-based projection (Def. 4.3).
    **reconstruct_kw
        Keyword arguments of :func:`~lacore.reconstruction.reconstruct`
        (``settings``, ``options``, ``hybrid``, ``initial_vertices``, ``context`` ...).

    Returns
    -------
    z_projected : (2E,) ndarray
        Admissible lengths and angles ``Z[R[z~]]``.
    result : ReconstructionResult
        The reconstruction (its ``vertices`` immerse ``z_projected``).

    Examples
    --------
    The average of the lengths and angles of a bent and a twisted bar is no mesh's; its projection is:

    >>> import numpy as np
    >>> from lacore import MeshTopology, lengths_and_angles
    >>> from lacore.samples.bar import bar_mesh, bar_pose
    >>> X, faces = bar_mesh(n_along=4, n_side=1)   # a closed box bar, 22 vertices
    >>> topo = MeshTopology.from_faces(faces)
    >>> from lacore import euler_integrability_map, project
    >>> bent, twisted = bar_pose(X, 0.5, 0.0), bar_pose(X, 0.0, 0.5)
    >>> z_mid = 0.5 * (lengths_and_angles(bent, topo) + lengths_and_angles(twisted, topo))
    >>> round(float(np.abs(euler_integrability_map(z_mid, topo)).max()), 4)
    0.0021
    >>> z_proj, result = project(z_mid, topo, X)
    >>> result.success, bool(np.abs(euler_integrability_map(z_proj, topo)).max() < 1e-10)
    (True, True)
    """
    result = reconstruct(z, topology, reference_vertices, method=method, **reconstruct_kw)
    return lengths_and_angles(result.vertices, topology), result
