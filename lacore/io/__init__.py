"""Files: triangle meshes, point caches, and the one atomic writer every output goes through.

* :mod:`.meshes` -- :func:`load_mesh` / :func:`save_mesh` (PLY, OBJ, OFF, STL) without
  merging or reordering vertices.
* :mod:`.point_cache` -- PC2 vertex animations (:func:`write_pc2`, :func:`read_pc2`), the
  format Blender's Mesh Cache modifier plays.
* :mod:`.atomic` -- :func:`atomic_write` and :func:`save_npz_atomic`: a failed or interrupted
  write leaves the previous file intact.
* :mod:`.npz` -- :func:`open_npz` and :func:`read_array`: ``.npz`` archives read without
  pickles, with one-line errors naming the file.

Marker takes (C3D, TRC) are read by :mod:`lacore.markers.io`.
"""

from .atomic import atomic_write, check_writable, npz_path, save_npz_atomic
from .npz import open_npz, read_array
from .meshes import SUPPORTED_EXTENSIONS, load_mesh, save_mesh
from .point_cache import HEADER_BYTES, PointCacheError, read_pc2, write_pc2

__all__ = ["atomic_write", "save_npz_atomic", "npz_path", "check_writable", "open_npz", "read_array",
           "load_mesh", "save_mesh", "SUPPORTED_EXTENSIONS",
           "PointCacheError", "HEADER_BYTES", "write_pc2", "read_pc2"]
