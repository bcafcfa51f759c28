"""Copy now, off the servo path, the memory pages the loop's process shares copy-on-write with the
recorder's forked writer.

After ``fork`` every page of the Python heap, numpy arrays and MuJoCo's buffers belongs to both
processes until one writes it; the loop's first write to each then takes a page fault and a copy
inside a tick (measured at 1 kHz: 12 to 66 faults and 0.1 to 0.9 ms in the first recorder and
guard calls). ``copy_shared_pages`` finds the pages still shared (``/proc/self/pagemap``: present,
not exclusively mapped) and has the kernel copy them in one call per run of pages
(``madvise(MADV_POPULATE_WRITE)``, Linux 5.14), the prefaulting a real-time process does before its
loop. Pages never touched stay untouched (no memory is added beyond what the writes would copy).
Elsewhere (another OS, an older kernel, no pagemap) it does nothing and says so.
"""

from __future__ import annotations

import ctypes
import os
import sys

import numpy as np

MADV_POPULATE_WRITE = 23  # linux/mman.h
PRESENT, EXCLUSIVE = np.uint64(1 << 63), np.uint64(1 << 56)  # pagemap entry bits
PAGE = os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else 4096
BLOCK = 1 << 16  # pagemap entries read at a time (512 KB)


def copy_shared_pages() -> int | None:
    """Copy every page this process shares copy-on-write with a child; the pages copied, None where the
    OS cannot say or do it."""
    if not sys.platform.startswith("linux"):
        return None
    madvise = ctypes.CDLL(None, use_errno=True).madvise
    madvise.argtypes = [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int]
    try:
        with open("/proc/self/maps") as maps:
            regions = [line.split() for line in maps]
        pagemap = os.open("/proc/self/pagemap", os.O_RDONLY)
    except OSError:
        return None
    copied = 0
    try:
        for fields in regions:
            if fields[1] != "rw-p" or (len(fields) > 5 and fields[5].startswith("[v")):
                continue  # shared and read-only mappings take no copy; [vvar] and [vsyscall] are the kernel's
            start, end = (int(x, 16) for x in fields[0].split("-"))
            for first, last in _shared_runs(pagemap, start, end):
                if madvise(start + first * PAGE, (last - first) * PAGE, MADV_POPULATE_WRITE) == 0:
                    copied += last - first
                elif ctypes.get_errno() == 22 and copied == 0:  # EINVAL on the first call: a kernel before 5.14
                    return None
    except OSError:
        return None
    finally:
        os.close(pagemap)
    return copied


def _shared_runs(pagemap: int, start: int, end: int, block: int = BLOCK) -> list[tuple[int, int]]:
    """Runs [first, last) of page indices from ``start`` that are present and not this process's alone
    (the map read ``block`` pages at a time: a mapping may reserve gigabytes it never touches)."""
    runs: list[tuple[int, int]] = []
    total = (end - start) // PAGE
    for offset in range(0, total, block):
        n = min(block, total - offset)
        entries = np.frombuffer(os.pread(pagemap, 8 * n, 8 * (start // PAGE + offset)), dtype=np.uint64)
        shared = ((entries & PRESENT) != 0) & ((entries & EXCLUSIVE) == 0)
        edges = (np.flatnonzero(np.diff(np.concatenate(([0], shared.astype(np.int8), [0])))) + offset).tolist()
        for first, last in zip(edges[::2], edges[1::2]):
            if runs and runs[-1][1] == first:  # a run across two blocks is one run
                first = runs.pop()[0]
            runs.append((first, last))
    return runs
