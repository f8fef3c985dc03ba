"""Helpers shared by the benchmark scripts: where the shared meshes are, and what machine ran them.

Every benchmark prints one JSON object whose ``"machine"`` entry comes from
:func:`machine_info`, so results from different scripts can be compared.
"""

import os
import platform

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def shared_meshes_dir():
    """``shared/data/meshes`` beside the repository (``LACORE_SHARED_DATA`` overrides)."""
    env = os.environ.get("LACORE_SHARED_DATA")
    path = os.path.abspath(env if env else os.path.join(REPO, "..", "shared", "data"))
    return path if os.path.basename(path) == "meshes" else os.path.join(path, "meshes")


def cpu_model():
    """CPU model name from /proc/cpuinfo (or the platform's processor string)."""
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def machine_info(**extra):
    """Platform, CPU, core count, load and library versions (plus ``extra`` entries)."""
    import numpy
    import scipy

    try:
        import cvxopt
        cvx = cvxopt.__version__
    except ImportError:
        cvx = None
    info = {"platform": platform.platform(), "cpu": cpu_model(), "cpu_count": os.cpu_count(),
            "python": platform.python_version(), "numpy": numpy.__version__, "scipy": scipy.__version__,
            "cvxopt": cvx, "threads": {k: os.environ.get(k) for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS")}}
    try:
        info["load_average"] = [round(x, 2) for x in os.getloadavg()]
    except OSError:  # pragma: no cover - not available on Windows
        pass
    info.update(extra)
    return info


def emit(result, path=None):
    """Print ``result`` as one indented JSON object and, with ``path``, write the same text there."""
    import json

    text = json.dumps(result, indent=1)
    print(text)
    if path:
        with open(path, "w") as fh:
            fh.write(text)
