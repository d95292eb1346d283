"""Speed of color transfer at 12 megapixels, ours and color-matcher's peers in one run.

The pair of ``bench/color.py`` (astronaut -> coffee, both upscaled to 4000 × 3000), arrays
in -> array out, warm (best of ``--repeats`` after a first run that compiles / warms
caches); peak traced memory (tracemalloc) of the first run; numba threads as set by
``NUMBA_NUM_THREADS`` (2 on the bench machines), BLAS pinned to 1 thread; stages of the
last run of each otgeo setting.  Run it under ``cpu bench``.

Usage: ``.venv/bin/python bench/color_speed.py [--repeats N] [--out FILE]``; writes
``bench/results/color_speed.md`` by default.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import tracemalloc
from pathlib import Path

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import numba  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from color import color_matcher, loadavg, upscale  # noqa: E402
from skimage import data  # noqa: E402

from solvers.color import color_transfer, transfer  # noqa: E402


def otgeo(constants=None, **kw):
    """Our transfer with keyword options, and module constants of solvers.color.transfer
    set for the duration of the call (``constants``)."""
    def run(src, tgt):
        saved = {k: getattr(transfer, k) for k in constants or {}}
        for k, v in (constants or {}).items():
            setattr(transfer, k, v)
        try:
            r = color_transfer([src, tgt], [0.0, 1.0], recolor=[0], **kw)
        finally:
            for k, v in saved.items():
                setattr(transfer, k, v)
        run.timings = r.timings
        return r.images[0][0]

    return run


METHODS = {
    "otgeo split (default)": otgeo(),
    "otgeo split, no within-node remap": otgeo({"WITHIN_NODE_SUBBINS": 0}),
    "color-matcher mkl": color_matcher("mkl"),
    "color-matcher hm-mvgd-hm": color_matcher("hm-mvgd-hm"),
}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", default=str(ROOT / "bench" / "results" / "color_speed.md"))
    args = ap.parse_args()
    src, tgt = upscale(data.astronaut()), upscale(data.coffee())
    lines = ["# Color transfer speed at 12 Mpx (bench/color_speed.py)\n",
             f"astronaut → coffee at 4000 × 3000, arrays in → array out; {os.cpu_count()} "
             f"cores shared; numba threads {numba.get_num_threads()}, BLAS 1 thread; warm: "
             f"best of {args.repeats} after a first run; peak traced memory (tracemalloc) of "
             "the first run.\n",
             "| method | warm s | ratio to otgeo default | peak traced MiB | load before/after | "
             "stages of the last run (s) |",
             "|---|---|---|---|---|---|"]
    base = None
    for name, fn in METHODS.items():
        la = loadavg()
        tracemalloc.start()
        fn(src, tgt)
        peak = tracemalloc.get_traced_memory()[1] / 2**20
        tracemalloc.stop()
        times = []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            fn(src, tgt)
            times.append(time.perf_counter() - t0)
        best = min(times)
        base = base or best
        stages = ", ".join(f"{k} {v:.3f}" for k, v in getattr(fn, "timings", {}).items())
        row = (f"| {name} | {best:.2f} | {best / base:.2f} | {peak:.0f} | {la} / {loadavg()} | "
               f"{stages} |")
        print(row, [round(t, 3) for t in times], flush=True)
        lines.append(row)
    Path(args.out).write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
