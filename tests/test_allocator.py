"""The allocator keeps the numerics' large temporaries instead of faulting them in anew."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

CHURN = """
import resource, sys
import numpy as np
if sys.argv[1] == "kept":
    from furnace_model.allocator import keep_freed_blocks
    keep_freed_blocks()
keep = [np.ones(1 << 20)]  # a block beside them, as the fit's own arrays are
for i in range(41):
    if i == 1:  # the first iteration grows the heap
        before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    a = np.ones(1 << 20)  # 8 MB, made and freed as an iteration's Jacobian is
    b = np.ones(1 << 19)
    del a, b
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""
PAGES = 40 * (3 << 20) // 4096
"""Pages the loop touches: each faulted in anew when the blocks are handed back."""


def faults(mode: str) -> int:
    # Dask's nanny starts its workers so: glibc's sliding threshold then stays at 128 KiB
    env = {**os.environ, "MALLOC_TRIM_THRESHOLD_": "65536"}
    out = subprocess.run([sys.executable, "-c", CHURN, mode], capture_output=True, text=True,
                         env=env, timeout=60, check=True)
    return int(out.stdout)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's allocator")
def test_the_numerics_large_temporaries_are_reused_not_faulted_in_again():
    assert faults("plain") > PAGES // 2  # the failure this guards against is there to see
    assert faults("kept") < PAGES // 20
