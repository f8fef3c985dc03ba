#!/usr/bin/env python3
"""Run a command with NumPy and OpenBLAS on other compute kernels than this CPU would pick.

Floating-point results differ in their last bits between SIMD paths (AVX-512, AVX2, SSE) and between
OpenBLAS core types, and a greedy choice or an iteration count can change with them.  ``make test`` runs
the tests marked ``numerics`` a second time under this script, so that a dependence on the CPU shows on
the machine where a test is written, not on the next one.

* ``NPY_DISABLE_CPU_FEATURES``: every SIMD feature NumPy dispatches to at run time and this CPU has
  (computed from what this NumPy reports, so the same command works on CPUs with and without AVX-512,
  under NumPy 1.x names such as ``AVX2`` and 2.x names such as ``X86_V3``); baseline features cannot
  be disabled and are left alone.
* ``OPENBLAS_CORETYPE``: an older core than any current default (x86-64: ``Sandybridge``, AVX without
  FMA, or ``Nehalem`` on a CPU without AVX; ARM64: ``ARMV8``), read by every OpenBLAS in the process
  (NumPy's, SciPy's, CVXOPT's).

Variables already set in the environment are kept.  The choice is printed as one line on stderr.

usage: python scripts/other_kernels.py COMMAND [ARG ...]
"""

import os
import platform
import sys


def numpy_features():
    """(available, dispatched, baseline) CPU feature names of the NumPy this interpreter imports."""
    try:
        from numpy._core import _multiarray_umath as umath  # NumPy >= 2
    except ImportError:
        from numpy.core import _multiarray_umath as umath  # NumPy 1.x
    available = {name for name, on in umath.__cpu_features__.items() if on}
    return available, list(umath.__cpu_dispatch__), set(umath.__cpu_baseline__)


def kernel_environment(machine=None, features=None):
    """The variables selecting the other kernels: ``{"NPY_DISABLE_CPU_FEATURES": ..., "OPENBLAS_CORETYPE": ...}``.

    ``machine`` (``platform.machine()``) and ``features`` (as :func:`numpy_features` returns them) can be
    given for testing.
    """
    available, dispatched, baseline = numpy_features() if features is None else features
    disable = [f for f in dispatched if f in available and f not in baseline]
    machine = (machine or platform.machine()).lower()
    env = {}
    if disable:
        env["NPY_DISABLE_CPU_FEATURES"] = ",".join(disable)
    if machine in ("x86_64", "amd64", "i686", "i386", "x86"):
        env["OPENBLAS_CORETYPE"] = "Sandybridge" if "AVX" in available or "X86_V3" in available else "Nehalem"
    elif machine in ("aarch64", "arm64"):
        env["OPENBLAS_CORETYPE"] = "ARMV8"
    return env


def main(argv):
    if not argv or argv[0] in ("-h", "--help"):
        print(__doc__)
        return 0 if argv else 2
    env = dict(os.environ)
    chosen = {k: v for k, v in kernel_environment().items() if k not in env}
    env.update(chosen)
    shown = " ".join(f"{k}={env[k]}" for k in ("NPY_DISABLE_CPU_FEATURES", "OPENBLAS_CORETYPE") if k in env)
    print(f"other kernels: {shown or '(none available on this machine)'}", file=sys.stderr, flush=True)
    os.execvpe(argv[0], argv, env)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
