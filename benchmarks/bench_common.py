"""Helpers shared by the benchmark scripts: where the shared meshes are, and what machine ran them.

Every benchmark prints one JSON object whose ``"machine"`` entry comes from
:func:`machine_info`, so results from different scripts can be compared.
"""

import os
import platform
import resource
import time

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


def reference_workload_seconds(repeats=3):
    """CPU seconds of a fixed workload (the best of ``repeats``): the machine's speed, comparable between runs.

    A sparse LU factorization and solve of the 5-point Laplacian on a 200 x 200 grid (SciPy's SuperLU) and
    thirty 256 x 256 matrix products (one BLAS thread with ``OPENBLAS_NUM_THREADS=1``): the kinds of work
    the benchmarks time.  Two machines of the same CPU name can differ several times in speed (clock, host
    load, virtualization); a run's figures scale with this number.  About 0.1 s on a 2-core AMD EPYC.

    Examples
    --------
    >>> reference_workload_seconds(repeats=1) > 0
    True
    """
    import numpy as np
    import scipy.sparse as sp
    from scipy.sparse.linalg import splu

    n = 200
    d = sp.diags([-1.0, 2.0, -1.0], [-1, 0, 1], shape=(n, n))
    lap = (sp.kron(d, sp.identity(n)) + sp.kron(sp.identity(n), d)).tocsc()
    rhs = np.ones(n * n)
    a = np.random.default_rng(0).standard_normal((256, 256))
    best = np.inf
    for _ in range(repeats):
        t = time.process_time()
        splu(lap).solve(rhs)
        b = a
        for _ in range(30):
            b = a @ b
            b /= np.abs(b).max()
        best = min(best, time.process_time() - t)
    return round(best, 4)


def cache_dir(name):
    """A folder for results a benchmark computes once and reads again on this machine (made if missing):
    ``$XDG_CACHE_HOME/lacore-benchmarks/<name>`` (``~/.cache/...`` without the variable)."""
    root = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    path = os.path.join(root, "lacore-benchmarks", name)
    os.makedirs(path, exist_ok=True)
    return path


def _status_kb(field):
    """A field of ``/proc/self/status`` in KiB, or None where there is none."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith(field + ":"):
                    return int(line.split()[1])
    except OSError:
        pass
    return None


def peak_rss_growth():
    """A function giving the growth of the peak resident memory since this call, in KiB. On Linux the peak is reset
    to the present resident memory (``/proc/self/clear_refs``) and read from ``VmHWM``, so that a peak before this
    call does not hide it; elsewhere it is the growth of the process' peak (``ru_maxrss``)."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        rss = _status_kb("VmRSS")
        if rss is not None and _status_kb("VmHWM") is not None:
            return lambda: _status_kb("VmHWM") - rss
    except OSError:
        pass
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return lambda: resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - peak


def machine_info(**extra):
    """Platform, CPU, core count, load, library versions and :func:`reference_workload_seconds`
    (plus ``extra`` entries)."""
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
    info["reference_workload_seconds"] = reference_workload_seconds()
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
