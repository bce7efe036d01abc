"""Threads of campaign workers: a worker among others traces scans in one thread and gives
IPOPT's OpenBLAS one."""

from __future__ import annotations

import os
import subprocess
import sys


def test_a_worker_among_others_takes_one_blas_and_one_scan_thread():
    code = (
        "import os\n"
        "for k in ('OPENBLAS_NUM_THREADS', 'SECURE3D_SCAN_THREADS'): os.environ.pop(k, None)\n"
        "from secure3d.mapping.scan import scan_threads\n"
        "from secure3d.simulation.campaign_pool import one_thread_each\n"
        "before = scan_threads()\n"
        "one_thread_each(scan_too=False)\n"
        "alone = scan_threads()\n"
        "one_thread_each()\n"
        "print(before, alone, scan_threads(), os.environ['OPENBLAS_NUM_THREADS'])\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False)
    assert out.returncode == 0, out.stderr[-2000:]
    before, alone, after, blas = out.stdout.split()
    cores = len(os.sched_getaffinity(0))
    assert int(alone) == int(before) == max(1, min(4, cores))
    assert (int(after), blas) == (1, "1"), out.stdout
