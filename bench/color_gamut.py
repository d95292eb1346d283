"""Gamut-shift variants of the split transfer against the targets of issue 27, on the 20
pairs of bench/color.py and bench/color_heldout.py (``--fresh``: on the 4 validation pairs
chosen before any experiment and never looked at while developing, instead; ``--new``: on
5 more pairs fixed before the chroma-split fix of issue 27 was measured; ``--all``: all 29).

Per pair: W2 at or below the best peer's, SSIM and grad at or above color-matcher
hm-mvgd-hm's (bench/color.py's metrics and peers).  Peer scores are computed once per run.
Variants set module constants of ``solvers.color.transfer`` (listed in ``VARIANTS``).

Usage: `cpu run env OPENBLAS_NUM_THREADS=1 .venv/bin/python bench/color_gamut.py [--fresh]`
(quality only: the load is printed for the record).
"""
import argparse
import importlib.util
import json
import pathlib

from solvers.color import transfer

_here = pathlib.Path(__file__).parent
_spec = importlib.util.spec_from_file_location("color_bench", _here / "color.py")
cb = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(cb)
_spec = importlib.util.spec_from_file_location("color_heldout", _here / "color_heldout.py")
ho = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(ho)

# chosen before any experiment of this file; in neither bench
FRESH = [("immunohistochemistry", "chelsea"), ("astronaut", "retina"),
         ("stereo_motorcycle", "hubble_deep_field"), ("colorwheel", "coffee")]
# chosen before measuring the re-split after the gamut step (branch color27h); in no list above
NEW = [("hubble_deep_field", "stereo_motorcycle"), ("retina", "rocket"), ("coffee", "astronaut"),
       ("immunohistochemistry", "retina"), ("chelsea", "hubble_deep_field")]
VARIANTS = {
    "default": {},
    "strength 1e-4": {"GAMUT_SHIFT_STRENGTH": 1e-4},
    "1e-4, max slope 0.1": {"GAMUT_SHIFT_STRENGTH": 1e-4, "GAMUT_MAX_SLOPE": 0.1},
    "1e-4, max slope 0.25": {"GAMUT_SHIFT_STRENGTH": 1e-4, "GAMUT_MAX_SLOPE": 0.25},
    "1e-5, max slope 0.1": {"GAMUT_SHIFT_STRENGTH": 1e-5, "GAMUT_MAX_SLOPE": 0.1},
    "1e-5, max slope 0.25": {"GAMUT_SHIFT_STRENGTH": 1e-5, "GAMUT_MAX_SLOPE": 0.25},
    "1e-4, max slope 0.5": {"GAMUT_SHIFT_STRENGTH": 1e-4, "GAMUT_MAX_SLOPE": 0.5},
    "1e-4, max slope 0.75": {"GAMUT_SHIFT_STRENGTH": 1e-4, "GAMUT_MAX_SLOPE": 0.75},
    "1e-4, max slope 0.85": {"GAMUT_SHIFT_STRENGTH": 1e-4, "GAMUT_MAX_SLOPE": 0.85},
    "1e-4, max slope 1": {"GAMUT_SHIFT_STRENGTH": 1e-4, "GAMUT_MAX_SLOPE": 1.0},
    # the default before branch color27h (GAMUT_* constants; since then 1e-4, slope 0.85)
    "1e-3, no slope limit": {"GAMUT_SHIFT_STRENGTH": 1e-3, "GAMUT_MAX_SLOPE": float("inf")},
    # the within-node remap (WITHIN_NODE_SUBBINS, on by default since branch color27h)
    "no remap": {"WITHIN_NODE_SUBBINS": 0},
    "1e-4, max slope 0.85, no remap": {"GAMUT_SHIFT_STRENGTH": 1e-4, "GAMUT_MAX_SLOPE": 0.85,
                                       "WITHIN_NODE_SUBBINS": 0},
}


def peers(src, tgt, th, cache=None, key=None):
    """Targets (best peer's W2, hm-mvgd-hm's SSIM and grad); ``cache``: a JSON file of
    them per pair (the peers are deterministic: POT samples with a fixed seed)."""
    path = pathlib.Path(cache) if cache else None
    stored = json.loads(path.read_text()) if path and path.exists() else {}
    if key in stored:
        return tuple(stored[key])
    res = {m: cb.METHODS[m](src, tgt) for m in cb.PEERS}
    res = {m: (cb.coarse_w2(out, th), *cb.structure(out, src)) for m, out in res.items()}
    best = min(cb.PEERS, key=lambda m: res[m][0])
    out = res[best][0], res[ho.HM][1], res[ho.HM][2]
    if path:
        stored = json.loads(path.read_text()) if path.exists() else {}
        path.write_text(json.dumps({**stored, key: out}, indent=1))
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--fresh", action="store_true")
    ap.add_argument("--new", action="store_true")
    ap.add_argument("--all", action="store_true", help="the 20 pairs, --fresh and --new")
    ap.add_argument("--peers-cache", default=None, help="JSON file of the peers' targets")
    ap.add_argument("--variants", nargs="*", default=list(VARIANTS))
    ap.add_argument("--first", nargs="*", default=[], help="pairs s:t to run first")
    ap.add_argument("--only", type=int, default=None, help="stop after this many pairs")
    args = ap.parse_args()
    pairs = (cb.PAIRS + ho.PAIRS + FRESH + NEW if args.all else FRESH if args.fresh
             else NEW if args.new else cb.PAIRS + ho.PAIRS)
    first = [tuple(p.split(":")) for p in args.first]
    pairs = (first + [p for p in pairs if p not in first])[:args.only]
    print("load", cb.loadavg(), flush=True)
    met = {v: 0 for v in args.variants}
    saved = {k: getattr(transfer, k) for v in VARIANTS.values() for k in v}
    for s, t in pairs:
        src, tgt = cb.image(s), cb.image(t)
        th = cb.ab_histogram(cb.rgb_to_lab(tgt)[..., 1:], cb.BINS)
        w2, ssim, grad = peers(src, tgt, th, args.peers_cache, f"{s}->{t}")
        cells = []
        for v in args.variants:
            for k, val in {**saved, **VARIANTS[v]}.items():
                setattr(transfer, k, val)
            out = cb.METHODS[cb.OURS](src, tgt)
            o = (cb.coarse_w2(out, th), *cb.structure(out, src))
            ok = o[0] <= w2 and o[1] >= ssim and o[2] >= grad
            met[v] += ok
            cells.append(f"{v}: {o[0]:.2f}/{o[1]:.3f}/{o[2]:.3f}{'' if ok else ' NOT MET'}")
        print(f"{s}->{t} | targets W2<={w2:.2f} SSIM>={ssim:.3f} grad>={grad:.3f} | "
              + " | ".join(cells), flush=True)
    print("MET per variant:", met, "of", len(pairs))
    print("load", cb.loadavg())


if __name__ == "__main__":
    main()
