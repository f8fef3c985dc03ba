"""scripts/other_kernels.py: the kernel choice of the second run of the `numerics` tests in `make test`."""

import importlib.util
import os
import subprocess
import sys

from conftest import REPO

spec = importlib.util.spec_from_file_location("other_kernels", REPO / "scripts" / "other_kernels.py")
other_kernels = importlib.util.module_from_spec(spec)
spec.loader.exec_module(other_kernels)

NUMPY1_DISPATCH = ["SSSE3", "SSE41", "POPCNT", "SSE42", "AVX", "F16C", "FMA3", "AVX2", "AVX512F", "AVX512CD",
                   "AVX512_SKX", "AVX512_CLX", "AVX512_CNL", "AVX512_ICL"]


def test_disables_what_this_cpu_has_and_numpy_can_disable():
    avx2 = {"SSE", "SSE2", "SSE3", "SSSE3", "SSE41", "POPCNT", "SSE42", "AVX", "F16C", "FMA3", "AVX2"}
    avx512 = avx2 | {"AVX512F", "AVX512CD", "AVX512_SKX", "AVX512_CLX"}
    baseline = {"SSE", "SSE2", "SSE3"}
    env = other_kernels.kernel_environment("x86_64", (avx2, NUMPY1_DISPATCH, baseline))
    assert env == {"NPY_DISABLE_CPU_FEATURES": "SSSE3,SSE41,POPCNT,SSE42,AVX,F16C,FMA3,AVX2",
                   "OPENBLAS_CORETYPE": "Sandybridge"}
    env = other_kernels.kernel_environment("x86_64", (avx512, NUMPY1_DISPATCH, baseline))
    assert env["NPY_DISABLE_CPU_FEATURES"].endswith("AVX2,AVX512F,AVX512CD,AVX512_SKX,AVX512_CLX")
    # NumPy 2 groups: only what it dispatches to (never the baseline)
    env = other_kernels.kernel_environment("x86_64", ({"X86_V2", "X86_V3", "AVX"}, ["X86_V3", "X86_V4"], {"X86_V2"}))
    assert env["NPY_DISABLE_CPU_FEATURES"] == "X86_V3"
    env = other_kernels.kernel_environment("x86_64", ({"SSE", "SSE2", "SSE3"}, NUMPY1_DISPATCH, baseline))
    assert env == {"OPENBLAS_CORETYPE": "Nehalem"}  # nothing to disable; an old core without AVX
    assert other_kernels.kernel_environment("aarch64", ({"NEON", "ASIMD"}, ["ASIMDHP"], {"NEON"})) == {
        "OPENBLAS_CORETYPE": "ARMV8"}


def test_the_chosen_kernels_are_the_ones_numpy_runs():
    code = ("import os\ntry:\n    from numpy._core._multiarray_umath import __cpu_features__ as f\n"
            "except ImportError:\n    from numpy.core._multiarray_umath import __cpu_features__ as f\n"
            "off = [x for x in os.environ.get('NPY_DISABLE_CPU_FEATURES', '').split(',') if x]\n"
            "print(sum(f[x] for x in off), len(off))\n")
    env = {k: v for k, v in os.environ.items() if k not in ("NPY_DISABLE_CPU_FEATURES", "OPENBLAS_CORETYPE")}
    proc = subprocess.run([sys.executable, str(REPO / "scripts" / "other_kernels.py"), sys.executable, "-W", "error",
                           "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr.startswith("other kernels: ")
    still_on, disabled = map(int, proc.stdout.split())
    assert still_on == 0  # every disabled feature is off in the child (and NumPy did not warn: -W error)
