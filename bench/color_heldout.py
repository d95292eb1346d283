"""Pairs held out from every choice of the colour defaults (none of them is in bench/color.py):
ours (default) against every peer of bench/color.py, W2 and structure, one line per pair.

Usage: `cpu run env OPENBLAS_NUM_THREADS=1 .venv/bin/python bench/color_heldout.py`
(quality only: the load does not change the figures, it is printed for the record).
"""
import importlib.util
import pathlib

_spec = importlib.util.spec_from_file_location(
    "color_bench", pathlib.Path(__file__).with_name("color.py"))
cb = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(cb)

PAIRS = [("astronaut", "hubble_deep_field"), ("stereo_motorcycle", "chelsea"),
         ("retina", "coffee"), ("hubble_deep_field", "rocket"),
         ("coffee", "immunohistochemistry"), ("colorwheel", "astronaut"),
         ("chelsea", "retina"), ("rocket", "stereo_motorcycle")]
HM = "color-matcher hm-mvgd-hm"


def scores(src, tgt) -> dict[str, tuple[float, float, float]]:
    """(W2, SSIM, grad) of ours and of every peer on one pair."""
    th = cb.ab_histogram(cb.rgb_to_lab(tgt)[..., 1:], cb.BINS)
    return {m: (cb.coarse_w2(out := cb.METHODS[m](src, tgt), th), *cb.structure(out, src))
            for m in [cb.OURS, *cb.PEERS]}


def main() -> None:
    print("load", cb.loadavg())
    for s, t in PAIRS:
        res = scores(cb.image(s), cb.image(t))
        best = min(cb.PEERS, key=lambda m: res[m][0])
        ours, hm = res[cb.OURS], res[HM]
        met = ours[0] <= res[best][0] and ours[1] >= hm[1] and ours[2] >= hm[2]
        print(f"{s}->{t}: ours W2 {ours[0]:.2f} vs best peer {res[best][0]:.2f} ({best}); "
              f"SSIM {ours[1]:.3f} vs hm {hm[1]:.3f}; grad {ours[2]:.3f} vs hm {hm[2]:.3f}; "
              f"{'MET' if met else 'NOT MET'}", flush=True)
    print("load", cb.loadavg())


if __name__ == "__main__":
    main()
