"""The shape mixer: nonlinear blends of shape keys in lengths and angles, in real time.

* :mod:`.mixer` -- :class:`ShapeMixer` (build, mix, save, load; :func:`~.mixer.mixer_bytes`), :class:`MixerOptions`,
  :class:`MixResult`, the blend of targets :func:`blend_targets` (keys relative to another key and masked by vertex
  groups: :func:`key_directions`, :func:`edge_masks`), the keys' validation :func:`check_keys`, :func:`check_masks`,
  :func:`check_key_count`;
* :mod:`.subspace` -- the reduced space (keys, derivatives of the projection, chord vectors);
* :mod:`.reduced` -- the reduced energy on a weighted subset of edges and its solver;
* :mod:`.cubature` -- the choice of that subset (greedy non-negative least squares);
* :mod:`.local` -- the local correction: one full Gauss-Newton step on the few vertices the space misses;
* :mod:`.files` -- the layout of mixer files;
* :mod:`.path` -- in-betweens of two keys by a reduced model of their path (:func:`path_inbetweens`).
"""

from .mixer import (FORMAT, FORMAT_VERSION, MIN_LENGTH_RATIO, MixerError, MixerOptions, MixResult, ShapeMixer,
                    blend_targets, check_key_count, check_keys, check_masks, edge_masks, key_directions)
from .path import PathOptions, PathResult, path_inbetweens

__all__ = ["ShapeMixer", "MixerOptions", "MixResult", "MixerError", "blend_targets", "check_keys", "check_masks",
           "check_key_count",
           "edge_masks", "key_directions", "MIN_LENGTH_RATIO",
           "FORMAT", "FORMAT_VERSION", "PathOptions", "PathResult", "path_inbetweens"]
