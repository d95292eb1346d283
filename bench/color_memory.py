"""Memory of the default 12 Mpx colour transfer of one source tree: the peak traced by
tracemalloc during a second (warm) call, and the whole process's maximum resident set
(inputs, libraries and compiled kernels included), against issue 27's 1 GB.

Usage: ``cpu run env OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1 .venv/bin/python
bench/color_memory.py ROOT`` (ROOT the checkout to measure).
"""

import resource
import sys
import tracemalloc

root = sys.argv[1]
sys.path.insert(0, root)
sys.path.insert(0, root + "/bench")

from color import upscale  # noqa: E402
from skimage import data  # noqa: E402

from solvers.color import color_transfer  # noqa: E402

src, tgt = upscale(data.astronaut()), upscale(data.coffee())
color_transfer([src, tgt], [0, 1], recolor=[0])
tracemalloc.start()
color_transfer([src, tgt], [0, 1], recolor=[0])
peak = tracemalloc.get_traced_memory()[1]
rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024  # Linux: KiB
print(f"peak traced {peak / 2**20:.1f} MiB; max RSS {rss / 2**20:.0f} MiB; load "
      f"{open('/proc/loadavg').read().split()[0]}")
