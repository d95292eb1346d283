"""The first color transfer after ``otgeo serve`` starts, against the same request warm
(issue 44, item 3: "a first color transfer on a fresh install within 2x the warm time").

For each scenario a new ``otgeo serve`` (API and one worker, embedded queue, numba's cache
as ``make install`` left it) on a new data directory; then one default color transfer of
two 600 x 800 images (``POST /v1/color-transfers?wait=``, the images in the request) is
timed from submission to its result, then the same request on other images three more
times (warm: the best).

- ``at-start``: the request is sent the moment ``/healthz`` first answers, while the worker
  is still starting and warming its kernels (the worst case a user can meet);
- ``after-warm-up``: sent once the worker's log says its kernels are ready.

    .venv/bin/python bench/first_color_transfer.py [--rounds 3]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import httpx
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "service"))
sys.path.insert(0, str(ROOT))
from liveserver import API, stop_all, wait_for  # noqa: E402

from bench._common import cpu_model, load1  # noqa: E402
from service.operations.color import write_image  # noqa: E402

READY = "color-transfers kernels ready"


def images(seed: int) -> list[bytes]:
    """Two 600 x 800 photographs' stand-ins (8-bit RGB PNG), warm and cool gradients with
    noise: new bytes for every ``seed``, so that no request reuses what an earlier one
    stored or computed."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:600, 0:800] / 800.0
    warm = np.stack([200 + 40 * x, 90 + 80 * y, 40 + 30 * x * y], -1)
    cool = np.stack([40 + 60 * y, 90 + 50 * x, 170 + 60 * y * x], -1)
    return [write_image(np.clip(p + rng.normal(0, 6, p.shape), 0, 255).astype(np.uint8))
            for p in (warm, cool)]


def transfer(client: httpx.Client, pictures: list[bytes]) -> float:
    """Seconds from submission to the result of one default color transfer of ``pictures``."""
    start = time.perf_counter()
    r = client.post("/v1/color-transfers?wait=60", files=[
        ("images", (f"image-{i}.png", data, "image/png")) for i, data in enumerate(pictures)])
    r.raise_for_status()
    assert r.json()["state"] == "succeeded", r.json()
    return time.perf_counter() - start


def scenario(name: str, rounds: int) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        env = {"OTGEO_DATA_DIR": str(Path(tmp) / "data"), "OTGEO_WORKERS": "1",
               "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
        started = time.perf_counter()
        api = API(env, Path(tmp))
        try:
            api.wait_healthy(120)
            healthy = time.perf_counter() - started
            if name == "after-warm-up":
                wait_for(lambda: READY in api.log(10**7), 300, interval=0.2,
                         what="the worker's warm-up")
            with httpx.Client(base_url=api.url, timeout=180) as client:
                first = transfer(client, images(0))
                warm = min(transfer(client, images(1 + i)) for i in range(rounds))
        finally:
            stop_all([api])
    return {"scenario": name, "healthy_s": healthy, "first_s": first, "warm_s": warm,
            "ratio": first / warm}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    print(f"{cpu_model()}; load {load1():.2f}")
    print("| scenario | /healthz after s | first s | warm s (best of "
          f"{args.rounds}) | first / warm | load |")
    print("|---|---|---|---|---|---|")
    for name in ("at-start", "after-warm-up"):
        r = scenario(name, args.rounds)
        print(f"| {name} | {r['healthy_s']:.1f} | {r['first_s']:.2f} | {r['warm_s']:.2f} | "
              f"{r['ratio']:.2f}x | {load1():.2f} |", flush=True)


if __name__ == "__main__":
    main()
