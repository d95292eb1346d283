"""The default entropic regularization on coarse ab grids (``default_gamma``: 16, or twice
the smallest the grid resolves below 17 nodes) against other choices, in the barycentric mode
(where gamma acts), alphas (0, 1): W2 between the output's ab histogram and the target's
(bench/color.py's exact-LP score, 32^2 bins), for several grid sizes and pairs.  16 is
refused below 11 nodes (it does not resolve the grid); ``min`` is the smallest gamma the
grid resolves (h^2 / 36); h^2 the squared node spacing (a blur of 0.7 nodes).

Usage: ``cpu run env OPENBLAS_NUM_THREADS=1 .venv/bin/python bench/color_coarse_gamma.py``.
"""

import pathlib
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

import color as cb  # noqa: E402

from solvers.color import color_transfer  # noqa: E402
from solvers.color.chrominance import AbGrid  # noqa: E402
from solvers.color.transfer import default_gamma  # noqa: E402
from solvers.errors import InputError  # noqa: E402
from solvers.validation import GAMMA_RESOLUTION  # noqa: E402

PAIRS = [("coffee", "chelsea"), ("astronaut", "coffee"), ("rocket", "astronaut")]
GRIDS = [8, 12, 16, 24, 32, 48, 64]


def score(src, tgt, th, bins, gamma) -> str:
    try:
        r = color_transfer([src, tgt], [0, 1], mode="barycentric", bins=bins, gamma=gamma,
                           recolor=[0])
    except InputError:
        return "refused"
    return f"{cb.coarse_w2(r.images[0][0], th):.2f}"


def main() -> None:
    print("load", cb.loadavg())
    print("| pair | bins | default (its gamma) | 16 | 8 min | h^2 | split default |")
    print("|---|---|---|---|---|---|---|")
    for s, t in PAIRS:
        src, tgt = cb.image(s), cb.image(t)
        th = cb.ab_histogram(cb.rgb_to_lab(tgt)[..., 1:], cb.BINS)
        split = cb.coarse_w2(color_transfer([src, tgt], [0, 1], recolor=[0]).images[0][0], th)
        for bins in GRIDS:
            h2 = AbGrid(bins).spacing ** 2
            low = GAMMA_RESOLUTION * h2
            g = default_gamma(bins)
            print(f"| {s}→{t} | {bins} | {score(src, tgt, th, bins, None)} ({g:.1f}) "
                  f"| {score(src, tgt, th, bins, 16.0)} | {score(src, tgt, th, bins, 8 * low)} "
                  f"| {score(src, tgt, th, bins, h2)} | {split:.2f} |", flush=True)
    print("load", cb.loadavg())


if __name__ == "__main__":
    main()
