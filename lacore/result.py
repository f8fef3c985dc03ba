"""The base type of every solver's result (like :class:`scipy.optimize.OptimizeResult`, but a dataclass).

Every long-running lacore entry point returns a subclass of :class:`SolverResult`
(:class:`lacore.reconstruction.ReconstructionResult`,
:class:`lacore.reconstruction.GaussNewtonResult`,
:class:`lacore.shapes.interpolation.InterpolationResult`,
:class:`lacore.shapes.geodesics.GeodesicResult`), complete when returned: no field is
filled in by the caller afterwards.  Fields are attributes; for code written
against ``OptimizeResult`` they can also be read as ``res["name"]``.
"""

from dataclasses import dataclass, field, fields

import numpy as np

__all__ = ["SolverResult", "json_value"]


def json_value(x):
    """A JSON-serializable version of ``x`` (NaN/inf -> None, arrays -> lists, NumPy scalars -> Python)."""
    if isinstance(x, dict):
        return {str(k): json_value(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [json_value(v) for v in x]
    if isinstance(x, np.ndarray):
        return json_value(x.tolist())
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (int, np.integer)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        x = float(x)
        return x if np.isfinite(x) else None
    if x is None or isinstance(x, str):
        return x
    return None  # objects (contexts, trees, nested results): not part of a summary


@dataclass(kw_only=True)
class SolverResult:
    """Outcome of a solver.

    Attributes
    ----------
    success : bool
        Whether the solver finished normally (see the subclass for what that means).
    status : int or (N,) ndarray of int
        Reason code (the subclass documents its table of codes); batch results
        (one solve per frame) hold one code per item.
    message : str
        Why the solver stopped, in words.
    iterations : int or (N,) ndarray of int
        Iterations (per item for batch results).
    timings : dict
        Seconds per phase (``"total"``: the whole call).

    Examples
    --------
    Every solver's result reads like a :class:`scipy.optimize.OptimizeResult` and has a JSON summary:

    >>> import numpy as np
    >>> from lacore import MeshTopology, lengths_and_angles
    >>> from lacore.samples.bar import bar_mesh, bar_pose
    >>> X, faces = bar_mesh(n_along=4, n_side=1)   # a closed box bar, 22 vertices
    >>> topo = MeshTopology.from_faces(faces)
    >>> from lacore import SolverResult, reconstruct
    >>> res = reconstruct(lengths_and_angles(bar_pose(X, 0.5, 0.0), topo), topo, X)
    >>> isinstance(res, SolverResult), res["success"] == res.success
    (True, True)
    >>> summary = res.summary()                      # JSON-ready: no vertex arrays
    >>> "vertices" in summary, summary["status"]
    (False, 1)
    """

    success: bool
    status: int
    message: str
    iterations: int = 0
    timings: dict = field(default_factory=dict)

    #: Fields left out of :meth:`summary` (large arrays, objects).
    _summary_exclude = ()

    def __getitem__(self, name):
        try:
            return getattr(self, name)
        except AttributeError:
            raise KeyError(name) from None

    def get(self, name, default=None):
        """``res[name]`` or ``default`` (``OptimizeResult`` compatibility)."""
        return getattr(self, name, default)

    def keys(self):
        """Field names (``OptimizeResult`` compatibility)."""
        return [f.name for f in fields(self)]

    def __repr__(self):
        lines = [f"{type(self).__name__}("]
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, np.ndarray):
                v = f"<array {v.shape} {v.dtype}>" if v.size > 6 else np.array2string(v, precision=6)
            elif isinstance(v, list) and len(v) > 6:
                head = ", ".join(f"{x:.6g}" if isinstance(x, (int, float)) else type(x).__name__ for x in v[:3])
                v = f"[{head}, ...] ({len(v)} entries)"
            elif isinstance(v, dict) and all(isinstance(b, (int, float)) for b in v.values()):
                v = "{" + ", ".join(f"{a!r}: {b:.4g}" for a, b in v.items()) + "}"
            elif isinstance(v, SolverResult) or (hasattr(v, "__dict__") and not isinstance(v, type)):
                v = f"<{type(v).__name__}>"
            lines.append(f"    {f.name}={v},")
        return "\n".join(lines) + "\n)"

    def summary(self):
        """A JSON-serializable dict of the fields (arrays as lists, NaN/inf as None; objects left out)."""
        out = {}
        for f in fields(self):
            if f.name in self._summary_exclude:
                continue
            v = getattr(self, f.name)
            if isinstance(v, (list, tuple)) and v and isinstance(v[0], SolverResult):
                continue
            if v is not None and json_value(v) is None and not isinstance(v, (float, np.floating)):
                continue  # an object
            out[f.name] = json_value(v)
        return out
