"""12 Mpx time of the default colour transfer of one source tree, for side-by-side runs of
two checkouts in the same conditions (bench/color_speed.py's pair, best of 3 after a
warm-up).

Usage: ``cpu bench env OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1 .venv/bin/python
bench/color_speed_default.py ROOT`` (``PYTHONPATH=ROOT``; ROOT the checkout to time).
"""

import sys
import time

root = sys.argv[1]
sys.path.insert(0, root)
sys.path.insert(0, root + "/bench")

from color import upscale  # noqa: E402
from skimage import data  # noqa: E402

import solvers  # noqa: E402
from solvers.color import color_transfer  # noqa: E402

src, tgt = upscale(data.astronaut()), upscale(data.coffee())
color_transfer([src, tgt], [0, 1], recolor=[0])
times = []
for _ in range(3):
    t0 = time.perf_counter()
    r = color_transfer([src, tgt], [0, 1], recolor=[0])
    times.append(time.perf_counter() - t0)
print(solvers.__file__, round(min(times), 3), [round(t, 3) for t in times],
      {k: round(v, 3) for k, v in r.timings.items()}, open("/proc/loadavg").read().split()[0])
